"""Reflectance fields and relighting (Debevec et al. 2000), for measured and fitted faces.

A face imaged under every direction of a light stage (64 × 32 directions) is a
*reflectance field*; any lighting is then a weighted sum of its images (eq. 2-4).
One module per job:

* :mod:`~facestats.relight.field` — the data model (xarray Dataset, light
  directions, solid angles and intensities as coordinates) and its tiled zarr store;
* :mod:`~facestats.relight.lighting` — light probes as per-light L·δA (exact cell
  integrals, spherical Voronoi cells), rotation, lat-long/angular layouts;
* :mod:`~facestats.relight.relighting` — relighting (eq. 4), tile by tile for fields on
  disk, and the clothing tint of §3.4;
* :mod:`~facestats.relight.compression` — compressed relighting (clustered PCA);
* :mod:`~facestats.relight.stage` — the virtual light stage: any store subject
  rendered through the skin model into a field, and the direct render;
* :mod:`~facestats.relight.separate` — colour-space diffuse/specular separation and
  the chromaticity ramp (eq. 6-7);
* :mod:`~facestats.relight.novel` — reflectance functions for novel views (eq. 8-9);
* :mod:`~facestats.relight.shadows` — shadow maps by brightness thresholding (§4.4);
* :mod:`~facestats.relight.olat` — one-light-at-a-time and photometric-stereo folders (DiLiGenT
  layout or a JSON manifest) read as reflectance fields;
* :mod:`~facestats.relight.photometric` — photometric stereo (normals, albedo);
* :mod:`~facestats.relight.display`, :mod:`~facestats.relight.plots` — previews and figures.

Spherical geometry (directions, exact solid angles, rotation about +y, Voronoi
cells) lives in :mod:`facestats.model.sphere` and is re-exported here; probe files
are read by :func:`facestats.io.read_light_probe`.
"""

from facestats.model.sphere import (
    angular_directions,
    angular_solid_angles,
    latlong_directions,
    latlong_solid_angles,
    light_stage_directions,
    rotate_directions,
    rotation_y,
    voronoi_solid_angles,
)
from facestats.relight.camera import stage_camera
from facestats.relight.compression import CompressedField, compress
from facestats.relight.field import make_field, open_field, write_field
from facestats.relight.lighting import angular_to_latlong, latlong_to_angular, resample_probe, rotate_probe
from facestats.relight.novel import novel_view_field, reproject
from facestats.relight.olat import read_olat_folder, write_olat_manifest
from facestats.relight.photometric import photometric_stereo
from facestats.relight.relighting import lighting_for, relight, tint_indirect
from facestats.relight.separate import separate_field
from facestats.relight.shadows import threshold_shadow_maps
from facestats.relight.stage import light_stage_field, relight_subject, render_subject

__all__ = [
    "latlong_directions",
    "latlong_solid_angles",
    "light_stage_directions",
    "angular_directions",
    "angular_solid_angles",
    "rotation_y",
    "rotate_directions",
    "voronoi_solid_angles",
    "resample_probe",
    "rotate_probe",
    "latlong_to_angular",
    "angular_to_latlong",
    "lighting_for",
    "relight",
    "tint_indirect",
    "compress",
    "CompressedField",
    "make_field",
    "write_field",
    "open_field",
    "stage_camera",
    "light_stage_field",
    "render_subject",
    "relight_subject",
    "separate_field",
    "novel_view_field",
    "reproject",
    "threshold_shadow_maps",
    "photometric_stereo",
    "read_olat_folder",
    "write_olat_manifest",
]
