"""Figures of appearance edits: before/after albedo, convergence, histogram interpolation.

Each function returns a :class:`matplotlib.figure.Figure` (no pyplot state, no
``show``).  Linear-RGB albedo is displayed with the sRGB transfer function
(colour-science's ``cctf_encoding``).
"""

from __future__ import annotations

import numpy as np

from facestats.edit.histogram import Histogram, interpolate_histograms
from facestats.edit.pyramid import band_names
from facestats.errors import ValidationError

__all__ = ["plot_texture_transfer", "plot_histogram_interpolation"]


def _figure(**kwargs):
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def _display(rgb):
    """Linear RGB in [0, 1] → sRGB-encoded values for imshow."""
    import colour

    return np.clip(colour.cctf_encoding(np.clip(np.asarray(rgb, np.float64), 0.0, 1.0)), 0.0, 1.0)


def _crop(img, crop):
    if crop is None:
        return img
    (r0, r1), (c0, c1) = crop
    return img[r0:r1, c0:c1]


def plot_texture_transfer(result, *, target=None, crop=None, title="Texture transfer (Heeger & Bergen 1995)"):
    """Source, result (and optionally target) albedo, and the convergence curve.

    Parameters
    ----------
    result : facestats.edit.TextureTransfer
        Output of :func:`facestats.edit.transfer_texture`.
    target : array_like, shape (H', W', 3), optional
        Target albedo to show next to them.
    crop : ((row0, row1), (col0, col1)), optional
        Window of the source/result (and target) to display, e.g. to see pores
        on a large map.
    title : str
        Figure title.

    Returns
    -------
    matplotlib.figure.Figure
        Image panels, then the mean band-histogram distance per iteration with
        the mean of each pyramid level (high-pass, levels, low-pass).
    """
    if not hasattr(result, "band_distance") or not hasattr(result, "albedo"):
        raise ValidationError(f"result must be a TextureTransfer, got {type(result).__name__}")
    panels = [("source", result.source), ("result", result.albedo)]
    if target is not None:
        panels.insert(1, ("target", target))
    fig = _figure(figsize=(4.0 * (len(panels) + 1.3), 4.2), layout="constrained")
    gs = fig.add_gridspec(1, len(panels) + 1, width_ratios=[1] * len(panels) + [1.3])
    for k, (name, img) in enumerate(panels):
        ax = fig.add_subplot(gs[0, k])
        ax.imshow(_display(_crop(np.asarray(img), crop)), interpolation="nearest")
        ax.set_title(name)
        ax.set_axis_off()
    ax = fig.add_subplot(gs[0, -1])
    it = np.arange(result.distance.size)
    bd = result.band_distance.mean(axis=1)  # (iterations + 1, bands)
    first = next(iter(result.statistics.values()))
    levels, orientations = first.levels, first.orientations
    names = band_names(levels, orientations)
    cmap = _cmap(levels + 2)
    ax.plot(it, bd[:, 0], color=cmap[0], lw=1, label=names[0])
    for i in range(levels):
        ax.plot(
            it,
            bd[:, 1 + i * orientations : 1 + (i + 1) * orientations].mean(axis=1),
            color=cmap[i + 1],
            lw=1,
            label=f"level {i}",
        )
    ax.plot(it, bd[:, -1], color=cmap[-1], lw=1, label=names[-1])
    ax.plot(it, result.distance, "k-o", lw=2.2, ms=4, label="mean")
    ax.set_xlabel("iteration")
    ax.set_ylabel("histogram distance to target (TV)")
    ax.set_xticks(it)
    ax.set_ylim(0, None)
    ax.legend(fontsize=7, ncol=2, loc="upper right", framealpha=0.8)
    ax.set_title("convergence")
    fig.suptitle(title)
    return fig


def _cmap(n):
    from matplotlib import colormaps

    return colormaps["viridis"](np.linspace(0.0, 0.9, n))


def plot_histogram_interpolation(
    h0: Histogram,
    h1: Histogram,
    ts=(0.0, 0.25, 0.5, 0.75, 1.0),
    *,
    labels=("source", "target"),
    xlabel="value",
    title="Histogram interpolation",
):
    """Densities of :func:`interpolate_histograms` between two histograms for several ``t``.

    Parameters
    ----------
    h0, h1 : Histogram
        End points (t = 0 and t = 1).
    ts : sequence of float
        Weights to draw.
    labels : (str, str)
        Names of the end points, e.g. ``("normal", "lotion")``.
    xlabel, title : str
        Axis label (parameter and unit) and title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = _figure(figsize=(6.5, 4.0), layout="constrained")
    ax = fig.add_subplot()
    cmap = _cmap(len(ts))
    for colour_, t in zip(cmap, ts):
        h = interpolate_histograms(h0, h1, t)
        density = h.pdf / np.diff(h.edges)
        label = f"t = {t:g}" + (f" ({labels[0]})" if t == 0 else f" ({labels[1]})" if t == 1 else "")
        ax.stairs(density, h.edges, color=colour_, lw=1.5, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("probability density")
    ax.legend(fontsize=8)
    ax.set_title(title)
    return fig
