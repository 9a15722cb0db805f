"""Figures of microstructure deformation: kernel tables and fits (Nagano et al. 2015 Fig. 11-12), strain, normals.

Every function takes result objects, imports matplotlib itself and returns a
:class:`matplotlib.figure.Figure` (no pyplot state: nothing is shown or saved here).
"""

from __future__ import annotations

import numpy as np

from facestats.model.microstructure.surface import normal_histogram
from facestats.model.microstructure.tables import FIG11, FOREHEAD

__all__ = ["plot_kernel_table", "plot_fit", "plot_strain", "plot_before_after"]


def _figure(rows, cols, figsize):
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(rows, cols)


def plot_kernel_table(table=FOREHEAD, fits=None, *, profiles=None, published=True, r_range=(0.7, 1.35)):
    """α(r) and σ(r) of a kernel table with fitted points (Nagano et al. 2015 Fig. 12).

    Parameters
    ----------
    table : KernelTable
    fits : sequence of (r, α, σ_µm) or of (r, KernelFit), optional
        Fitted points (the argmin of each fit, e.g. of synthetic patch pairs).
    profiles : sequence of (r, α, σ_µm), optional
        Profile points: α fitted with σ fixed to the table's, σ with α fixed.
    published : bool
        Also plot the published Fig. 11 points.
    r_range : (float, float)
        The stretch ratios r plotted (1: neutral).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    r = np.linspace(*r_range, 400)
    fig, axes = _figure(1, 2, (10, 3.8))
    below, above = r < 1, r >= 1
    axes[0].plot(r, table.alpha(r), "k-", label=f"table ({table.name})")
    axes[1].plot(r[below], table.sigma(r[below]), "k-", label=f"table ({table.name})")
    axes[1].plot(r[above], table.sigma(r[above]), "k-")
    if published:
        pts = np.asarray(FIG11)
        axes[0].plot(pts[:, 0], pts[:, 1], "s", mfc="none", color="tab:gray", label="Nagano Fig. 11")
        axes[1].plot(pts[:, 0], pts[:, 2], "s", mfc="none", color="tab:gray", label="Nagano Fig. 11")
    if fits:
        pts = np.array([(f[0], f[1].alpha, f[1].sigma_um) if len(f) == 2 else f for f in fits], float)
        axes[0].plot(pts[:, 0], pts[:, 1], "o", color="tab:red", label="fitted (argmin)")
        axes[1].plot(pts[:, 0], pts[:, 2], "o", color="tab:red", label="fitted (argmin)")
    if profiles:
        pts = np.asarray(profiles, float)
        axes[0].plot(pts[:, 0], pts[:, 1], "^", color="tab:blue", label="α given the table's σ")
        axes[1].plot(pts[:, 0], pts[:, 2], "v", color="tab:blue", label="σ given the table's α")
    for ax, name in zip(axes, ("α", "σ (µm)")):
        ax.axvline(1, color="0.8", lw=0.8)
        ax.set_xlabel("stretch ratio r")
        ax.set_ylabel(name)
        ax.legend(fontsize=8)
    axes[0].axhline(0, color="0.8", lw=0.8)
    fig.set_layout_engine("tight")
    return fig


def plot_fit(fit):
    """TV landscape of a :class:`~facestats.model.microstructure.fit.KernelFit` with its ridge, and both histograms.

    Parameters
    ----------
    fit : KernelFit
        The fit: its total-variation grid (eq. 7) over (α, σ µm), ridge, argmin and target and fitted normal
        histograms.

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    fig, axes = _figure(1, 3, (13, 3.8))
    grid = np.ma.masked_invalid(fit.tv_grid)
    im = axes[0].pcolormesh(fit.sigmas_um, fit.alphas, grid, shading="auto", cmap="viridis")
    fig.colorbar(im, ax=axes[0], label="total variation (eq. 7)")
    axes[0].plot(fit.ridge[:, 1], fit.ridge[:, 0], ".", ms=1.5, color="w", alpha=0.6, label="ridge")
    axes[0].plot(fit.sigma_um, fit.alpha, "r*", ms=10, label=f"argmin α={fit.alpha:.2f}, σ={fit.sigma_um:.1f} µm")
    axes[0].set_xlabel("σ (µm)")
    axes[0].set_ylabel("α")
    axes[0].legend(fontsize=7, loc="lower right")
    e = fit.extent
    for ax, h, title in (
        (axes[1], fit.target_histogram, "target (deformed)"),
        (axes[2], fit.fitted_histogram, "fitted"),
    ):
        ax.imshow(h, extent=(-e, e, e, -e), cmap="magma")
        ax.set_title(title)
        ax.set_xlabel("n_u")
        ax.set_ylabel("n_v")
    fig.set_layout_engine("tight")
    return fig


