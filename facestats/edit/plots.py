"""Figures of appearance edits: before/after maps, convergence, histogram interpolation, PNG export.

Each ``plot_*`` function returns a :class:`matplotlib.figure.Figure` (no pyplot
state, no ``show``); :func:`save_edit_images` writes PNGs (:func:`stage_edit_images` into an
:class:`~facestats.core.outputs.OutputSet` of the caller's).  matplotlib is
imported when a function is called.  Linear-RGB albedo is displayed with the
sRGB transfer function of IEC 61966-2-1 (through
:func:`facestats.io.images.linear_to_srgb`).  The summary figure draws maps of at
most :data:`PANEL_MAX` texels a side; the PNGs of each map are full size.

The PNG of each map is a plain image of it, one texel to k × k pixels (for viewing and compositing; the summary
figure is the one with colour bars), and its text chunks carry its scale (:data:`SCALE_KEYS`): the map's name and
units, the colour map, and the values drawn at the colour map's two ends.
"""

from __future__ import annotations

import pathlib

import numpy as np

from facestats.core.outputs import OutputSet, check_output_dir
from facestats.edit.histogram import Histogram, interpolate_histograms
from facestats.edit.pyramid import band_names
from facestats.edit.result import BRDF_VARIABLES, SubjectEdit
from facestats.errors import ValidationError
from facestats.io.images import linear_to_srgb, stride_step
from facestats.io.png import SCALE_KEYS, map_scale_text

__all__ = [
    "plot_texture_transfer",
    "plot_histogram_interpolation",
    "plot_subject_edit",
    "save_edit_images",
    "stage_edit_images",
    "edit_image_names",
    "SCALE_KEYS",
]


def _figure(**kwargs):
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def _display(rgb):
    """Linear RGB in [0, 1] → sRGB-encoded float32 values for imshow (:func:`facestats.io.images.linear_to_srgb`)."""
    return np.clip(linear_to_srgb(rgb), 0.0, 1.0)


#: Largest side of a panel of :func:`plot_subject_edit`: a panel is drawn about 250 pixels wide, and full-size
#: float64 copies of every map (and matplotlib's masked copies of them) took 3.2 GB at 4096² (the speed red team).
PANEL_MAX = 512


def _thumbnail(img, max_side=PANEL_MAX):
    """Every k-th texel of a map (k the smallest step that brings its longer side to at most ``max_side``)."""
    k = stride_step(*img.shape[:2], max_side)
    return img[::k, ::k]


def _window(img, crop):
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
        ax.imshow(_display(_window(np.asarray(img), crop)), interpolation="nearest")
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


# --------------------------------------------------------------------------- store-level edits


def _check_edit(edit):
    if not isinstance(edit, SubjectEdit):
        raise ValidationError(f"edit must be a SubjectEdit, got {type(edit).__name__}")
    return edit


def _map_range(before, after, face):
    vals = np.concatenate([before[face], after[face]])
    lo, hi = np.percentile(vals, [1, 99])
    return (float(lo), float(hi)) if hi > lo else (float(lo) - 1e-6, float(hi) + 1e-6)


def _edit_row(fig, grid, k, var, before, after, face):
    """Row ``k`` of :func:`plot_subject_edit`: before, after, their colour bar, difference, its colour bar."""
    ax_b, ax_a, cax, ax_d, dax = (fig.add_subplot(grid[k, j]) for j in range(5))
    if var == "albedo":
        ax_b.imshow(_display(before), interpolation="nearest")
        ax_a.imshow(_display(after), interpolation="nearest")
        cax.set_axis_off()
        diff = (after - before).mean(axis=-1)
    else:
        lo, hi = _map_range(before, after, face)
        for ax, img in ((ax_b, before), (ax_a, after)):
            im = ax.imshow(np.where(face, img, np.nan), vmin=lo, vmax=hi, cmap="viridis", interpolation="nearest")
        fig.colorbar(im, cax=cax, label=var)
        diff = after - before
    lim = float(np.percentile(np.abs(diff[face]), 99)) or 1e-6  # robust: a few texels may jump further
    im = ax_d.imshow(np.where(face, diff, np.nan), vmin=-lim, vmax=lim, cmap="RdBu_r", interpolation="nearest")
    fig.colorbar(im, cax=dax, label="after − before" + (" (mean RGB)" if var == "albedo" else ""))
    ax_b.set_title(f"{var}: before")
    ax_a.set_title(f"{var}: after")
    ax_d.set_title("difference")
    for ax in (ax_b, ax_a, ax_d):
        ax.set_axis_off()


