"""Light-probe files: Radiance ``.hdr`` (flat and RLE), OpenEXR and PFM, in lat-long or angular layout.

One job: read and write environment maps as linear radiance, checked for the
layout they claim.  Decoding is :mod:`facestats.io.images`; the layouts, the
direction convention (+y up, the image centre looks at −z, light directions
point from the surface towards the light) and the rotation convention are those
of :mod:`facestats.model.sphere`; resampling to a light stage is
:func:`facestats.relight.lighting.resample_probe`.

Values are returned as stored (float32, linear): high-dynamic-range data are
never normalised.  A probe with NaN, inf or negative values, the wrong aspect
ratio for its layout, an unknown layout or extension is refused with a
:class:`facestats.errors.ValidationError` naming the file, the field and the value.
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from facestats.core.validate import check_choice, check_integer
from facestats.errors import ValidationError

__all__ = [
    "PROBE_EXTENSIONS",
    "read_light_probe",
    "write_light_probe",
    "studio_probe",
    "write_studio_probe",
]

#: File types a probe can be read from (high dynamic range only: an 8-bit image is not a measurement of light).
PROBE_EXTENSIONS = (".hdr", ".pic", ".exr", ".pfm")


def _probe_path(path, must_exist=True) -> pathlib.Path:
    try:
        p = pathlib.Path(os.fspath(path))
    except TypeError:
        raise ValidationError(f"light probe path must be a str or path-like, got {path!r}") from None
    if p.suffix.lower() not in PROBE_EXTENSIONS:
        raise ValidationError(
            f"light probe {str(p)!r} must be one of {', '.join(PROBE_EXTENSIONS)} (high dynamic range), "
            f"got extension {p.suffix!r}"
        )
    if must_exist and not p.is_file():
        what = "is a directory, not a file" if p.is_dir() else "does not exist"
        raise ValidationError(f"light probe {str(p)!r} {what}")
    if not must_exist and not p.parent.is_dir():
        raise ValidationError(f"light probe {str(p)!r}: its directory {str(p.parent)!r} does not exist")
    return p


def read_light_probe(path, layout: str = "latlong") -> np.ndarray:
    """A light probe as float32 (H, W, 3) linear radiance, row 0 at the top.

    Parameters
    ----------
    path : str or path-like
        ``.hdr``/``.pic`` (Radiance RGBE, flat or run-length encoded), ``.exr``
        (R, G, B channels, or one grey channel) or ``.pfm``.
    layout : {"latlong", "angular"}
        The file's layout: lat-long (W = 2H; row 0 at +y, centre column at −z)
        or angular (W = H; the light-probe disc, centre at −z, rim at +z).
        Convert with :func:`facestats.relight.lighting.angular_to_latlong`.

    Returns
    -------
    ndarray of float32, shape (H, W, 3)
        As stored (never rescaled).  Grey files are repeated to three channels;
        an alpha channel is dropped.
    """
    # local imports: facestats.io imports this module, so `facestats query` would load them
    from facestats.io.images import read_image
    from facestats.model.sphere import LAYOUTS, check_probe

    check_choice(layout, "layout", LAYOUTS)
    p = _probe_path(path)
    img = read_image(p)
    if img.ndim == 3 and img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    return check_probe(img, layout, name=f"light probe {str(p)!r}")


def write_light_probe(path, probe, layout: str = "latlong", *, half: bool = False) -> pathlib.Path:
    """Write a probe (H, W, 3) in the format of the extension of ``path`` (``.hdr``, ``.exr``, ``.pfm``).

    The probe is checked as :func:`read_light_probe` checks it (finite, ≥ 0, the
    aspect ratio of ``layout``).  ``half`` stores half floats in EXR.  The layout
    is recorded in an EXR ``layout`` attribute (other formats cannot carry it).

    Parameters
    ----------
    path : str or path-like
        ``.hdr``, ``.pic``, ``.exr`` or ``.pfm``, in an existing folder.
    probe : array_like, shape (H, W, 3)
        Linear radiance.
    layout : {"latlong", "angular"}
        The probe's layout (W = 2H or W = H).
    half : bool
        EXR only: half floats instead of float32.

    Returns
    -------
    pathlib.Path
        The file written.

    Raises
    ------
    ValidationError
        Another extension, a missing folder, an unknown layout, or a probe that fails the checks.
    """
    # local imports: facestats.io imports this module, so `facestats query` would load them
    from facestats.io.images import write_image
    from facestats.model.sphere import check_probe

    p = _probe_path(path, must_exist=False)
    img = check_probe(probe, layout, name=f"light probe for {str(p)!r}")
    attrs = {"layout": layout, "units": "radiance (linear)"} if p.suffix.lower() == ".exr" else None
    return write_image(p, img, half=half, attributes=attrs)


def studio_probe(height: int = 32, *, key=(0.45, 0.5, 0.77), key_radiance=40.0, ambient=0.6) -> np.ndarray:
    """A simple studio probe: a uniform ambient sphere plus a soft key light (lat-long, linear RGB).

    Parameters
    ----------
    height : int
        Rows (width is twice this).
    key : array_like, shape (3,)
        World direction towards the key light (default: up, to the subject's left and in front, +z
        being the front of the face).
    key_radiance : float
        Peak radiance of the key light, a lobe exp((ω·k − 1)/(1 − cos 15°)) of about 15° width.
    ambient : float
        Radiance of the uniform ambient light.

    Returns
    -------
    ndarray of float32, shape (height, 2 height, 3)
        In the lat-long layout of :func:`facestats.model.sphere.latlong_directions`.
    """
    # local import: facestats.io imports this module, so `facestats query` would load facestats.model
    from facestats.model.sphere import latlong_directions

    h = check_integer(height, "height", 1)
    d = latlong_directions(h, 2 * h)
    k = np.asarray(key, np.float64)
    k = k / np.linalg.norm(k)
    lobe = np.exp((d @ k - 1) / (1 - np.cos(np.radians(15.0))))
    warm = np.array([1.0, 0.95, 0.88])
    return (ambient + key_radiance * lobe[..., None] * warm).astype(np.float32)


def write_studio_probe(path, height: int = 32) -> str:
    """Write :func:`studio_probe` as a lat-long light probe file; returns ``path`` as a string.

    Parameters
    ----------
    path : str or path-like
        ``.exr`` (the layout recorded in its header; what :mod:`facestats.io.mitsuba` writes), or ``.hdr``,
        ``.pic``, ``.pfm``, in an existing folder.
    height : int
        Rows of the probe (width twice this).

    Returns
    -------
    str
    """
    write_light_probe(path, studio_probe(height))
    return os.fspath(path)
