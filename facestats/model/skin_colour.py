"""Skin colour from a melanin index: spectral mixing of the measured ColorChecker skin patches.

The colour of skin of each Fitzpatrick type is anchored in measured reflectance
spectra: the ColorChecker "light skin" and "dark skin" patches shipped with
colour-science (BabelColor average, 380-730 nm in 10 nm steps).  A melanin index
t mixes them in log-reflectance, R(λ) = R_light(λ)^(1−t) R_dark(λ)^t (a
Beer-Lambert mixture: absorbance is linear in t), and colour-science renders R
to linear sRGB under D65 with the CIE 1931 2° observer.  The synthetic
population (:mod:`facestats.acquire.synthetic.population`) draws its base
colours from here and the physics demo (:mod:`facestats.model.demo`) starts
from the "light skin" patch.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["skin_albedo"]


@functools.lru_cache(maxsize=1)
def _anchor_spectra():
    """The ColorChecker "light skin" and "dark skin" reflectance spectra, 380-730 nm in 10 nm steps."""
    import colour

    sds = colour.characterisation.SDS_COLOURCHECKERS["BabelColor Average"]
    shape = colour.SpectralShape(380, 730, 10)
    return sds["light skin"].copy().align(shape), sds["dark skin"].copy().align(shape)


def skin_albedo(melanin) -> np.ndarray:
    """Linear sRGB albedo (D65) of the spectral mix R_light^(1-t) R_dark^t of the ColorChecker skin patches.

    Parameters
    ----------
    melanin : array_like
        Melanin index t (0: "light skin" patch, 1: "dark skin" patch; values
        outside [0, 1] extrapolate in log-reflectance).

    Returns
    -------
    ndarray, shape (..., 3)
        Linear RGB in (0, 1).
    """
    import colour

    light, dark = _anchor_spectra()
    t = np.atleast_1d(np.asarray(melanin, float))
    rl, rd = np.maximum(light.values, 1e-4), np.maximum(dark.values, 1e-4)
    spectra = np.exp((1 - t[:, None]) * np.log(rl) + t[:, None] * np.log(rd))
    # Integrate R(λ) against the CIE 1931 observer under D65 (colour-science data), vectorised over subjects.
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(light.shape)
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(light.shape)
    w = cmfs.values * ill.values[:, None]
    xyz = spectra @ w / w[:, 1].sum()
    rgb = colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_encoding=False)
    out = np.clip(rgb, 0.005, 0.95)
    return out.reshape(np.shape(melanin) + (3,))
