"""Physics of the skin reflectance model: pure functions of arrays, no I/O.

Modules: :mod:`~facestats.model.fresnel`, :mod:`~facestats.model.brdf`,
:mod:`~facestats.model.dipole`, :mod:`~facestats.model.skin`, and the fitting
stages in :mod:`~facestats.model.fitting`; mesh strain in texture space
(:mod:`~facestats.model.strain`) and strain-driven microstructure convolution
(:mod:`~facestats.model.microstructure`, Nagano et al. 2015).
"""

from facestats.model import brdf, dipole, fresnel, skin  # noqa: F401

__all__ = ["brdf", "dipole", "fresnel", "skin"]
