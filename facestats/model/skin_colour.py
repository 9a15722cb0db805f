"""Skin colour from a melanin index: spectral mixing of the measured ColorChecker skin patches.

The colour of skin of each Fitzpatrick type is anchored in measured reflectance
spectra: the ColorChecker "light skin" and "dark skin" patches shipped with
colour-science (BabelColor average, 380-730 nm in 10 nm steps).  A melanin index
t mixes them in log-reflectance, R(λ) = R_light(λ)^(1−t) R_dark(λ)^t (a
Beer-Lambert mixture: absorbance is linear in t), and colour-science renders R
to linear sRGB under D65 with the CIE 1931 2° observer.  The tables this takes from
colour-science (the two spectra, the observer and D65 at those wavelengths, and
the two matrices of ``colour.XYZ_to_RGB``) are shipped as the module
:mod:`facestats.model.skin_colour_tables`, written by
``scripts/make_skin_colour_tables.py`` from :func:`colour_science_tables`, so
drawing a population does not import colour-science (about a second per
process); a test checks the shipped tables against colour-science's and the
albedo against its own ``XYZ_to_RGB``, bit for bit.  The synthetic
population (:mod:`facestats.acquire.synthetic.population`) draws its base
colours from here and the physics demo (:mod:`facestats.model.demo`) starts
from the "light skin" patch.
"""

from __future__ import annotations

import functools

import numpy as np

from facestats.model import skin_colour_tables

__all__ = ["skin_albedo", "colour_science_tables"]


def colour_science_tables() -> dict:
    """What :func:`skin_albedo` takes from colour-science, computed by colour-science now.

    Returns
    -------
    dict
        ``wavelengths`` (nm, 380-730 in 10 nm steps); ``light_skin`` and ``dark_skin``: the ColorChecker
        patches' reflectance (BabelColor average) at those wavelengths; ``cmfs`` (36, 3): the CIE 1931 2°
        observer's x̄, ȳ, z̄ there; ``d65``: the D65 spectral power there; ``cat02``: the CAT02 von Kries
        matrix ``colour.XYZ_to_RGB`` applies from the sRGB whitepoint to itself (the identity up to
        rounding); ``xyz_to_rgb``: sRGB's XYZ → linear RGB matrix (IEC 61966-2-1); ``colour_science``: the
        version they came from.  Arrays as nested lists of floats (their ``repr`` keeps every float64 exactly).
    """
    import colour
    from colour.adaptation import matrix_chromatic_adaptation_VonKries

    sds = colour.characterisation.SDS_COLOURCHECKERS["BabelColor Average"]
    shape = colour.SpectralShape(380, 730, 10)
    light, dark = sds["light skin"].copy().align(shape), sds["dark skin"].copy().align(shape)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(light.shape)
    ill = colour.SDS_ILLUMINANTS["D65"].copy().align(light.shape)
    srgb = colour.RGB_COLOURSPACES["sRGB"]
    white = colour.xyY_to_XYZ(colour.xy_to_xyY(srgb.whitepoint))
    cat = matrix_chromatic_adaptation_VonKries(white, white, transform="CAT02")
    return {
        "colour_science": colour.__version__,
        "wavelengths": light.wavelengths.tolist(),
        "light_skin": light.values.tolist(),
        "dark_skin": dark.values.tolist(),
        "cmfs": cmfs.values.tolist(),
        "d65": ill.values.tolist(),
        "cat02": np.asarray(cat, np.float64).tolist(),
        "xyz_to_rgb": np.asarray(srgb.matrix_XYZ_to_RGB, np.float64).tolist(),
    }


@functools.lru_cache(maxsize=1)
def _tables() -> dict:
    """The shipped tables of :func:`colour_science_tables`, as float64 arrays."""
    return {k: np.asarray(v, np.float64) for k, v in skin_colour_tables.TABLES.items() if k != "colour_science"}


def skin_albedo(melanin) -> np.ndarray:
    """Linear sRGB albedo (D65) of the spectral mix R_light^(1-t) R_dark^t of the ColorChecker skin patches.

    The reflectance is integrated against the CIE 1931 2° observer under D65,
    XYZ = Σ R(λ) x̄(λ) S(λ) / Σ ȳ(λ) S(λ) (10 nm steps), and taken to linear sRGB
    as ``colour.XYZ_to_RGB(XYZ, "sRGB", apply_cctf_encoding=False)`` does: the
    CAT02 matrix from the sRGB whitepoint to itself, then sRGB's XYZ → RGB
    matrix, each applied with ``numpy.matmul`` (colour-science's ``vecmul``).
    Patch values below 1e-4 are raised to it before the logarithm.

    Parameters
    ----------
    melanin : array_like
        Melanin index t (0: "light skin" patch, 1: "dark skin" patch; values
        outside [0, 1] extrapolate in log-reflectance).

    Returns
    -------
    ndarray, shape (..., 3)
        Linear RGB, clipped to [0.005, 0.95].
    """
    tb = _tables()
    t = np.asarray(melanin, float).reshape(-1)  # any shape: the output takes it, plus the channel axis
    rl, rd = np.maximum(tb["light_skin"], 1e-4), np.maximum(tb["dark_skin"], 1e-4)
    spectra = np.exp((1 - t[:, None]) * np.log(rl) + t[:, None] * np.log(rd))
    w = tb["cmfs"] * tb["d65"][:, None]
    xyz = spectra @ w / w[:, 1].sum()
    rgb = np.matmul(tb["xyz_to_rgb"], np.matmul(tb["cat02"], xyz[..., None]).squeeze(-1)[..., None]).squeeze(-1)
    out = np.clip(rgb, 0.005, 0.95)
    return out.reshape(np.shape(melanin) + (3,))
