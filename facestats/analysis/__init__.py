"""Population analysis of facial skin reflectance (Weyrich et al. 2006 §5.4 and §7).

Every statistic takes a parameter store (``facestats.open_store()``: the
shipped default, a user's own or an imported MERL/ETH file) or its population
index as a DataFrame, and returns a small result object; the functions of
:mod:`facestats.analysis.plots` turn results into matplotlib figures.

* :func:`region_pca`: PCA ellipses of (ρs, m) per face region (§7, Fig. 15);
* :func:`cca`: canonical correlation analysis of two blocks of variables (§7, Fig. 16);
* :func:`brdf_cca`: CCA of the region BRDF means against skin type, gender and age (§7, Fig. 16);
* :func:`absorption_scattering`: σa against σ's per subject and channel (§7, Fig. 14);
* :func:`translucency_table`: mean and variance of σtr per site, σtrAvg, ℓd extremes (§5.4, Table 1);
* :func:`condition_differences`: BRDF differences between external conditions (§7);
* :func:`model_errors`: Blinn-Phong against Torrance-Sparrow fit errors per region (§5.3, Fig. 7);
* :func:`sigma_posterior`, :func:`site_sigma_posterior`: Bayesian (σ's, σa, σtr, ℓd) of a
  contact-sensor profile (§5.4, with uncertainty);
* :func:`store_sigma_posterior`: the same for a subject and site of a store (defaults: first normal subject, cheek);
* :func:`population_sigma_tr`: posterior of the mean σtr per skin type (§5.4, with uncertainty);
* :func:`select_population`, :func:`region_samples`, :func:`default_subject`: which subjects and samples
  enter an analysis (:mod:`facestats.analysis.population`).

Every result object has ``to_dict()`` (its JSON document: what ``facestats analyze``
writes; conventions in :mod:`facestats.analysis.serialize`), ``compare_published()``
(our numbers beside the paper's, as data) and ``to_text()`` (the printed summary).
Those whose result is a table also have ``to_frame()``, a :class:`pandas.DataFrame` with
documented columns: :meth:`RegionPCA.to_frame` (one row per region),
:meth:`TranslucencyTable.to_frame` (Table 1, one row per site and channel) and
:meth:`CCAResult.to_frame` (one row per subject: the canonical variates of Fig. 16);
:meth:`CCAResult.summary` and :meth:`CCAResult.direct_table` are its per-dimension and
per-variable tables.

The posterior (emcee) and plotting (matplotlib) modules are imported on first use and
pandas/scipy inside the functions, so ``import facestats.analysis`` is cheap.
"""

from __future__ import annotations

import importlib

# numpy-only modules are imported eagerly (pandas, scipy, matplotlib are imported inside their functions);
# importing ``cca`` and ``brdf_cca`` here also keeps ``facestats.analysis.cca`` and ``.brdf_cca`` bound to the
# functions, not the submodules.
from facestats.analysis.brdf_cca import brdf_cca
from facestats.analysis.cca import CCAResult, cca
from facestats.analysis.conditions import ConditionDifferences, condition_differences
from facestats.analysis.models import ModelErrors, model_errors
from facestats.analysis.pca import RegionEllipse, RegionPCA, principal_axes, region_pca
from facestats.analysis.population import default_subject, region_samples, select_population
from facestats.analysis.scatter import AbsorptionScattering, absorption_scattering
from facestats.analysis.translucency import TranslucencyTable, translucency_table

#: Names imported on first use (emcee is imported with the posterior module).
_LAZY = {
    "sigma_posterior": "posterior",
    "site_sigma_posterior": "posterior",
    "store_sigma_posterior": "posterior",
    "SigmaPosterior": "posterior",
    "population_sigma_tr": "posterior",
    "PopulationSigmaTr": "posterior",
}

__all__ = [
    "region_pca",
    "principal_axes",
    "RegionPCA",
    "RegionEllipse",
    "cca",
    "brdf_cca",
    "CCAResult",
    "absorption_scattering",
    "AbsorptionScattering",
    "translucency_table",
    "TranslucencyTable",
    "condition_differences",
    "ConditionDifferences",
    "model_errors",
    "ModelErrors",
    "select_population",
    "region_samples",
    "default_subject",
    "sigma_posterior",
    "site_sigma_posterior",
    "store_sigma_posterior",
    "SigmaPosterior",
    "population_sigma_tr",
    "PopulationSigmaTr",
    "plots",
]


def __getattr__(name):
    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    if name in ("plots", "posterior"):
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(__all__))
