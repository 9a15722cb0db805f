"""Settings of the fit pipeline and the names of its per-lumitexel and per-model outputs."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from facestats.core.published import ETA_SKIN, GRAZING_LIMIT_DEG
from facestats.core.validate import as_scalar, check_integer
from facestats.errors import ValidationError
from facestats.model import fitting
from facestats.model.dipole import check_dipole_eta
from facestats.model.fitting.engine import default_engine, resolve_engine

__all__ = ["FitSettings", "checked_settings", "LUMITEXEL_OUTPUTS", "MODEL_PREFIX", "MAP_VARS", "STD_VARS"]


@dataclass
class FitSettings:
    """Settings of the fit pipeline (recorded in each subject's provenance).

    Attributes
    ----------
    discard : int
        k of the stable minimum (eq. 9): smallest values discarded (≥ 0).
    grazing_penalty : float
        γ ≥ 0 of the grazing penalty of the stable minimum (growing from θ = 60°
        to 80°, :func:`facestats.model.fitting.albedo_stable_minimum`).
    refine_albedo : bool
        Re-estimate the albedo as the mean over specular-free samples (removes
        the low bias of the minimum of noisy samples; see
        :func:`facestats.model.fitting.refine_albedo`).
    max_angle_deg : float
        Samples with θi or θo beyond this are ignored (eq. 14: 80°), in (0, 90].
    bp_max_angle_deg : float
        The Blinn-Phong fit ignores samples beyond this angle too, in (0, 90] (default 70°).
        Beyond 70° Torrance-Sparrow's G F/(N·ωi N·ωo) rises (×2 to ×6 at 80°) where a Blinn-Phong
        lobe cannot follow: on Torrance-Sparrow captures of six default-population subjects the fits
        within 80° flag 7.2 % of Blinn-Phong's texels, within 70° 0.47 %, with E over the 80° domain
        5 % higher (``docs/scale.md``, *Blinn-Phong maps*: ``bench_scale.bench_blinn_phong_maps()``).
        Set it to ``max_angle_deg`` for eq. 14 as printed.
    min_samples : int
        Texels with fewer usable samples are flagged ``few_samples`` (≥ 2).
    max_relative_error : float
        Relative standard error above which a fit is flagged ``ill_conditioned`` (> 0).
    models : tuple of str
        Specular models to fit, at least one, each once; the first is fitted from
        the log-linear start, the others start from its result.
    exclude_cameras : tuple of int
        Cameras left out of the fit (e.g. one held out to validate renderings), ≥ 0.
    micro_normals : bool
        Keep the per-camera micro-normal maps (16 × 3 values per texel).
    normal_tilt : bool
        The standard errors of ρs and the lobe allow the lobe's normal a tilt away from the
        photometric-stereo normal (two nuisance parameters,
        :mod:`facestats.model.fitting.normal_tilt`); False: errors conditional on that normal,
        which cover the truth less often than they claim (``docs/scale.md``).
    block : int
        Lumitexels per block, ≥ 1 (memory per block ≈ block × 0.1 MB); best equal to
        the capture's zarr chunk (2048 by default), so no chunk is decoded twice.
    eta : float
        Relative index of refraction, in [1, 3].
    engine : {"numba", "numpy"}
        Implementation of the hot loops (:mod:`facestats.model.fitting.engine`): compiled
        kernels or pure numpy, close but not bit-identical results.  Default:
        ``$FACESTATS_ENGINE``, else numba when it imports.
    """

    discard: int = 2
    grazing_penalty: float = 1.0
    refine_albedo: bool = True
    max_angle_deg: float = GRAZING_LIMIT_DEG
    bp_max_angle_deg: float = 70.0
    min_samples: int = 30
    max_relative_error: float = 0.25
    models: tuple = ("torrance_sparrow", "blinn_phong")
    exclude_cameras: tuple = ()
    micro_normals: bool = True
    normal_tilt: bool = True
    block: int = 2048
    eta: float = ETA_SKIN
    engine: str = field(default_factory=default_engine)

    def __post_init__(self):
        self.models = _names(self.models, "models", "model names")
        self.exclude_cameras = tuple(
            check_integer(c, "exclude_cameras", 0) for c in _names(self.exclude_cameras, "exclude_cameras", None)
        )
        if not self.models or len(set(self.models)) != len(self.models):
            raise ValidationError(f"models must name at least one model, each once, got {self.models!r}")
        for m in self.models:
            if m not in fitting.DEFAULT_BOUNDS:
                raise ValidationError(f"models must be among {list(fitting.DEFAULT_BOUNDS)}, got {m!r}")
        for name in ("refine_albedo", "micro_normals", "normal_tilt"):
            value = getattr(self, name)
            if not isinstance(value, (bool, np.bool_)):
                raise ValidationError(f"{name} must be True or False, got {value!r}")
            setattr(self, name, bool(value))
        check_integer(self.discard, "discard", 0)
        check_integer(self.min_samples, "min_samples", 2)
        check_integer(self.block, "block", 1)
        self.grazing_penalty = _number(self.grazing_penalty, "grazing_penalty", 0, None)
        self.max_angle_deg = _number(self.max_angle_deg, "max_angle_deg", 0, 90, low_inclusive=False, unit="deg")
        self.bp_max_angle_deg = _number(
            self.bp_max_angle_deg, "bp_max_angle_deg", 0, 90, low_inclusive=False, unit="deg"
        )
        self.max_relative_error = _number(self.max_relative_error, "max_relative_error", 0, None, low_inclusive=False)
        self.eta = _number(self.eta, "eta")
        check_dipole_eta(self.eta)
        self.engine = resolve_engine(self.engine)


def checked_settings(settings) -> FitSettings:
    """``settings`` validated again as a copy (its fields may have been assigned since construction), or the
    default :class:`FitSettings` for None; anything else is a :class:`ValidationError`.

    Parameters
    ----------
    settings : FitSettings or None
        The settings given.

    Returns
    -------
    FitSettings
        A new, validated instance (``settings`` itself is not changed).

    Raises
    ------
    ValidationError
        ``settings`` is not a FitSettings, or a field assigned since its construction is invalid.
    """
    if settings is None:
        return FitSettings()
    if not isinstance(settings, FitSettings):
        raise ValidationError(f"settings must be a FitSettings, got {type(settings).__name__}")
    return replace(settings)


def _names(value, name, what):
    """``value`` as a tuple: a list, tuple or range (of ``what``: str, when given); else a ValidationError."""
    if not isinstance(value, (tuple, list, range)):
        raise ValidationError(f"{name} must be a tuple{' of ' + what if what else ''}, got {value!r}")
    if what and not all(isinstance(v, str) for v in value):
        raise ValidationError(f"{name} must be a tuple of {what}, got {tuple(value)!r}")
    return tuple(value)


def _number(value, name, low=None, high=None, **bounds):
    """``value`` as a float: one real number (not a bool, not an array) in the bounds of :func:`as_finite`."""
    if isinstance(value, (bool, np.bool_)) or np.ndim(value) != 0:
        raise ValidationError(f"{name} must be a number, got {value!r}")
    return as_scalar(value, name, low, high, **bounds)


#: Per-lumitexel outputs of :func:`fit_lumitexels` (a model's four entries only when it is
#: fitted; ``micro_normal`` is added when requested).
LUMITEXEL_OUTPUTS = (
    "normal",
    "albedo",
    "albedo_min",
    "n_samples",
    "n_invalid",
    "n_grazing",
    "ts_rho_s",
    "ts_m",
    "ts_error",
    "ts_flag",
    "ts_rho_s_std",
    "ts_m_std",
    "bp_rho_s",
    "bp_exponent",
    "bp_error",
    "bp_flag",
    "bp_rho_s_std",
    "bp_exponent_std",
)

#: Prefix of each specular model's outputs, and the (ρs, lobe, error) maps of each prefix.
MODEL_PREFIX = {"torrance_sparrow": "ts", "blinn_phong": "bp"}
MAP_VARS = {"ts": ("ts_rho_s", "ts_m", "ts_error"), "bp": ("bp_rho_s", "bp_exponent", "bp_error")}
#: The standard-error maps (ρs, lobe) of each prefix: robust HC3 standard errors of the eq. 14 fit
#: (:mod:`facestats.model.fitting.uncertainty`).
STD_VARS = {"ts": ("ts_rho_s_std", "ts_m_std"), "bp": ("bp_rho_s_std", "bp_exponent_std")}
