"""Lens distortion of OpenCV's camera model (Brown-Conrady radial and tangential terms, rational radial form).

Normalised image coordinates (x', y') = (x_c/z_c, y_c/z_c) of a point in camera
coordinates are distorted, with r² = x'² + y'² and coefficients
(k₁, k₂, p₁, p₂, k₃, k₄, k₅, k₆) in OpenCV's order (OpenCV ``calib3d``, "Camera
Calibration and 3D Reconstruction", distortion model; Brown 1966 for the
tangential terms), to

    x'' = x' (1 + k₁r² + k₂r⁴ + k₃r⁶)/(1 + k₄r² + k₅r⁴ + k₆r⁶) + 2p₁x'y' + p₂(r² + 2x'²)
    y'' = y' (1 + k₁r² + k₂r⁴ + k₃r⁶)/(1 + k₄r² + k₅r⁴ + k₆r⁶) + p₁(r² + 2y'²) + 2p₂x'y'.

The camera model that uses it is :class:`facestats.acquire.dome.Dome`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["distort_normalised", "undistort_normalised"]


def distort_normalised(x, y, dist):
    """OpenCV's lens distortion of normalised image coordinates (module docstring), broadcasting.

    Parameters
    ----------
    x, y : ndarray
        Normalised coordinates (x', y') = (x_c/z_c, y_c/z_c), broadcast with ``dist``'s leading axes.
    dist : array_like, shape (..., 8)
        (k₁, k₂, p₁, p₂, k₃, k₄, k₅, k₆) on the last axis (zeros for the terms a lens does not have).

    Returns
    -------
    xd, yd : ndarray of float64
        The distorted coordinates (x'', y'').
    """
    k1, k2, p1, p2, k3, k4, k5, k6 = np.moveaxis(np.asarray(dist, np.float64), -1, 0)
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xy = 2 * x * y
    return x * radial + p1 * xy + p2 * (r2 + 2 * x * x), y * radial + p1 * (r2 + 2 * y * y) + p2 * xy


def undistort_normalised(xd, yd, dist, iterations: int = 20):
    """Inverse of :func:`distort_normalised` by fixed-point iteration (as ``cv2.undistortPoints``).

    x ← (x_d − Δx(x, y)) / radial(x, y), starting from x = x_d; converges for the
    mild distortion of calibrated lenses (|residual| < 1e-10 after 20 iterations at
    |k₁| ≤ 0.3 inside the image).

    Parameters
    ----------
    xd, yd : array_like
        Distorted normalised coordinates (x'', y''), same or broadcastable shapes.
    dist : array_like, shape (8,)
        (k₁, k₂, p₁, p₂, k₃, k₄, k₅, k₆) of one camera (no leading axes, unlike :func:`distort_normalised`).
    iterations : int
        Fixed-point iterations; no convergence test is made.

    Returns
    -------
    x, y : ndarray of float64
        The undistorted normalised coordinates (x', y').
    """
    k1, k2, p1, p2, k3, k4, k5, k6 = np.asarray(dist, np.float64)
    x, y = np.array(xd, np.float64), np.array(yd, np.float64)
    for _ in range(iterations):  # loop over iterations, vectorised over points
        r2 = x * x + y * y
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x, y = (xd - dx) / radial, (yd - dy) / radial
    return x, y
