"""The per-subject Dataset schema shared by the fit pipeline, the store, analysis and editing.

A subject is an :class:`xarray.Dataset`.  Two kinds exist:

* **map subjects** (from the fit pipeline or an edit): parameter maps on dims
  (``v``, ``u``[, ``channel`` | ``component``]) in UV space, the region label map,
  contact-sensor data on (``site``, ``fiber``, ``channel``) and per-site /
  per-subject scattering coefficients;
* **sample subjects** (imported from published files such as the MERL/ETH
  ``ts_data.mat``): region-level parameter samples on a ``sample`` dim and
  albedo samples on an ``albedo_sample`` dim, with no maps.

Conventions follow docs/architecture.md: lengths in mm, σ in mm⁻¹, profiles in mm⁻²,
linear RGB on a ``channel`` dim with coords R, G, B; regions numbered as in
Weyrich et al. 2006 Fig. 15 (0 = not face).  Every variable carries ``units``
and ``long_name`` attributes.
"""

from __future__ import annotations

import json

import numpy as np

from facestats.core.conventions import CHANNELS, CONDITIONS, FLAG_BITS, GENDERS, REGIONS, SITES
from facestats.errors import SchemaError

__all__ = [
    "SCHEMA_VERSION",
    "VARIABLES",
    "MAP_REQUIRED",
    "STANDARD_ERRORS",
    "SAMPLE_REQUIRED",
    "FLAG_BITS",
    "subject_kind",
    "validate_subject",
    "set_variable_attrs",
    "provenance",
    "set_provenance",
    "modulation",
]

#: Version of this schema; stores record it and readers refuse versions they do not know.
SCHEMA_VERSION = 1

#: name -> (dims, units, long name)
VARIABLES = {
    "region": (("v", "u"), "1", "face region (Weyrich Fig. 15), 0 = not face"),
    "albedo": (("v", "u", "channel"), "1", "diffuse albedo, total diffuse reflectance (Weyrich eq. 9)"),
    "modulation": (("v", "u", "channel"), "1", "modulation texture M = albedo / albedo_avg (Weyrich eq. 7)"),
    "normal": (("v", "u", "component"), "1", "diffuse normal (photometric stereo, Weyrich §5.1)"),
    "micro_normal": (("camera", "v", "u", "component"), "1", "per-camera micro-normal (Weyrich §5.1)"),
    "n_samples": (("v", "u"), "1", "valid lumitexel samples used in the fit"),
    "ts_rho_s": (("v", "u"), "1", "Torrance-Sparrow specular scale rho_s (Weyrich eq. 12)"),
    "ts_m": (("v", "u"), "1", "Torrance-Sparrow Beckmann roughness m (Weyrich eq. 13)"),
    "ts_error": (("v", "u"), "sr-1", "Torrance-Sparrow fit error E(p) (Weyrich eq. 14)"),
    "ts_flag": (("v", "u"), "1", "Torrance-Sparrow fit flags (bits: facestats.io.schema.FLAG_BITS)"),
    "ts_rho_s_std": (("v", "u"), "1", "standard error of ts_rho_s (robust covariance of the eq. 14 fit)"),
    "ts_m_std": (("v", "u"), "1", "standard error of ts_m (robust covariance of the eq. 14 fit)"),
    "bp_rho_s": (("v", "u"), "1", "Blinn-Phong specular scale rho_s (Weyrich eq. 11)"),
    "bp_exponent": (("v", "u"), "1", "Blinn-Phong exponent n (Weyrich eq. 11)"),
    "bp_error": (("v", "u"), "sr-1", "Blinn-Phong fit error E(p) (Weyrich eq. 14)"),
    "bp_flag": (("v", "u"), "1", "Blinn-Phong fit flags (bits: facestats.io.schema.FLAG_BITS)"),
    "bp_rho_s_std": (("v", "u"), "1", "standard error of bp_rho_s (robust covariance of the eq. 14 fit)"),
    "bp_exponent_std": (("v", "u"), "1", "standard error of bp_exponent (robust covariance of the eq. 14 fit)"),
    "sensor_profile": (("site", "fiber", "channel"), "mm-2", "contact-sensor profile R(r) (HDR merged)"),
    "sensor_profile_std": (("site", "fiber", "channel"), "mm-2", "standard deviation of sensor_profile (noise model)"),
    "site_sigma_s_prime": (("site", "channel"), "mm-1", "reduced scattering coefficient fitted to the profile"),
    "site_sigma_a": (("site", "channel"), "mm-1", "absorption coefficient fitted to the profile"),
    "site_sigma_tr": (("site", "channel"), "mm-1", "effective transport coefficient (Weyrich eq. 15)"),
    "site_sigma_s_prime_std": (("site", "channel"), "mm-1", "1-sigma uncertainty of site_sigma_s_prime"),
    "site_sigma_a_std": (("site", "channel"), "mm-1", "1-sigma uncertainty of site_sigma_a"),
    "site_sigma_tr_std": (("site", "channel"), "mm-1", "1-sigma uncertainty of site_sigma_tr"),
    "albedo_avg": (("channel",), "1", "average albedo alpha_avg over the face (Weyrich §5.4)"),
    "sigma_s_prime": (("channel",), "mm-1", "subject reduced scattering from alpha_avg and sigma_tr (Weyrich §5.4)"),
    "sigma_a": (("channel",), "mm-1", "subject absorption from alpha_avg and sigma_tr (Weyrich §5.4)"),
    "sigma_tr": (("channel",), "mm-1", "transport coefficient used for the subject (population sigma_trAvg)"),
    # Sample subjects (published statistics files).
    "ts_sample_m": (("sample",), "1", "Torrance-Sparrow m of one sampled vertex"),
    "ts_sample_rho_s": (("sample",), "1", "Torrance-Sparrow rho_s of one sampled vertex"),
    "ts_sample_region": (("sample",), "1", "region of the sampled vertex"),
    "albedo_sample": (("albedo_sample", "channel"), "1", "albedo of one sampled vertex"),
    "albedo_sample_region": (("albedo_sample",), "1", "region of the albedo sample"),
}