def plot_subject_edit(edit: SubjectEdit, *, title: str | None = None):
    """Before, after and difference of the albedo and of every edited BRDF map.

    Parameters
    ----------
    edit : SubjectEdit
        Result of one of the subject edits.
    title : str, optional
        Figure title (default: the new id and the edit's name).

    Returns
    -------
    matplotlib.figure.Figure
        One row per map: before, after (albedo sRGB-encoded for display, BRDF
        maps on one colour scale), and after − before (albedo: mean over the
        channels; diverging scale clipped at the 99th percentile of the
        absolute change).  Texels outside the face are blank.
    """
    _check_edit(edit)
    face = np.asarray(edit.source["region"].values) > 0
    rows = (["albedo"] if "albedo" in edit.variables else []) + edit.brdf_variables
    if not rows:
        rows = ["albedo"]
    fig = _figure(figsize=(10.0, 3.0 * len(rows)), layout="constrained")
    # Columns: before, after, their colour bar, difference, its colour bar (same widths in every row).
    grid = fig.add_gridspec(len(rows), 5, width_ratios=[1, 1, 0.05, 1, 0.05])
    face = _thumbnail(face)
    for k, var in enumerate(rows):  # panels of at most PANEL_MAX texels a side, in float32
        before = np.asarray(_thumbnail(edit.source[var].values), np.float32)
        after = np.asarray(_thumbnail(edit.dataset[var].values), np.float32)
        _edit_row(fig, grid, k, var, before, after, face)
    fig.suptitle(title or f"{edit.subject_id} ({edit.edit['name']} of {edit.source.attrs['subject_id']})")
    return fig


