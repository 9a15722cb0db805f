"""The fit pipeline's stages (Weyrich et al. 2006 §4-5, Fig. 3), as functions on arrays.

Stages 1-4 work on :class:`Samples`: the valid samples of many lumitexels as
flat arrays, one contiguous run per lumitexel.

1. :func:`photometric_normals` (3 passes), :func:`micro_normals` (§5.1)
2. :func:`fresnel_factors`, :func:`albedo_stable_minimum` (eq. 9) and :func:`refine_albedo`
3. :func:`specular_residual` (eq. 10)
4. :func:`specular_factors`, :func:`fit_specular_samples` and :func:`fit_specular_models`
   (eq. 11-14, batch Levenberg-Marquardt; :func:`fit_specular` for per-texel sample arrays)
5. :func:`scatter_to_map`, :func:`push_pull`, :func:`fill_flagged`
6. :func:`fit_translucency`, :func:`population_sigma_tr_avg` (§5.4)
7. :func:`scattering_parameters` (§5.4, eq. 7, eq. 16)

Translucency from one image (Suzuki, Mukaigawa & Yagi): :func:`fit_scattering_image`
(quantised-distance solve, eq. 22-35, and the log-space dipole fit, eq. 36),
:func:`fit_scattering_channels` (R, G, B sharing one W), :class:`ProfileGrid`
(Table 2 by default).

:func:`facestats.pipeline.fit_subject` runs them all on a capture.
"""

from facestats.model.fitting.albedo import (
    BrdfSamples,
    albedo_stable_minimum,
    brdf_samples,
    fresnel_factors,
    refine_albedo,
    specular_residual,
)
from facestats.model.fitting.maps import fill_flagged, push_pull, scatter_to_map
from facestats.model.fitting.normals import micro_normals, photometric_normals
from facestats.model.fitting.profile_grid import TABLE2_GRID, ProfileGrid
from facestats.model.fitting.samples import Samples
from facestats.model.fitting.scattering_image import (
    ScatteringImageFit,
    fit_scattering_channels,
    fit_scattering_image,
    fit_scattering_system,
)
from facestats.model.fitting.specular import (
    DEFAULT_BOUNDS,
    SpecularFit,
    equivalent_lobe,
    fit_specular,
    fit_specular_models,
    fit_specular_samples,
    specular_factors,
)
from facestats.model.fitting.translucency import (
    TranslucencyFit,
    fit_translucency,
    population_sigma_tr_avg,
    scattering_parameters,
)

__all__ = [
    "photometric_normals",
    "micro_normals",
    "albedo_stable_minimum",
    "refine_albedo",
    "specular_residual",
    "fresnel_factors",
    "brdf_samples",
    "BrdfSamples",
    "fit_specular",
    "fit_specular_samples",
    "fit_specular_models",
    "specular_factors",
    "equivalent_lobe",
    "SpecularFit",
    "Samples",
    "DEFAULT_BOUNDS",
    "scatter_to_map",
    "push_pull",
    "fill_flagged",
    "fit_translucency",
    "TranslucencyFit",
    "population_sigma_tr_avg",
    "scattering_parameters",
    "fit_scattering_image",
    "fit_scattering_channels",
    "fit_scattering_system",
    "ScatteringImageFit",
    "ProfileGrid",
    "TABLE2_GRID",
]