#: Standard-error map of each BRDF parameter map (optional: stores written before they existed,
#: and edited subjects, whose edited parameters are no measurements, have none).
STANDARD_ERRORS = {
    "ts_rho_s": "ts_rho_s_std",
    "ts_m": "ts_m_std",
    "bp_rho_s": "bp_rho_s_std",
    "bp_exponent": "bp_exponent_std",
}

#: Variables a map subject must have.
MAP_REQUIRED = ("region", "albedo", "ts_rho_s", "ts_m", "ts_flag", "bp_rho_s", "bp_exponent", "bp_flag", "albedo_avg")
#: Variables a sample subject must have.
SAMPLE_REQUIRED = ("ts_sample_m", "ts_sample_rho_s", "ts_sample_region")

#: Attributes every subject carries.
REQUIRED_ATTRS = ("subject_id", "age", "gender", "skin_type", "condition", "provenance")


def set_variable_attrs(ds):
    """Attach ``units`` and ``long_name`` from :data:`VARIABLES` to every known variable (in place).

    Existing attributes are kept.

    Parameters
    ----------
    ds : xarray.Dataset

    Returns
    -------
    xarray.Dataset
        ``ds``.
    """
    for name in ds.data_vars:
        if name in VARIABLES:
            _, units, long_name = VARIABLES[name]
            ds[name].attrs.setdefault("units", units)
            ds[name].attrs.setdefault("long_name", long_name)
    return ds


def subject_kind(ds) -> str:
    """The kind of a subject, from the variables it has.

    Parameters
    ----------
    ds : xarray.Dataset

    Returns
    -------
    str
        ``"maps"`` (all of :data:`MAP_REQUIRED`) or ``"samples"`` (all of :data:`SAMPLE_REQUIRED`).

    Raises
    ------
    SchemaError
        If it is neither.
    """
    if all(v in ds.data_vars for v in MAP_REQUIRED):
        return "maps"
    if all(v in ds.data_vars for v in SAMPLE_REQUIRED):
        return "samples"
    missing = [v for v in MAP_REQUIRED if v not in ds.data_vars]
    raise SchemaError(
        f"subject {ds.attrs.get('subject_id', '?')!r} has neither the map variables (missing {missing}) "
        f"nor the sample variables {list(SAMPLE_REQUIRED)}"
    )


def provenance(ds) -> dict:
    """The provenance attribute of a subject as a dict (stored as a JSON string).

    Parameters
    ----------
    ds : xarray.Dataset

    Returns
    -------
    dict
        Empty if the subject has no provenance.
    """
    p = ds.attrs.get("provenance", "{}")
    return json.loads(p) if isinstance(p, str) else dict(p)


def set_provenance(ds, **entries):
    """Merge ``entries`` into the subject's provenance (in place; JSON-serialisable values).

    Parameters
    ----------
    ds : xarray.Dataset
    **entries
        Keys and values to set (values that JSON cannot encode are stored as ``str``).

    Returns
    -------
    xarray.Dataset
        ``ds``.
    """
    p = provenance(ds)
    p.update(entries)
    ds.attrs["provenance"] = json.dumps(p, sort_keys=True, default=str)
    return ds


