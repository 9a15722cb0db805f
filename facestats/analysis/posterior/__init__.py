"""Bayesian posteriors of the subsurface scattering coefficients (Weyrich et al. 2006 §5.4, with uncertainty).

One module per model, and the pieces they share:

* :mod:`~facestats.analysis.posterior.profile`: the posterior of (σ's, σa),
  σtr and ℓd per channel of one contact-sensor profile
  (:func:`sigma_posterior`, :func:`site_sigma_posterior`,
  :func:`store_sigma_posterior`, result :class:`SigmaPosterior`), built from
  :mod:`~facestats.analysis.posterior.likelihood` (model, likelihood, prior),
  :mod:`~facestats.analysis.posterior.start` (least-squares start),
  :mod:`~facestats.analysis.posterior.moves` (the emcee move
  :class:`BlockDEMove`) and :mod:`~facestats.analysis.posterior.chains`
  (convergence, burn-in, thinning);
* :mod:`~facestats.analysis.posterior.hierarchical`: the posterior of the
  mean σtr per skin type (:func:`population_sigma_tr`, result
  :class:`PopulationSigmaTr`);
* :mod:`~facestats.analysis.posterior.credible`: credible levels and interval
  quantiles.

Importing this package imports emcee; :mod:`facestats.analysis` imports it on
first use only.
"""

from __future__ import annotations

from facestats.analysis.posterior.hierarchical import PopulationSigmaTr, population_sigma_tr
from facestats.analysis.posterior.likelihood import DEFAULT_BOUNDS, PARAMETERS
from facestats.analysis.posterior.moves import BlockDEMove
from facestats.analysis.posterior.profile import (
    SigmaPosterior,
    sigma_posterior,
    site_sigma_posterior,
    store_sigma_posterior,
)

__all__ = [
    "DEFAULT_BOUNDS",
    "PARAMETERS",
    "BlockDEMove",
    "SigmaPosterior",
    "sigma_posterior",
    "site_sigma_posterior",
    "store_sigma_posterior",
    "PopulationSigmaTr",
    "population_sigma_tr",
]
