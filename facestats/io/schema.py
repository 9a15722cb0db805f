"""The per-subject Dataset schema shared by the fit pipeline, the store, analysis and editing.

A subject is an :class:`xarray.Dataset`.  Two kinds exist:

* **map subjects** (from the fit pipeline or an edit): parameter maps on dims
  (``v``, ``u``[, ``channel`` | ``component``]) in UV space, the region label map,
  contact-sensor data on (``site``, ``fiber``, ``channel``) and per-site /
  per-subject scattering coefficients, optionally with the contactless
  ``image_*`` estimates of the same sites (Suzuki et al. from one image; the
  provenance entry ``contactless_translucency`` says how they were made);
* **sample subjects** (imported from published files such as the MERL/ETH
  ``ts_data.mat``): region-level parameter samples on a ``sample`` dim and
  albedo samples on an ``albedo_sample`` dim, with no maps.

Conventions follow docs/architecture.md: lengths in mm, σ in mm⁻¹, profiles in mm⁻²,
linear RGB on a ``channel`` dim with coords R, G, B; regions numbered as in
Weyrich et al. 2006 Fig. 15 (0 = not face).  Every variable carries ``units``
and ``long_name`` attributes.

Every variable also has a **physical domain** (:data:`DOMAINS`), checked when a
subject is written and by ``facestats validate``: map variables on the face
texels (``region`` > 0; outside the face values carry no meaning), the others
everywhere.  Infinite values are never in a domain; NaN only where a domain
says so (a quantity that may be missing).  The bounds and where they come from:

* ``albedo``, ``albedo_sample`` in [0, 1]: α is a total
  diffuse reflectance (Weyrich eq. 9), which cannot exceed the incident energy;
  ``albedo_avg`` in (0, 1]: it also divides the albedo in the modulation texture
  M = α / α_avg (eq. 7), which a zero would make infinite on the whole face;
* ``ts_rho_s``, ``ts_sample_rho_s`` in [0, ρs,max] with ρs,max = 1/(4 F_r(0))
  = 9.807 at η = 1.38: in the convention of eq. 12-13 as printed (D without
  1/π, see :func:`facestats.model.brdf.torrance_sparrow`) the lobe's
  directional albedo at normal incidence is 4 ρs F_r(0) for m ≲ 0.3
  (numerical integral: 1.000 at m = 0.1, 1.002 at m = 0.3, less for rougher
  lobes; ``tests/reliability/test_api_and_physics.py``), so ρs,max reflects all
  incident light;
* ``ts_m``, ``ts_sample_m`` in (0, 10]: the Beckmann RMS slope (eq. 13) is
  positive; 10 (a mean facet slope of 84°) is far beyond skin (fitted 0.1-0.7,
  the fitter's bound is 1) and beyond where V-groove facets mean anything, so
  larger values are refused as corrupt rather than physics;
* ``bp_rho_s`` in [0, 1]: eq. 11's normalisation is chosen so that ρs = 1
  reflects 100 % of the energy (Weyrich §5.3); ``bp_exponent`` n ≥ 0 (cosⁿ δ
  diverges at δ = 90° for n < 0);
* σ's, σa ≥ 0 and σtr > 0 (mm⁻¹; eq. 15 with σa, σ's ≥ 0), their standard
  errors ≥ 0; normals have components in [-1, 1]; fit errors E(p) ≥ 0 (eq.
  14); flags hold the bits of :data:`FLAG_BITS`; sample counts ≥ 0;
* ``sensor_profile`` may dip slightly below zero in its noise (a dark-subtracted
  HDR profile); NaN marks a fibre without a reading (its spot clipped in every
  exposure), which the dipole fit leaves out.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from facestats.core.blocked import blockwise
from facestats.core.conventions import CHANNELS, COMPONENTS, CONDITIONS, FLAG_BITS, GENDERS, REGIONS, SITES
from facestats.core.published import ETA_SKIN
from facestats.errors import SchemaError
from facestats.io.layout import map_chunk_rows

__all__ = [
    "check_subject_metadata",
    "SCHEMA_VERSION",
    "VARIABLES",
    "MAP_REQUIRED",
    "STANDARD_ERRORS",
    "SAMPLE_REQUIRED",
    "FLAG_BITS",
    "Domain",
    "DOMAINS",
    "TS_RHO_S_MAX",
    "M_MAX",
    "check_domain",
    "subject_kind",
    "validate_subject",
    "face_bands",
    "face_texels",
    "FINITE_MAPS",
    "MapChecks",
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
    "image_sigma_s_prime": (("site", "channel"), "mm-1", "reduced scattering from one image under known light"),
    "image_sigma_a": (("site", "channel"), "mm-1", "absorption coefficient from one image under known light"),
    "image_sigma_tr": (("site", "channel"), "mm-1", "effective transport coefficient from one image"),
    "image_sigma_tr_low": (("site", "channel"), "mm-1", "lower end of the interval of image_sigma_tr"),
    "image_sigma_tr_high": (("site", "channel"), "mm-1", "upper end of the interval of image_sigma_tr"),
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


#: Values :meth:`Domain.outside` converts to float64 at a time.
DOMAIN_BLOCK = 1 << 18


@dataclass(frozen=True)
class Domain:
    """The values a variable may hold: ``low``/``high`` bounds (None: unbounded), open or closed, NaN or not.

    Infinite values are always outside (:meth:`outside`).

    Attributes
    ----------
    low, high : float or None
        The bounds, in the variable's units; None: unbounded on that side. ``high`` is always closed.
    low_open : bool
        ``low`` itself is outside (``(low, high]``); default closed (``[low, high]``).
    nan : bool
        NaN is allowed (a missing value).
    """

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    nan: bool = False

    def describe(self) -> str:
        """The domain as an interval, e.g. ``(0, inf)`` or ``[0, 1]``."""
        lo = "-inf" if self.low is None else f"{self.low:g}"
        hi = "inf" if self.high is None else f"{self.high:g}"
        return (
            ("(" if self.low_open or self.low is None else "[")
            + f"{lo}, {hi}"
            + ("]" if self.high is not None else ")")
        )

    def violated(self, value: float) -> str | None:
        """The bound a single value breaks, as text: ``"> 0"``, ``">= 0"`` or ``"<= 9.8"``; None if it is inside.

        Parameters
        ----------
        value : float
            One value, compared in float64 as :meth:`outside` compares it.

        Returns
        -------
        str or None
            The bound; ``"finite"`` for an infinite value (or a NaN the domain does not allow) within the bounds;
            None for a value inside the domain (one :meth:`outside` does not flag, an allowed NaN included).
        """
        value = float(value)  # a float32 against a float bound compares in float32 (NEP 50), outside() in float64
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return f"{'>' if self.low_open else '>='} {self.low:g}"
        if self.high is not None and value > self.high:
            return f"<= {self.high:g}"
        if np.isinf(value) or (np.isnan(value) and not self.nan):
            return "finite"
        return None

    def outside(self, values: np.ndarray) -> np.ndarray:
        """Boolean mask of the values outside the domain (inf always; NaN unless allowed).

        Compared in float64 (a bound is never rounded to the values' precision), block by block
        (:func:`facestats.core.blocked.blockwise`): a whole float32 map in float64 at once doubled a subject's size
        in memory at every read, write and export (1 GB more for a 2048² subject with micro-normals; the speed red
        team).

        Parameters
        ----------
        values : array_like
            Values of any shape; non-numeric dtypes are never outside.

        Returns
        -------
        ndarray of bool
            Same shape as ``values``.
        """
        v = np.asarray(values)
        if v.dtype.kind not in "fiub":
            return np.zeros(v.shape, bool)
        return blockwise(self._outside, [v], np.float64, block=DOMAIN_BLOCK, out_dtype=bool)

    def _outside(self, v: np.ndarray) -> np.ndarray:
        """:meth:`outside` of float64 values."""
        bad = np.isinf(v) | (np.isnan(v) & (not self.nan))
        with np.errstate(invalid="ignore"):
            if self.low is not None:
                bad |= (v <= self.low) if self.low_open else (v < self.low)
            if self.high is not None:
                bad |= v > self.high
        return bad


#: Torrance-Sparrow ρs that reflects all light at normal incidence: 1/(4 F_r(0)), F_r(0) = ((η−1)/(η+1))², η = 1.38.
TS_RHO_S_MAX = 1.0 / (4.0 * ((ETA_SKIN - 1.0) / (ETA_SKIN + 1.0)) ** 2)

#: Largest Beckmann roughness m a store accepts (module docstring).
M_MAX = 10.0

_NONNEG = Domain(0.0)
_NONNEG_OR_MISSING = Domain(0.0, nan=True)
_FLAGS = Domain(0, sum(FLAG_BITS.values()))
_REGION = Domain(0, max(REGIONS))
_SAMPLE_REGION = Domain(1, max(REGIONS))
_UNIT_COMPONENT = Domain(-1.0 - 1e-6, 1.0 + 1e-6, nan=True)

#: Physical domain of every variable of :data:`VARIABLES` (module docstring: where each bound comes from).
DOMAINS = {
    "region": _REGION,
    "albedo": Domain(0.0, 1.0),
    "modulation": _NONNEG,
    "normal": _UNIT_COMPONENT,
    "micro_normal": _UNIT_COMPONENT,
    "n_samples": _NONNEG,
    "ts_rho_s": Domain(0.0, TS_RHO_S_MAX),
    "ts_m": Domain(0.0, M_MAX, low_open=True),
    "ts_error": _NONNEG_OR_MISSING,
    "ts_flag": _FLAGS,
    "bp_rho_s": Domain(0.0, 1.0),
    "bp_exponent": _NONNEG,
    "bp_error": _NONNEG_OR_MISSING,
    "bp_flag": _FLAGS,
    "sensor_profile": Domain(nan=True),
    "sensor_profile_std": _NONNEG_OR_MISSING,
    "site_sigma_s_prime": _NONNEG_OR_MISSING,
    "site_sigma_a": _NONNEG_OR_MISSING,
    "site_sigma_tr": _NONNEG_OR_MISSING,
    "site_sigma_s_prime_std": _NONNEG_OR_MISSING,
    "site_sigma_a_std": _NONNEG_OR_MISSING,
    "site_sigma_tr_std": _NONNEG_OR_MISSING,
    "albedo_avg": Domain(0.0, 1.0, low_open=True),
    "sigma_s_prime": _NONNEG,
    "sigma_a": _NONNEG,
    "sigma_tr": Domain(0.0, low_open=True),
    "ts_sample_m": Domain(0.0, M_MAX, low_open=True),
    "ts_sample_rho_s": Domain(0.0, TS_RHO_S_MAX),
    "ts_sample_region": _SAMPLE_REGION,
    "albedo_sample": Domain(0.0, 1.0),
    "albedo_sample_region": _SAMPLE_REGION,
    "ts_rho_s_std": _NONNEG_OR_MISSING,
    "ts_m_std": _NONNEG_OR_MISSING,
    "bp_rho_s_std": _NONNEG_OR_MISSING,
    "bp_exponent_std": _NONNEG_OR_MISSING,
    "image_sigma_s_prime": _NONNEG_OR_MISSING,
    "image_sigma_a": _NONNEG_OR_MISSING,
    "image_sigma_tr": _NONNEG_OR_MISSING,
    "image_sigma_tr_low": _NONNEG_OR_MISSING,
    "image_sigma_tr_high": _NONNEG_OR_MISSING,
}


def check_domain(name: str, values, *, what: str, unit: str | None = None) -> None:
    """Raise :class:`SchemaError` if ``values`` of variable ``name`` leave its domain (:data:`DOMAINS`).

    Parameters
    ----------
    name : str
        A variable of :data:`DOMAINS`.
    values : array_like
        The values to check (for maps: the face texels).
    what : str
        Whose values they are, for the message (e.g. ``"subject 'S001'"``).
    unit : str, optional
        Units for the message (default: the variable's).
    """
    v = np.asarray(values)
    _check_numeric(name, v.dtype, what)
    _raise_outside(name, *_outside_count(name, v), what=what, unit=unit)


def _check_numeric(name: str, dtype, what: str) -> None:
    """Strings, complex or objects would pass the range test unseen: refuse them."""
    if np.dtype(dtype).kind not in "fiub":
        raise SchemaError(f"{what}: variable {name!r} must be numeric (float, int or bool), got dtype {dtype}")


def _outside_count(name: str, values: np.ndarray) -> tuple[int, object]:
    """(number of ``values`` outside the domain of ``name``, the first of them or None)."""
    bad = DOMAINS[name].outside(values)
    count = int(bad.sum())
    return count, (values[bad].reshape(-1)[0].item() if count else None)


def _raise_outside(name: str, count: int, first, *, what: str, unit: str | None = None) -> None:
    """The :class:`SchemaError` of :func:`check_domain` when ``count`` values (``first`` the first) are outside."""
    if not count:
        return
    domain = DOMAINS[name]
    unit = VARIABLES[name][1] if unit is None else unit
    unit_s = "" if unit == "1" else f" {unit}"
    raise SchemaError(
        f"{what}: variable {name!r} must lie in {domain.describe()}{unit_s}"
        + (" or be NaN (missing)" if domain.nan else "")
        + f", got {first!r} ({count} value(s) outside)"
    )


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


def validate_subject(ds, *, name: str | None = None, checked: MapChecks | None = None):
    """Check a subject Dataset against the schema; raise :class:`SchemaError` naming the problem.

    Checks: required attributes and their values, the variables of its kind, the
    dims of every known variable, coords of ``channel``/``site``, finite values in
    the face for the fitted maps, region labels in 0-10, and every known
    variable inside its physical domain (:data:`DOMAINS`; maps on the face).

    Parameters
    ----------
    ds : xarray.Dataset
        A subject.
    name : str, optional
        The subject's name in messages (default: its ``subject_id`` attribute).
    checked : MapChecks, optional
        The map checks of some variables already made, fed every band of them on the face of ``ds``'s ``region``
        (``open_generation(..., banded=True)`` feeds the bands its checksum pass reads): those variables are not read
        again.  The checks, their order and their messages are the same as without it.

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
    checks = None
    if kind == "maps":
        checks = _check_maps(ds, label, checked)
    else:
        _check_samples(ds, label)
    _check_domains(ds, label, checks)
    return kind


def _check_attrs(ds, label) -> None:
    """The required attributes are present and valid."""
    for key in REQUIRED_ATTRS:
        if key not in ds.attrs:
            raise SchemaError(f"subject {label!r}: missing attribute {key!r}")
    check_subject_metadata(ds.attrs, f"subject {label!r}")


def check_subject_metadata(attrs, label: str) -> None:
    """Gender, skin type, condition and age of a subject's metadata (a mapping) are in their domains.

    Parameters
    ----------
    attrs : mapping
        Holds ``gender``, ``skin_type``, ``condition`` and ``age``.
    label : str
        What messages call the mapping (e.g. ``"subject 'S001'"`` or a manifest field).

    Raises
    ------
    SchemaError
        Naming ``label``, the attribute and its value.
    """
    if not isinstance(attrs["gender"], str) or attrs["gender"] not in GENDERS:
        raise SchemaError(f"{label}: attribute gender must be one of {GENDERS}, got {attrs['gender']!r}")
    st = attrs["skin_type"]
    if isinstance(st, (bool, np.bool_)) or not isinstance(st, (int, np.integer)) or int(st) not in range(1, 7):
        raise SchemaError(f"{label}: attribute skin_type must be an integer 1-6, got {st!r}")
    if not isinstance(attrs["condition"], str) or attrs["condition"] not in CONDITIONS:
        raise SchemaError(f"{label}: attribute condition must be one of {CONDITIONS}, got {attrs['condition']!r}")
    age = attrs["age"]
    if isinstance(age, (bool, np.bool_)) or not (isinstance(age, (int, np.integer)) and 0 <= int(age) <= 200):
        raise SchemaError(f"{label}: attribute age must be an integer in 0-200 years, got {age!r}")


def _check_dims(ds, label) -> None:
    """Every known variable has the dims of :data:`VARIABLES`."""
    for var in ds.data_vars:
        if var in VARIABLES and tuple(ds[var].dims) != VARIABLES[var][0]:
            raise SchemaError(
                f"subject {label!r}: variable {var!r} must have dims {VARIABLES[var][0]}, got {tuple(ds[var].dims)}"
            )


def _check_coords(ds, label) -> None:
    """The subject's coordinates: labels (:func:`_check_labels`) and positions (:func:`_check_positions`)."""
    _check_labels(ds, label)
    _check_positions(ds, label)


def _check_labels(ds, label) -> None:
    """``channel`` coords are R, G, B; ``component`` coords x, y, z (readers take both by index); ``site`` coords
    are known sites, each once."""
    for dim, expected in (("channel", CHANNELS), ("component", COMPONENTS)):
        if dim in ds.coords:
            values = np.asarray(ds[dim].values)  # a scalar coordinate (isel(channel=0)) is no list of labels
            got = [str(c) for c in values] if values.ndim == 1 else f"a {values.ndim}-D coordinate {values.tolist()!r}"
            if got != list(expected):
                raise SchemaError(f"subject {label!r}: {dim} coords must be {expected}, got {got}")
    if "site" in ds.dims:
        sites = [str(s) for s in ds["site"].values]
        if not set(sites) <= set(SITES):
            raise SchemaError(f"subject {label!r}: site coords must be among {SITES}, got {sites}")
        if len(set(sites)) != len(sites):  # a second row of one site: which would the statistics take?
            raise SchemaError(f"subject {label!r}: site coords must name each site once, got {sites}")


def _check_positions(ds, label) -> None:
    """``u`` and ``v`` are UV positions of texels, strictly increasing inside (0, 1) (the texel centres
    (k + ½) / n of a whole map; a crop or a strided copy keeps its texels' positions); ``fiber_distance`` is a
    contact sensor's (finite, > 0 mm, strictly increasing: :class:`facestats.acquire.sensor.ContactSensor`), the
    coordinate of the ``fiber`` dimension whenever there is one."""
    for dim in ("u", "v"):
        if dim in ds.coords and dim in ds.dims:
            problem = _increasing_problem(np.asarray(ds[dim].values), 0.0, 1.0)
            if problem:
                raise SchemaError(
                    f"subject {label!r}: {dim} coords must be UV positions of texels, strictly increasing inside "
                    f"(0, 1), got {problem}"
                )
    if "fiber" in ds.dims or "fiber_distance" in ds.coords:  # the σ posterior reads the profile at these distances
        dims = ds["fiber_distance"].dims if "fiber_distance" in ds.coords else None
        if dims != ("fiber",):
            raise SchemaError(
                f"subject {label!r}: fiber_distance must be the coordinate of the fiber dimension (each fibre's "
                f"distance in mm, as sensor_profile is measured), got {'none' if dims is None else f'dims {dims}'}"
            )
        problem = _increasing_problem(np.asarray(ds["fiber_distance"].values), 0.0, np.inf)
        if problem:
            raise SchemaError(
                f"subject {label!r}: fiber_distance must be finite, > 0 mm and strictly increasing (a contact "
                f"sensor's fibres), got {problem}"
            )


def _increasing_problem(r, low: float, high: float) -> str | None:
    """What keeps the 1-D coordinate ``r`` from being finite, strictly increasing and inside (low, high) (for a
    message: the first offending value), or None."""
    if r.dtype.kind not in "fiu" or r.ndim != 1:
        return f"dtype {r.dtype}, shape {r.shape}"
    r = r.astype(np.float64)
    bad = ~np.isfinite(r) | (r <= low) | (r >= high)
    bad[1:] |= ~(r[1:] > r[:-1])
    if not bad.any():
        return None
    k = int(np.flatnonzero(bad)[0])
    after = f" after {float(r[k - 1])!r}" if k > 0 else ""
    return f"{float(r[k])!r} at index {k}{after}"


#: The fitted maps whose face texels must be finite.
FINITE_MAPS = ("albedo", "ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent")


def _check_maps(ds, label, checked: MapChecks | None = None) -> MapChecks:
    """Region labels 0-10 with at least one face texel; finite fitted maps in the face.

    Returns the :class:`MapChecks` of the subject's face (``checked`` if given), fed the maps checked here.
    """
    region = np.asarray(ds["region"].values)
    if region.dtype.kind not in "iu":  # 2.5 would silently belong to no region of any statistic
        raise SchemaError(f"subject {label!r}: region labels must be integers 0-10, got dtype {region.dtype}")
    if region.min() < 0 or region.max() > max(REGIONS):
        raise SchemaError(
            f"subject {label!r}: region labels must be 0-10, got {int(region.min())}..{int(region.max())}"
        )
    face = region > 0
    if not face.any():
        raise SchemaError(f"subject {label!r}: the region map has no face texel")
    checks = MapChecks(face) if checked is None else checked
    for var in FINITE_MAPS:
        bad = checks.of(var, ds[var].variable).nonfinite
        if bad:
            raise SchemaError(f"subject {label!r}: variable {var!r} has {bad} non-finite face texel(s)")
    return checks


def face_texels(band, dims, face_rows):
    """The face texels of one band of rows of a map: an array (texels, *other dims*), in row-major order of (v, u).

    Parameters
    ----------
    band : ndarray
        Rows ``lo:hi`` of ``v`` of a map variable with ``dims`` (``v`` and ``u`` among them).
    dims : sequence of str
        The variable's dims.
    face_rows : ndarray of bool, shape (hi - lo, u)
        The face texels of those rows (``region > 0``).

    Returns
    -------
    ndarray
    """
    dims = tuple(dims)
    return np.moveaxis(np.asarray(band), [dims.index("v"), dims.index("u")], [0, 1])[face_rows]


def face_bands(var, face):
    """The face texels of map variable ``var``, band by band of rows of ``v``: arrays (texels, *other dims*).

    A band is a chunk of the stored layout (:func:`facestats.io.layout.map_chunk_rows`), so a lazily read
    variable loads (and CRC-verifies) each chunk once and the whole variable is never in memory twice: the
    face texels of a 2048² subject's 16-camera micro-normal map gathered at once were a 480 MB copy at every
    read and write.  Texels come in row-major order of (``v``, ``u``), as ``values[face]`` would give them.

    Parameters
    ----------
    var : xarray.Variable
        A map variable (dims ``v`` and ``u`` among others), in memory or left on disk.
    face : ndarray of bool, shape (v, u)
        The face texels (``region > 0``).

    Yields
    ------
    ndarray
        The face texels of one band, shape (texels, *other dims*) (:func:`face_texels`).
    """
    dims = tuple(var.dims)
    rows = map_chunk_rows(dims, var.shape)
    for lo in range(0, var.shape[dims.index("v")], rows):
        hi = lo + rows
        yield face_texels(var[{"v": slice(lo, hi)}].values, dims, face[lo:hi])


@dataclass
class FaceCheck:
    """What the schema found on the face texels of one map variable (:class:`MapChecks`).

    Attributes
    ----------
    nonfinite : int
        Non-finite face texel values (counted for :data:`FINITE_MAPS` only, else 0).
    outside : int
        Face texel values outside the variable's domain (:data:`DOMAINS`; 0 for a variable without one).
    first : object
        The first of them in row-major texel order, or None.
    """

    nonfinite: int = 0
    outside: int = 0
    first: object = None


class MapChecks:
    """The schema's checks of map variables on the face texels (finite values, domains), fed band by band.

    :func:`validate_subject` reads each map it checks through :func:`face_bands` and feeds it here; a caller that
    reads the bands anyway (``open_generation(..., banded=True)``, which reads every band of a large map for its
    checksums) feeds them with :meth:`add` as it reads them and passes this object on, so no map is read twice.
    Counts are sums over bands and the first value outside is that of the first band holding one: the same as one
    check of all face texels at once.

    Parameters
    ----------
    face : ndarray of bool, shape (v, u)
        The face texels (``region > 0``).
    """

    def __init__(self, face):
        self.face = np.asarray(face, bool)
        self.found: dict[str, FaceCheck] = {}

    @staticmethod
    def wants(name: str, dims) -> bool:
        """True if the schema checks the face texels of a variable ``name`` with ``dims`` (a map with a domain or
        one of :data:`FINITE_MAPS`, on ``v`` and ``u``).

        Parameters
        ----------
        name : str
            The variable's name.
        dims : sequence of str
            Its dimensions.
        """
        return (name in FINITE_MAPS or (name in DOMAINS and name != "region")) and "v" in dims and "u" in dims

    def add(self, name: str, texels) -> None:
        """Feed the face texels of the next band of rows of ``name`` (:func:`face_texels`), in order of ``v``.

        Parameters
        ----------
        name : str
            The map variable's name.
        texels : ndarray, shape (texels, ...)
            The face texels of the band, in texel order.
        """
        found = self.found.setdefault(name, FaceCheck())
        if name in FINITE_MAPS:
            found.nonfinite += int((~np.isfinite(texels)).sum())
        if name in DOMAINS:
            n, first = _outside_count(name, texels)
            found.outside += n
            found.first = first if found.first is None else found.first

    def of(self, name: str, var) -> FaceCheck:
        """The checks of map variable ``name``: those fed already, else made now from ``var`` band by band.

        Parameters
        ----------
        name : str
            The map variable's name.
        var : xarray.Variable
            The variable, read band by band if nothing was fed for it.

        Returns
        -------
        FaceCheck
            Its counts of non-finite and out-of-domain face texels and the first value outside.
        """
        if name not in self.found:
            self.found[name] = FaceCheck()
            for texels in face_bands(var, self.face):
                self.add(name, texels)
        return self.found[name]


def _check_samples(ds, label) -> None:
    """Sample regions are 1-10."""
    reg = np.asarray(ds["ts_sample_region"].values)
    if reg.size and (reg.min() < 1 or reg.max() > max(REGIONS)):
        raise SchemaError(f"subject {label!r}: ts_sample_region must be 1-10, got {int(reg.min())}..{int(reg.max())}")


def _check_domains(ds, label, checks: MapChecks | None) -> None:
    """Every known variable inside its physical domain (:data:`DOMAINS`); maps on the face texels only.

    ``checks``: those of a map subject's face (None for a sample subject).  Maps are checked band by band
    (:class:`MapChecks`); the message gives the first value outside in row-major texel order and the count over the
    whole map, as one check of all face texels would.
    """
    what = f"subject {label!r}"
    for name in ds.variables:
        if name not in DOMAINS or name == "region":
            continue
        var = ds.variables[name]
        _check_numeric(name, var.dtype, what)
        if checks is None or "v" not in var.dims or "u" not in var.dims:
            _raise_outside(name, *_outside_count(name, np.asarray(var.values)), what=what)
            continue
        found = checks.of(name, var)
        _raise_outside(name, found.outside, found.first, what=what)
