"""BRDF transfer per face region (Weyrich et al. 2006 §8).

§8: "For each face region, we can match the parameter histogram of the source
face with another parameter histogram using the histogram interpolation
technique presented in [Matusik et al. 2005]", e.g. to change a face's BRDF
from the normal condition to lotion.  The parameters are those of the fitted
specular BRDF maps: Torrance-Sparrow ``rho_s`` and ``m`` or Blinn-Phong
``rho_s`` and ``exponent`` (any set of named maps works the same way).

Method
------
Within each region ``r`` and for each parameter, the source texels' values
``x`` are replaced by

    x' = (1 - t) x + t Q_target(u),   u = (rank(x) + ½) / n,

where ``rank`` is the texel's rank among the region's ``n`` finite source values
and ``Q_target`` the target's quantile function in that region: the empirical
quantile of target samples (another face's texels in the same region, or
samples of a population subset; :func:`facestats.edit.histogram.match_values`)
or the piecewise-linear quantile of a target :class:`Histogram`.  At ``t = 1``
the region's values have exactly the target's distribution (for equal sample
sizes, exactly the target's values); for ``0 < t < 1`` they follow the
displacement interpolation ``Q_t = (1 - t) Q_source + t Q_target`` of Matusik
et al. 2005; ``t = 0`` leaves the source untouched.

Joint plausibility of (rho_s, m)
--------------------------------
As in the paper, each parameter's histogram is matched on its own (marginals
independently).  Because every map x → x' is increasing, the ranks of each
parameter inside a region are kept, so the rank dependence between the
parameters (their copula; e.g. the Spearman correlation of rho_s and m per
region) is exactly the source's: the result has the target's marginals joined
the way the source face joins them.  Values stay inside the target's range
(hence valid if the target's are), and texels outside the edited regions, with
label 0, or with non-finite values (flagged fits) are returned bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from facestats.core.validate import as_float, check_finite
from facestats.edit.histogram import Histogram, check_t, empirical_quantile, stable_ranks
from facestats.errors import ValidationError

__all__ = ["transfer_brdf", "region_histograms"]


def _label_map(labels, shape, name):
    lab = np.asarray(labels)
    if lab.shape != tuple(shape):
        raise ValidationError(f"{name} must have shape {tuple(shape)}, got shape {lab.shape}")
    if lab.dtype.kind not in "iu":
        raise ValidationError(f"{name} must be an integer label map (0 = no region), got dtype {lab.dtype}")
    return lab


#: Physical domains of the specular parameters a transfer knows (lower bound, whether it is excluded): target
#: samples outside them are refused (a target m of -1 gave an edited m of -1).
_DOMAINS = {"rho_s": (0.0, False), "m": (0.0, True), "exponent": (0.0, False)}


def _in_domain(y, what, name):
    """``y`` if every value lies in the parameter's physical domain (:data:`_DOMAINS`; other names: any)."""
    if name in _DOMAINS and y.size:
        low, strict = _DOMAINS[name]
        bad = y <= low if strict else y < low
        if bad.any():
            sign = ">" if strict else ">="
            raise ValidationError(f"{what} must be {sign} {low:g} ({name}), got {float(y[bad][0])!r}")
    return y


def _histogram_in_domain(h, what, name):
    """``h`` if its quantiles lie in the parameter's domain: its first non-empty bin starts at or above the bound.

    A transfer draws quantiles at probabilities (k + 1/2)/n > 0, strictly inside that bin, so an excluded bound
    (m > 0) is met by an edge at the bound itself.
    """
    if name in _DOMAINS:
        low, strict = _DOMAINS[name]
        start = float(h.edges[np.argmax(h.counts > 0)])
        if start < low:
            sign = ">" if strict else ">="
            raise ValidationError(
                f"{what} must be {sign} {low:g} ({name}): the histogram's first non-empty bin starts at {start!r}"
            )
    return h


def _target_for_region(spec, name, region, target_regions):
    """Sorted finite target samples (ndarray) or a Histogram for one parameter and region, or None."""
    if isinstance(spec, Mapping):
        if region not in spec:
            return None
        v = spec[region]
        if isinstance(v, Histogram):
            return _histogram_in_domain(v, f"target[{name!r}][{region}]", name)
        y = as_float(v, f"target[{name!r}][{region}]", np.float64).ravel()
        y = _in_domain(np.sort(y[np.isfinite(y)]), f"target[{name!r}][{region}]", name)
        return y if y.size else None
    y = as_float(spec, f"target[{name!r}]", np.float64)
    if target_regions is None:
        raise ValidationError(f"target_regions must be given when target[{name!r}] is a map")
    if y.shape != target_regions.shape:
        raise ValidationError(
            f"target[{name!r}] must have the shape of target_regions {target_regions.shape}, got {y.shape}"
        )
    y = _in_domain(y[(target_regions == region) & np.isfinite(y)], f"target[{name!r}]", name)
    return np.sort(y) if y.size else None


def _check_mappings(source, target):
    if not isinstance(source, Mapping) or not source:
        got = "an empty mapping" if isinstance(source, Mapping) else type(source).__name__
        raise ValidationError(f"source must be a non-empty mapping of parameter name to map, got {got}")
    if not isinstance(target, Mapping):
        raise ValidationError(f"target must be a mapping of parameter name to target data, got {type(target).__name__}")