def _upscale_factor(shape, min_side=256):
    """Pixels a side of one texel in a map's PNG: the smallest k with k × the longer side ≥ ``min_side``."""
    return max(1, -(-min_side // max(shape[:2])))


def _upscale(img, k):
    return img if k == 1 else np.repeat(np.repeat(img, k, axis=0), k, axis=1)


_SHARED = (
    "; the before and after images share it (1st-99th percentile of both images' face texels); black outside the face"
)


def edit_image_names(subject_id: str) -> list[str]:
    """Every file name :func:`save_edit_images` may write for the edited subject ``subject_id`` (a superset of
    one edit's: the BRDF maps it did not change are not written).

    Parameters
    ----------
    subject_id : str
        The new subject's id.

    Returns
    -------
    list of str
        ``<id>_<map>_before.png`` and ``<id>_<map>_after.png`` for the albedo and every BRDF map, then
        ``<id>_summary.png`` (bare names, no folder).
    """
    maps = ("albedo", *BRDF_VARIABLES)
    return [f"{subject_id}_{m}_{when}.png" for m in maps for when in ("before", "after")] + [
        f"{subject_id}_summary.png"
    ]


def stage_edit_images(edit: SubjectEdit, outputs: OutputSet) -> dict[str, str]:
    """Render the before/after PNGs of an edit into an open :class:`~facestats.core.outputs.OutputSet`.

    Each file is written under the temporary name ``outputs.path(name)`` gives (hidden, beside its target, in the
    set's folder); they are renamed into place, all or none, when the set's ``with`` block ends, and removed if it
    fails.  The files and their contents are those of :func:`save_edit_images`, which is this function in a set
    of its own.  ``facestats edit`` stages them before it commits a pending edit
    (:class:`~facestats.edit.session.PendingEdit`) in the same block, so that the images appear only for a
    subject that was written, and a failure to write them leaves the store as it was.

    Parameters
    ----------
    edit : SubjectEdit
        Result of one of the subject edits (written or pending: only its datasets are drawn).
    outputs : facestats.core.outputs.OutputSet
        The set, inside its ``with`` block; the names are relative to its folder.

    Returns
    -------
    dict of str to str
        File name → its scale in words (what ``facestats edit`` prints beside the name; the per-map PNGs also hold
        it in their text chunks, :data:`SCALE_KEYS`).  After the block, ``outputs.written`` lists the files.
    """
    import matplotlib.pyplot as plt
    from matplotlib import colormaps
    from matplotlib.image import imsave

    _check_edit(edit)
    face = np.asarray(edit.source["region"].values) > 0
    k = _upscale_factor(face.shape)
    cmap = colormaps["viridis"]
    scales = {}
    text, words = map_scale_text("albedo", "sRGB", 0.0, 1.0, k)
    for when, ds in (("before", edit.source), ("after", edit.dataset)):
        name = f"{edit.subject_id}_albedo_{when}.png"
        imsave(outputs.path(name), _upscale(_display(np.asarray(ds["albedo"].values)), k), metadata=text)
        scales[name] = words
    for var in edit.brdf_variables:
        before = np.asarray(edit.source[var].values, np.float32)
        after = np.asarray(edit.dataset[var].values, np.float32)
        lo, hi = _map_range(before, after, face)
        text, words = map_scale_text(var, "viridis", lo, hi, k, note=_SHARED)
        for when, img in (("before", before), ("after", after)):
            rgb = cmap(np.clip((img - lo) / (hi - lo), 0.0, 1.0), bytes=True)[..., :3]  # 8-bit, as written
            rgb[~face] = 0
            name = f"{edit.subject_id}_{var}_{when}.png"
            imsave(outputs.path(name), _upscale(rgb, k), metadata=text)
            scales[name] = words
    fig = plot_subject_edit(edit)
    try:
        name = f"{edit.subject_id}_summary.png"
        fig.savefig(outputs.path(name), dpi=100)
        scales[name] = "before, after and difference of each map, with colour bars"
    finally:
        plt.close(fig)
    return scales


def save_edit_images(edit: SubjectEdit, directory=".") -> list[pathlib.Path]:
    """Write before/after PNGs of an edit.

    Files (``<id>`` the new subject id), in ``directory`` (created if missing):
    ``<id>_albedo_before.png`` and ``<id>_albedo_after.png`` (linear albedo
    sRGB-encoded for display), ``<id>_<map>_before.png`` /
    ``<id>_<map>_after.png`` for every edited BRDF map (viridis on one scale
    for both, 1st-99th percentile of the face texels; black outside the face),
    and ``<id>_summary.png`` (:func:`plot_subject_edit`, with colour bars).
    Small maps are enlarged by pixel repetition to at least 256 pixels a side.
    The maps' PNGs have no colour bar: their text chunks hold the scale
    (:data:`SCALE_KEYS`).
    To write them together with something else, all or none, use
    :func:`stage_edit_images` in an :class:`~facestats.core.outputs.OutputSet`.

    Parameters
    ----------
    edit : SubjectEdit
        Result of one of the subject edits.
    directory : str or pathlib.Path
        Output directory (checked first: :func:`facestats.core.outputs.check_output_dir`;
        the files are written all or none).

    Returns
    -------
    list of pathlib.Path
        The files written.
    """
    _check_edit(edit)
    d = check_output_dir(directory, "directory")
    with OutputSet(d) as out:  # all files or none
        stage_edit_images(edit, out)
    return out.written