def modulation(ds):
    """Modulation texture M = albedo / albedo_avg (Weyrich eq. 7) of a map subject, 0 outside the face.

    α_avg is the subject's stored ``albedo_avg`` (fitted from the clipped
    albedo, or kept by an edit), not recomputed from the map as
    :func:`facestats.model.skin.modulation_texture` does, so the two differ
    in general.

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject (``albedo``, ``albedo_avg``, ``region``).

    Returns
    -------
    xarray.DataArray
        M on the dims of ``albedo``.
    """
    face = ds["region"] > 0
    return (ds["albedo"] / ds["albedo_avg"]).where(face, 0.0)


def validate_subject(ds, *, name: str | None = None):
    """Check a subject Dataset against the schema; raise :class:`SchemaError` naming the problem.

    Checks: required attributes and their values, the variables of its kind, the
    dims of every known variable, coords of ``channel``/``site``, finite values in
    the face for the fitted maps, region labels in 0-10.

    Parameters
    ----------
    ds : xarray.Dataset
        A subject.
    name : str, optional
        The subject's name in messages (default: its ``subject_id`` attribute).

    Returns
    -------
    str
        Its kind, ``"maps"`` or ``"samples"`` (:func:`subject_kind`).
    """
    label = name or ds.attrs.get("subject_id", "?")
    _check_attrs(ds, label)
    kind = subject_kind(ds)
    _check_dims(ds, label)
    _check_coords(ds, label)
    if kind == "maps":
        _check_maps(ds, label)
    else:
        _check_samples(ds, label)
    return kind


def _check_attrs(ds, label) -> None:
    """The required attributes are present and valid."""
    for key in REQUIRED_ATTRS:
        if key not in ds.attrs:
            raise SchemaError(f"subject {label!r}: missing attribute {key!r}")
    if ds.attrs["gender"] not in GENDERS:
        raise SchemaError(f"subject {label!r}: attribute gender must be one of {GENDERS}, got {ds.attrs['gender']!r}")
    if int(ds.attrs["skin_type"]) not in range(1, 7):
        raise SchemaError(f"subject {label!r}: attribute skin_type must be 1-6, got {ds.attrs['skin_type']!r}")
    if ds.attrs["condition"] not in CONDITIONS:
        raise SchemaError(
            f"subject {label!r}: attribute condition must be one of {CONDITIONS}, got {ds.attrs['condition']!r}"
        )
    age = ds.attrs["age"]
    if not (isinstance(age, (int, np.integer)) and 0 <= int(age) <= 200):
        raise SchemaError(f"subject {label!r}: attribute age must be an integer in 0-200 years, got {age!r}")


def _check_dims(ds, label) -> None:
    """Every known variable has the dims of :data:`VARIABLES`."""
    for var in ds.data_vars:
        if var in VARIABLES and tuple(ds[var].dims) != VARIABLES[var][0]:
            raise SchemaError(
                f"subject {label!r}: variable {var!r} must have dims {VARIABLES[var][0]}, got {tuple(ds[var].dims)}"
            )


def _check_coords(ds, label) -> None:
    """``channel`` coords are R, G, B; ``site`` coords are known sites."""
    if "channel" in ds.dims and tuple(str(c) for c in ds["channel"].values) != CHANNELS:
        raise SchemaError(f"subject {label!r}: channel coords must be {CHANNELS}, got {list(ds['channel'].values)}")
    if "site" in ds.dims and not set(str(s) for s in ds["site"].values) <= set(SITES):
        raise SchemaError(f"subject {label!r}: site coords must be among {SITES}, got {list(ds['site'].values)}")


def _check_maps(ds, label) -> None:
    """Region labels 0-10 with at least one face texel; finite fitted maps in the face."""
    region = np.asarray(ds["region"].values)
    if region.min() < 0 or region.max() > max(REGIONS):
        raise SchemaError(
            f"subject {label!r}: region labels must be 0-10, got {int(region.min())}..{int(region.max())}"
        )
    face = region > 0
    if not face.any():
        raise SchemaError(f"subject {label!r}: the region map has no face texel")
    for var in ("albedo", "ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent"):
        vals = np.asarray(ds[var].values)[face]
        if not np.all(np.isfinite(vals)):
            raise SchemaError(
                f"subject {label!r}: variable {var!r} has {int((~np.isfinite(vals)).sum())} non-finite face texel(s)"
            )


def _check_samples(ds, label) -> None:
    """Sample regions are 1-10."""
    reg = np.asarray(ds["ts_sample_region"].values)
    if reg.size and (reg.min() < 1 or reg.max() > max(REGIONS)):
        raise SchemaError(f"subject {label!r}: ts_sample_region must be 1-10, got {int(reg.min())}..{int(reg.max())}")