def plot_strain(strain, *, step=None, limits=(0.8, 1.25)):
    """Stretches r_s, r_t and the stretch axis field of a :class:`~facestats.model.strain.TexelStrain` (Fig. 13).

    Axes are drawn as headless segments (their sign is meaningless), coloured by r_s.

    Parameters
    ----------
    strain : TexelStrain
        Per-texel stretches, axes and ``valid`` mask (texels off the mesh are masked).
    step : int, optional
        Texels between drawn axes; default min(H, W) // 40 (at least 1).
    limits : (float, float)
        Colour range of the stretch ratios, below and above 1 (the neutral ratio is the colour map's centre).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """
    from matplotlib.colors import TwoSlopeNorm

    h, w = strain.r_s.shape
    norm = TwoSlopeNorm(vmin=limits[0], vcenter=1.0, vmax=limits[1])
    fig, axes = _figure(1, 3, (14, 4.6))
    for ax, field, title in ((axes[0], strain.r_s, "r_s (largest stretch)"), (axes[1], strain.r_t, "r_t (smallest)")):
        im = ax.imshow(np.ma.masked_where(~strain.valid, field), cmap="RdBu_r", norm=norm)
        ax.set_title(title)
        fig.colorbar(im, ax=ax, fraction=0.046)
    step = step or max(1, min(h, w) // 40)
    yy, xx = np.mgrid[step // 2 : h : step, step // 2 : w : step]
    ok = strain.valid[yy, xx]
    a = strain.axis_s[yy, xx]
    axes[2].imshow(np.where(strain.valid, 0.93, 1.0), cmap="gray", vmin=0, vmax=1)
    q = axes[2].quiver(xx[ok], yy[ok], a[ok][:, 0], a[ok][:, 1], strain.r_s[yy, xx][ok], cmap="RdBu_r", norm=norm,
                       angles="xy", pivot="middle", headwidth=0, headlength=0, headaxislength=0, scale=1.4 / step,
                       scale_units="xy", width=0.004)  # fmt: skip
    axes[2].set_title("stretch axis s (colour: r_s)")
    fig.colorbar(q, ax=axes[2], fraction=0.046)
    for ax in axes:
        ax.set_xlabel("u (texels)")
        ax.set_ylabel("v (texels)")
    fig.set_layout_engine("tight")
    return fig


def plot_before_after(neutral, deformed, neutral_normals, *, bins=64, extent=None, crop=None):
    """Neutral and deformed displacement, normal maps (RGB = normal / 2 + 1/2) and their normal histograms.

    Parameters
    ----------
    neutral : ndarray (H, W)
    deformed : DeformedMicrostructure
    neutral_normals : ndarray (H, W, 3)
    bins : int
        Bins per axis of the normal histograms (:func:`facestats.model.microstructure.surface.normal_histogram`).
    extent : float, optional
        Half-width of the histograms in normal components (n_u, n_v), in (0, 1], as in
        :func:`~facestats.model.microstructure.surface.normal_histogram`; default 1.1 × the 99.9th percentile of
        |n_u|, |n_v| over both maps.
    crop : (slice, slice), optional
        Part of the maps to show (histograms use the whole maps).

    Returns
    -------
    matplotlib.figure.Figure
        The figure.
    """

    crop = crop or (slice(None), slice(None))
    nn, dn = neutral_normals, deformed.normals
    if extent is None:
        extent = float(np.quantile(np.abs(np.concatenate([nn[..., :2].ravel(), dn[..., :2].ravel()])), 0.999)) * 1.1
    fig, axes = _figure(2, 3, (12, 8))
    lo, hi = np.percentile(neutral, [1, 99])
    for row, (disp, nrm, label) in enumerate(((neutral, nn, "neutral"), (deformed.displacement, dn, "deformed"))):
        axes[row, 0].imshow(disp[crop], cmap="gray", vmin=lo, vmax=hi)
        axes[row, 0].set_title(f"{label} displacement (µm)")
        axes[row, 1].imshow(np.clip(nrm[crop] * 0.5 + 0.5, 0, 1))
        axes[row, 1].set_title(f"{label} tangent normals")
        gx, gy = -nrm[..., 0] / nrm[..., 2], -nrm[..., 1] / nrm[..., 2]
        hist = normal_histogram(gx, gy, bins=bins, extent=extent)
        axes[row, 2].imshow(hist, extent=(-extent, extent, extent, -extent), cmap="magma")
        axes[row, 2].set_title(f"{label} normal histogram")
        axes[row, 2].set_xlabel("n_u")
        axes[row, 2].set_ylabel("n_v")
    fig.set_layout_engine("tight")
    return fig