def _source_maps(source, target) -> dict:
    """The source maps as float arrays of one shape, each with target data."""
    maps = {k: as_float(v, f"source[{k!r}]") for k, v in source.items()}
    shape = next(iter(maps.values())).shape
    for k, v in maps.items():
        if v.shape != shape:
            raise ValidationError(f"source[{k!r}] must have the shape {shape} of the other maps, got {v.shape}")
    missing = [k for k in maps if k not in target]
    if missing:
        raise ValidationError(f"target must provide every source parameter, missing {missing}")
    return maps


def _target_labels(target_regions):
    if target_regions is None:
        return None
    tlab = np.asarray(target_regions)
    if tlab.dtype.kind not in "iu":
        raise ValidationError(f"target_regions must be an integer label map, got dtype {tlab.dtype}")
    return tlab


def _regions_to_edit(lab, edit_regions):
    """``(regions, explicit)``: ``edit_regions`` (checked present) or every nonzero region of ``lab``."""
    present = [int(r) for r in np.unique(lab) if r != 0]
    if edit_regions is None:
        return present, False
    wanted = [int(r) for r in edit_regions]
    absent = [r for r in wanted if r not in present]
    if absent:
        raise ValidationError(f"edit_regions must be regions present in regions, got {absent} (present: {present})")
    return wanted, True


def _transfer_region(out, maps, in_region, tgt, t):
    """Move the finite values of each map inside ``in_region`` to its target quantiles (into ``out``)."""
    for k, x_map in maps.items():
        sel = in_region & np.isfinite(x_map)
        x = x_map[sel].astype(np.float64)
        if x.size == 0:
            continue
        ranks = stable_ranks(x)
        y = tgt[k]
        if isinstance(y, Histogram):
            q = y.quantile(np.clip((ranks + 0.5) / x.size, 0.0, 1.0))
        else:
            q = empirical_quantile(y, ranks, x.size)
        new = q if t == 1.0 else (1 - t) * x + t * q
        out[k][sel] = new.astype(out[k].dtype)


def transfer_brdf(
    source: Mapping, regions, target: Mapping, *, target_regions=None, t: float = 1.0, edit_regions=None
) -> dict:
    """Match (or interpolate) BRDF parameter distributions per face region.

    See the module docstring for the method (Weyrich et al. 2006 §8 with the
    histogram interpolation of Matusik et al. 2005).

    Parameters
    ----------
    source : mapping of str to array_like
        Source parameter maps of one shape, e.g. ``{"rho_s": …, "m": …}``
        (Torrance-Sparrow) or ``{"rho_s": …, "exponent": …}`` (Blinn-Phong).
        Non-finite texels are ignored and kept.
    regions : array_like of int
        Region labels of the source texels (Weyrich Fig. 15: 1-10; 0 = none).
    target : mapping of str to (array_like or mapping of int to (array_like or Histogram))
        For each parameter of ``source``: either a map of another face (then
        ``target_regions`` labels it), or per region the target samples (e.g.
        pooled from a population subset) or a :class:`Histogram`.
    target_regions : array_like of int, optional
        Region labels of the target maps.
    t : float
        Interpolation weight in [0, 1] (0: source, 1: target; e.g. normal →
        lotion half-way at 0.5).
    edit_regions : iterable of int, optional
        Regions to edit; default every nonzero source region for which the
        target has data for all parameters.  An explicit region without target
        data is an error.

    Returns
    -------
    dict of str to numpy.ndarray
        New maps (copies, the source dtype) for the parameters of ``source``.
    """
    _check_mappings(source, target)
    t = check_t(t)
    maps = _source_maps(source, target)
    lab = _label_map(regions, next(iter(maps.values())).shape, "regions")
    tlab = _target_labels(target_regions)
    wanted, explicit = _regions_to_edit(lab, edit_regions)
    out = {k: v.copy() for k, v in maps.items()}
    if t == 0.0:
        return out
    for r in wanted:
        tgt = {k: _target_for_region(target[k], k, r, tlab) for k in maps}
        lacking = [k for k, v in tgt.items() if v is None]
        if lacking:
            if explicit:
                raise ValidationError(f"target has no data for region {r} and parameter(s) {lacking}")
            continue
        _transfer_region(out, maps, lab == r, tgt, t)
    return out


def region_histograms(values, regions, *, bins: int = 256, range=None) -> dict[int, Histogram]:
    """Histogram of a parameter map (or samples) per region.

    Parameters
    ----------
    values : array_like
        Parameter values (non-finite ones are ignored).
    regions : array_like of int
        Region label of each value (0 = none), same shape.
    bins : int
        Bins per histogram.
    range : (float, float), optional
        Common range of all histograms (default: each region's own min-max).

    Returns
    -------
    dict
        Region label → :class:`Histogram`, for every nonzero label with finite values.
    """
    x = as_float(values, "values", np.float64)
    lab = _label_map(regions, x.shape, "regions")
    out = {}
    for r in np.unique(lab):
        if r == 0:
            continue
        v = x[(lab == r) & np.isfinite(x)]
        if v.size:
            out[int(r)] = Histogram.from_data(check_finite(v, "values"), bins, range)
    return out
