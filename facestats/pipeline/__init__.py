"""The fit pipeline: the stage between captures (:mod:`facestats.acquire`) and the store (:mod:`facestats.io`).

Weyrich et al. 2006 §4-5, Fig. 3, on the functions of :mod:`facestats.model.fitting`:

1. diffuse normals by photometric stereo, per-camera micro-normals;
2. albedo by the stable minimum of eq. 9 (then refined, see
   :func:`facestats.model.fitting.refine_albedo`);
3. grey specular residual, eq. 10;
4. Torrance-Sparrow and Blinn-Phong fits, eq. 14, flags;
5. maps at the capture's resolution, push-pull hole filling, flagged texels
   filled from neighbours;
6. dipole fits of the sensor profiles, σtr and ℓd per site, σtrAvg;
7. α_avg, σ's and σa from α_avg and σtrAvg (inverse of eq. 16), modulation M.

Invalid samples (NaN or negative radiance, zero irradiance, occluded or unlit
samples — all NaN in the capture —, and samples beyond 80°) are masked and
counted; a texel with too few valid samples is flagged and filled, never NaN in
the output maps.

Modules, one job each:

* :mod:`~facestats.pipeline.settings` — :class:`FitSettings` and output names;
* :mod:`~facestats.pipeline.lumitexels` — stages 1-4 on a block (:func:`fit_lumitexels`);
* :mod:`~facestats.pipeline.maps` — stage 5;
* :mod:`~facestats.pipeline.subject` — one capture, all stages (:func:`fit_subject`, :func:`fit_sensor`);
* :mod:`~facestats.pipeline.population` — many captures, σtrAvg first (:func:`fit_population`);
* :mod:`~facestats.pipeline.render` — the fitted model rendered into a capture's cameras;
* :mod:`~facestats.pipeline.build` — simulate and fit a synthetic population into a store
  (how the embedded default is made);
* :mod:`~facestats.pipeline.microstructure` — dynamic skin microstructure of a mesh sequence
  (Nagano et al. 2015), streamed to zarr/EXR, resumable;
* :mod:`~facestats.pipeline.photographs` — a folder of dome photographs to a fitted subject in a store.
* :mod:`~facestats.pipeline.texture_sample` — six population subjects at 512² (generator truth) for
  7-level texture transfer, built once into the user's cache.
"""

from facestats.pipeline.lumitexels import fit_lumitexels
from facestats.pipeline.population import fit_population
from facestats.pipeline.render import camera_image, held_out_camera_error, predict_radiance
from facestats.pipeline.settings import LUMITEXEL_OUTPUTS, FitSettings
from facestats.pipeline.subject import fit_sensor, fit_subject

__all__ = [
    "FitSettings",
    "fit_lumitexels",
    "fit_sensor",
    "fit_subject",
    "fit_population",
    "predict_radiance",
    "held_out_camera_error",
    "camera_image",
    "LUMITEXEL_OUTPUTS",
]
