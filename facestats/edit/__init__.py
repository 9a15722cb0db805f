"""Appearance editing (Weyrich et al. 2006 §8): array-level edits and store-level edits of subjects.

Array-level edits (numpy in, numpy out):

* BRDF transfer per face region with histogram interpolation (Matusik et al.
  2005): :func:`transfer_brdf`, :func:`interpolate_histograms`
  (:mod:`~facestats.edit.brdf`, :mod:`~facestats.edit.histogram`);
* skin-colour transfer in a decorrelated colour space: :func:`transfer_colour`
  (:mod:`~facestats.edit.colour`, :mod:`~facestats.edit.colourspace`);
* skin-texture transfer by Heeger & Bergen 1995 histogram matching on a
  steerable pyramid: :class:`TextureStatistics` (the 256 × 31 × 3 histogram
  vector of §8, :mod:`~facestats.edit.statistics`), :func:`transfer_texture`
  (:mod:`~facestats.edit.texture`);
* the building blocks: :class:`Histogram`, :func:`match_histogram`,
  :func:`match_values`, :class:`SteerablePyramid`, :class:`ColourBasis`.

Store-level edits that write a new subject with its provenance
(:mod:`facestats.edit.subjects`): :func:`change_skin_type`,
:func:`transfer_brdf_subject`, :func:`transfer_colour_subject`,
:func:`transfer_texture_subject`, :func:`subject_texture_statistics`; their
targets (:func:`select_subjects`, :mod:`~facestats.edit.targets`), the edit
session that reads the source and writes the result
(:mod:`~facestats.edit.session`), the result :class:`SubjectEdit` (or, with
``commit=False``, a :class:`PendingEdit` written by its ``commit()``)
(:mod:`~facestats.edit.result`) and the translucency that follows the albedo
(:mod:`~facestats.edit.translucency`).

Shared helpers of the modules: region masks and blending
(:mod:`~facestats.edit.masks`), pyramid grids of maps of any size
(:mod:`~facestats.edit.grids`).

Figures: :mod:`facestats.edit.plots` (:func:`~facestats.edit.plots.plot_subject_edit`,
:func:`~facestats.edit.plots.save_edit_images`, …; import matplotlib when called).
"""

from facestats.edit.brdf import region_histograms, transfer_brdf
from facestats.edit.colour import transfer_colour
from facestats.edit.colourspace import ColourBasis, decorrelating_basis
from facestats.edit.histogram import (
    Histogram,
    histogram_distance,
    interpolate_histograms,
    match_histogram,
    match_values,
)
from facestats.edit.pyramid import SteerablePyramid, band_names, max_levels
from facestats.edit.result import SubjectEdit
from facestats.edit.session import PendingEdit
from facestats.edit.statistics import TextureStatistics, region_statistics
from facestats.edit.subjects import (
    change_skin_type,
    subject_texture_statistics,
    transfer_brdf_subject,
    transfer_colour_subject,
    transfer_texture_subject,
)
from facestats.edit.targets import select_subjects
from facestats.edit.texture import TextureTransfer, transfer_texture

__all__ = [
    "ColourBasis",
    "Histogram",
    "PendingEdit",
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
