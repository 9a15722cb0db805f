"""Latitude-longitude light probes: the pixel ↔ direction mapping, reading a probe, and a default studio probe.

One convention for every renderer facestats drives, chosen to be Mitsuba 3's
``envmap`` plugin's (so a probe file means the same lighting in Mitsuba and in
:func:`facestats.pipeline.validation.render_probe`): in facestats' world frame
(+y up, +z towards the frontal camera), pixel column u ∈ [0, 1) and row
v ∈ [0, 1] (row 0 at the top) look towards

    θ = π v,   φ = 2π u,   ω = (sin θ sin φ, cos θ, −sin θ cos φ),

i.e. u = atan2(ωx, −ωz)/2π and v = acos(ωy)/π (Mitsuba 3, ``envmap.cpp``):
the top row is straight up, the centre of the image (u = 0.5) looks at +z,
the front of the face.  Each pixel subtends Δω = (2π/W)(π/H) sin θ sr.
Radiance values are linear RGB (W mm⁻² sr⁻¹ or any consistent unit).
"""

from __future__ import annotations

import os

import numpy as np

from facestats.core.validate import check_integer
from facestats.errors import ValidationError

__all__ = ["latlong_directions", "read_latlong_probe", "studio_probe", "write_studio_probe"]


def latlong_directions(height: int, width: int):
    """Unit directions and solid angles of the pixel centres of a ``height`` × ``width`` lat-long map.

    Parameters
    ----------
    height, width : int
        Map size in pixels (width = 2 height for a full sphere).

    Returns
    -------
    directions : ndarray, shape (height, width, 3)
        ω of each pixel centre (module docstring).
    solid_angle : ndarray, shape (height, width)
        Δω of each pixel, sr; sums to 4π.
    """
    h = check_integer(height, "height", 1)
    w = check_integer(width, "width", 1)
    theta = np.pi * (np.arange(h) + 0.5) / h
    phi = 2 * np.pi * (np.arange(w) + 0.5) / w
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    d = np.stack(
        [st * np.sin(phi)[None, :], np.broadcast_to(ct, (h, w)), -st * np.cos(phi)[None, :]],
        axis=-1,
    )
    # Exact solid angle of each pixel's band (cos θ0 − cos θ1) Δφ.
    edges = np.pi * np.arange(h + 1) / h
    band = (np.cos(edges[:-1]) - np.cos(edges[1:])) * (2 * np.pi / w)
    return d, np.broadcast_to(band[:, None], (h, w)).copy()


def read_latlong_probe(path) -> np.ndarray:
    """A lat-long light probe (EXR, Radiance HDR or PFM) as float32 (H, W, 3), checked.

    Raises
    ------
    ValidationError
        Not an HDR file, not RGB, not 2:1, or negative or non-finite radiance.
    """
    from facestats.io.images import HDR_EXTENSIONS, read_image

    p = os.fspath(path)
    if not os.path.isfile(p):
        raise ValidationError(f"probe must name an existing latitude-longitude HDR file, got {p!r}")
    if os.path.splitext(p)[1].lower() not in HDR_EXTENSIONS:
        raise ValidationError(f"probe must be a high-dynamic-range file ({', '.join(HDR_EXTENSIONS)}), got {p!r}")
    img = read_image(p)
    if img.shape[2] < 3:
        raise ValidationError(f"probe {p!r} must be an RGB image, got {img.shape[2]} channel(s)")
    img = img[..., :3]
    if img.shape[1] != 2 * img.shape[0]:
        raise ValidationError(f"probe {p!r} must be a latitude-longitude map of width 2 x height, got {img.shape[:2]}")
    if not np.all(np.isfinite(img)) or img.min() < 0:
        raise ValidationError(f"probe {p!r} must hold finite radiance >= 0")
    return img


def studio_probe(height: int = 32, *, key=(0.45, 0.5, 0.77), key_radiance=40.0, ambient=0.6):
    """A simple studio probe: a uniform ambient sphere plus a soft key light (lat-long, linear RGB).

    Parameters
    ----------
    height : int
        Rows (width is twice this).
    key : array_like, shape (3,)
        Direction towards the key light (default: up and to the subject's left, in front).
    key_radiance : float
        Peak radiance of the key light (a Gaussian lobe of about 15° width).
    ambient : float
        Radiance of the uniform ambient light.

    Returns
    -------
    ndarray of float32, shape (height, 2 height, 3)
    """
    d, _ = latlong_directions(height, 2 * height)
    k = np.asarray(key, np.float64)
    k = k / np.linalg.norm(k)
    lobe = np.exp((d @ k - 1) / (1 - np.cos(np.radians(15.0))))
    warm = np.array([1.0, 0.95, 0.88])
    return (ambient + key_radiance * lobe[..., None] * warm).astype(np.float32)


def write_studio_probe(path, height: int = 32) -> str:
    """Write :func:`studio_probe` as an EXR (with the lat-long convention in its header); returns ``path``."""
    from facestats.io.images import write_exr

    img = studio_probe(height)
    write_exr(
        path,
        {c: img[..., i] for i, c in enumerate("RGB")},
        attributes={"facestats.probe": "latitude-longitude, Mitsuba 3 envmap convention, +y up, centre = +z"},
    )
    return os.fspath(path)
