"""Appearance editing on arrays (Weyrich et al. 2006 §8).

* BRDF transfer per face region with histogram interpolation (Matusik et al.
  2005): :func:`transfer_brdf`, :func:`interpolate_histograms`;
* skin-colour transfer in a decorrelated colour space: :func:`transfer_colour`;
* skin-texture transfer by Heeger & Bergen 1995 histogram matching on a
  steerable pyramid: :class:`TextureStatistics` (the 256 × 31 × 3 histogram
  vector of §8), :func:`transfer_texture`;
* the building blocks: :class:`Histogram`, :func:`match_histogram`,
  :func:`match_values`, :class:`SteerablePyramid`, :class:`ColourBasis`.

Figures: :mod:`facestats.edit.plots` (imports matplotlib when called).
"""

from .brdf import region_histograms, transfer_brdf
from .colour import ColourBasis, decorrelating_basis, transfer_colour
from .histogram import Histogram, histogram_distance, interpolate_histograms, match_histogram, match_values
from .pyramid import SteerablePyramid, band_names, max_levels
from .texture import TextureStatistics, TextureTransfer, region_statistics, transfer_texture

__all__ = [
    "ColourBasis",
    "Histogram",
    "SteerablePyramid",
    "TextureStatistics",
    "TextureTransfer",
    "band_names",
    "decorrelating_basis",
    "histogram_distance",
    "interpolate_histograms",
    "match_histogram",
    "match_values",
    "max_levels",
    "region_histograms",
    "region_statistics",
    "transfer_brdf",
    "transfer_colour",
    "transfer_texture",
]
