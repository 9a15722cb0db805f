"""Appearance editing on arrays (Weyrich et al. 2006 §8).

* BRDF transfer per face region with histogram interpolation (Matusik et al.
  2005): :func:`transfer_brdf`, :func:`interpolate_histograms`;
* skin-colour transfer in a decorrelated colour space: :func:`transfer_colour`;
* skin-texture transfer by Heeger & Bergen 1995 histogram matching on a
  steerable pyramid: :class:`TextureStatistics` (the 256 × 31 × 3 histogram
  vector of §8), :func:`transfer_texture`;
* store-level edits that write a new subject with its provenance
  (:mod:`facestats.edit.subjects`): :func:`change_skin_type`,
  :func:`transfer_brdf_subject`, :func:`transfer_colour_subject`,
  :func:`transfer_texture_subject`, :func:`subject_texture_statistics`;
* the building blocks: :class:`Histogram`, :func:`match_histogram`,
  :func:`match_values`, :class:`SteerablePyramid`, :class:`ColourBasis`.

Figures: :mod:`facestats.edit.plots` and :func:`facestats.edit.subjects.plot_subject_edit`,
:func:`facestats.edit.subjects.save_edit_images` (import matplotlib when called).
"""

from facestats.edit.brdf import region_histograms, transfer_brdf
from facestats.edit.colour import ColourBasis, decorrelating_basis, transfer_colour
from facestats.edit.histogram import (
    Histogram,
    histogram_distance,
    interpolate_histograms,
    match_histogram,
    match_values,
)
from facestats.edit.pyramid import SteerablePyramid, band_names, max_levels
from facestats.edit.subjects import (
    SubjectEdit,
    change_skin_type,
    select_subjects,
    subject_texture_statistics,
    transfer_brdf_subject,
    transfer_colour_subject,
    transfer_texture_subject,
)
from facestats.edit.texture import TextureStatistics, TextureTransfer, region_statistics, transfer_texture

__all__ = [
    "ColourBasis",
    "Histogram",
    "SteerablePyramid",
    "SubjectEdit",
    "TextureStatistics",
    "TextureTransfer",
    "band_names",
    "change_skin_type",
    "decorrelating_basis",
    "histogram_distance",
    "interpolate_histograms",
    "match_histogram",
    "match_values",
    "max_levels",
    "region_histograms",
    "region_statistics",
    "select_subjects",
    "subject_texture_statistics",
    "transfer_brdf",
    "transfer_brdf_subject",
    "transfer_colour",
    "transfer_colour_subject",
    "transfer_texture",
    "transfer_texture_subject",
]
