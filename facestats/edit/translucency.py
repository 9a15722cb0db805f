"""The translucency of an edited subject follows its new albedo (Weyrich et al. 2006 §5.4).

The subject's homogeneous dipole is derived from its average albedo:
``α_avg`` = mean albedo over the face, ``(σ's, σa)`` =
:func:`facestats.model.dipole.scattering_from_albedo` (α_avg, σtr).  After an
edit that changes the albedo (colour, texture, skin type) the translucency
follows the new albedo through the pipeline's own stage
(:func:`facestats.model.fitting.scattering_parameters`): ``albedo_avg``,
``sigma_s_prime`` and ``sigma_a`` are recomputed with the subject's own
``sigma_tr`` (which is kept, so σtr = sqrt(3 σa (σa + σ's)) is unchanged; the
population's σtrAvg if the subject has none) and the relative index of
refraction of its fit (provenance ``fit_settings.eta``, else
:data:`facestats.core.published.ETA_SKIN`).  With ``keep=True``
``albedo_avg``, ``sigma_s_prime``, ``sigma_a`` and ``sigma_tr`` stay the
source's: the dipole keeps its profile and the modulation texture
M = albedo / albedo_avg (Weyrich eq. 7) carries the new albedo.  A stored
``modulation`` variable is recomputed in both cases
(:func:`facestats.io.schema.modulation`).  Per-site sensor data (``site_*``,
``sensor_profile*``) are measurements of the source and are left unchanged.
"""

from __future__ import annotations

import numpy as np

from facestats.core.published import ETA_SKIN, SIGMA_TR_AVG
from facestats.edit.session import replace_values
from facestats.model.dipole import check_dipole_eta

__all__ = ["follow_translucency"]


def _fit_eta(ds) -> float:
    """The relative index of refraction of the subject's fit (provenance ``fit_settings.eta``), else ETA_SKIN."""
    # local import: keeps facestats.io (22 modules) out of this module's import
    from facestats.io.schema import provenance

    try:
        eta = float(provenance(ds).get("fit_settings", {}).get("eta", ETA_SKIN))
    except (TypeError, ValueError, AttributeError):
        eta = ETA_SKIN
    return float(check_dipole_eta(eta))


def follow_translucency(ds, keep: bool) -> list[str]:
    """Update the §5.4 scattering of a subject to its (new) albedo, in place.

    Parameters
    ----------
    ds : xarray.Dataset
        The edited subject (its ``albedo`` already replaced).
    keep : bool
        Keep ``albedo_avg``, ``sigma_s_prime``, ``sigma_a`` and ``sigma_tr``
        (only a stored ``modulation`` is recomputed).

    Returns
    -------
    list of str
        The variables changed, in the order ``sigma_tr`` (if added),
        ``albedo_avg``, ``sigma_s_prime``, ``sigma_a``, ``modulation``.
    """
    # local import: keeps facestats.io (22 modules) out of this module's import
    from facestats.io.schema import modulation
    from facestats.model.fitting import scattering_parameters

    changed = []
    if not keep:
        face = np.asarray(ds["region"].values) > 0
        # The face texels only, in float64 and clipped as in the fit pipeline: α_avg is their mean, the same values
        # in the same (row-major) order as the whole map masked by the face gives, so the same bits; the whole map
        # in float64 held about 400 MB beside a 2048² subject (tracemalloc).
        alb = np.clip(np.asarray(ds["albedo"].values)[face].astype(np.float64), 1e-4, 1 - 1e-4)
        if "sigma_tr" not in ds:
            ds["sigma_tr"] = (("channel",), np.asarray(SIGMA_TR_AVG, np.float64))
            changed.append("sigma_tr")
        sigma_tr = np.asarray(ds["sigma_tr"].values, np.float64)
        avg, sp, sa, _ = scattering_parameters(alb, np.ones(len(alb), bool), sigma_tr, _fit_eta(ds))
        for name, value in (("albedo_avg", avg), ("sigma_s_prime", sp), ("sigma_a", sa)):
            attrs = ds[name].attrs if name in ds else {}
            ds[name] = (("channel",), np.asarray(value, np.float64), attrs)
            changed.append(name)
    if "modulation" in ds:
        replace_values(ds, "modulation", modulation(ds).values)
        changed.append("modulation")
    return changed
