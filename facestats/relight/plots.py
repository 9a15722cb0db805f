"""Figures of relighting results: each function returns a :class:`matplotlib.figure.Figure` (no pyplot state).

* :func:`plot_relit` — relit images side by side (tone-mapped with one exposure each);
* :func:`plot_compression` — relighting error against compression ratio;
* :func:`plot_separation` — the maps of a colour-space separation (Debevec et al. 2000 Fig. 14);
* :func:`plot_reflectance_functions` — reflectance functions of chosen pixels as lat-long images (Fig. 4).
"""

from __future__ import annotations

import numpy as np

from facestats.core.validate import check_integer
from facestats.errors import ValidationError
from facestats.relight.display import exposure_scale

__all__ = ["plot_relit", "plot_compression", "plot_separation", "plot_reflectance_functions"]


def _figure(**kwargs):
    from matplotlib.figure import Figure

    return Figure(layout="constrained", **kwargs)


def _srgb(image, mask=None, scale=None):
    # local import: keeps facestats.io (22 modules) out of this module's import
    from facestats.io.images import linear_to_srgb

    s = exposure_scale(image, mask) if scale is None else scale
    return linear_to_srgb(np.clip(np.asarray(image) * s, 0, 1))


def plot_relit(images: dict, mask=None, *, shared_exposure: bool = False, ncols: int = 4):
    """Relit images ``{title: (H, W, 3) linear image}`` in a grid, sRGB tone-mapped.

    Each image gets its own exposure (its 99th luminance percentile at 0.9)
    unless ``shared_exposure``, which uses the first image's for all (to compare brightness).

    Parameters
    ----------
    images : dict
        Title → linear image, shape (H, W, 3), in panel order; at least one.
    mask : array_like of bool, shape (H, W), optional
        The subject's pixels, over which the exposure is chosen (:func:`~facestats.relight.display.exposure_scale`).
    shared_exposure : bool
        One exposure (the first image's) for all.
    ncols : int
        Panels per row at most, ≥ 1.

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValidationError
        If ``images`` is empty or ``ncols`` < 1.
    """
    names = list(images)
    n = len(names)
    if n == 0:
        raise ValidationError("images must hold at least one relit image, got an empty dict")
    cols = min(check_integer(ncols, "ncols", 1), n)
    rows = int(np.ceil(n / cols))
    fig = _figure(figsize=(2.6 * cols, 2.7 * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    scale = exposure_scale(images[names[0]], mask) if shared_exposure else None
    for ax, name in zip(axes.flat, names):
        ax.imshow(_srgb(images[name], mask, scale), interpolation="nearest")
        ax.set_title(name, fontsize=9)
    for ax in axes.flat:
        ax.axis("off")
    return fig


def plot_compression(ratios, errors: dict, *, target: float = 0.03, metric: str = "max relative error"):
    """Relighting error against compression ratio, one curve per probe (``errors``: name → values per ratio).

    Parameters
    ----------
    ratios : array_like, shape (n,)
        Compression ratios (dense / stored values), the x axis (log scale).
    errors : dict
        Probe name → error at each ratio, shape (n,) (log scale: positive values).
    target : float
        Error drawn as a dashed horizontal line.
    metric : str
        Label of the y axis.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig = _figure(figsize=(5, 3.4))
    ax = fig.subplots()
    for name, err in errors.items():
        ax.plot(ratios, err, "o-", label=name)
    ax.axhline(target, color="k", lw=0.8, ls="--", label=f"target {target:g}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("compression ratio (dense / stored values)")
    ax.set_ylabel(metric)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    return fig


def plot_separation(separation, mask=None):
    """Normals (RGB = xyz/2 + ½), diffuse albedo ρd, specular energy ρs and the ramp α₀, α₁ of a separation.

    Parameters
    ----------
    separation : xarray.Dataset
        :func:`facestats.relight.separate.separate_field`'s result (``normal``, ``albedo``, ``rho_s``, ``alpha0``,
        ``alpha1`` are used); the albedo is tone-mapped with its own exposure.
    mask : array_like of bool, shape (y, x), optional
        Pixels to show (default all); outside it normals are white and the scalar maps blank.

    Returns
    -------
    matplotlib.figure.Figure
        One row of five panels, colour bars on ρs, α₀ and α₁.
    """
    m = np.ones(separation["rho_s"].shape, bool) if mask is None else np.asarray(mask, bool)
    normal = np.nan_to_num(separation["normal"].values) * 0.5 + 0.5
    albedo = np.nan_to_num(separation["albedo"].values)
    panels = [
        ("normal n (xyz → RGB)", np.where(m[..., None], normal, 1.0), None),
        ("diffuse albedo ρd", _srgb(albedo, m), None),
        ("specular energy ρs", np.where(m, separation["rho_s"].values, np.nan), "magma"),
        ("ramp α₀", np.where(m, separation["alpha0"].values, np.nan), "coolwarm"),
        ("ramp α₁", np.where(m, separation["alpha1"].values, np.nan), "coolwarm"),
    ]
    fig = _figure(figsize=(2.9 * len(panels), 2.9))
    axes = fig.subplots(1, len(panels))
    for ax, (title, img, cmap) in zip(axes, panels):
        im = ax.imshow(img, cmap=cmap, interpolation="nearest")
        if cmap is not None:
            fig.colorbar(im, ax=ax, fraction=0.046)
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    return fig


def plot_reflectance_functions(field, pixels, *, centre_camera: bool = True):
    """Reflectance functions of ``pixels`` [(y, x), ...] of a lat-long field as images (Debevec Fig. 4).

    With ``centre_camera`` the azimuth is rolled so that the frontal camera's
    direction (+z) is in the middle, as Debevec displays them.

    Parameters
    ----------
    field : xarray.Dataset
        A lat-long grid field (``reflectance`` dims ``light_phi``, ``light_theta``, ``y``, ``x``, ``channel``); its
        values are read into memory.
    pixels : sequence of (int, int)
        (y, x) of the pixels to show, one panel each.
    centre_camera : bool
        Roll the azimuth by half a turn (+z to the centre column).

    Returns
    -------
    matplotlib.figure.Figure
        Each function tone-mapped with its own exposure, sRGB.

    Raises
    ------
    ValidationError
        If ``reflectance`` is not 5-dimensional (a list field).
    """
    vals = np.asarray(field["reflectance"].values)
    if vals.ndim != 5:
        raise ValidationError(
            f"field must be a lat-long grid field (light_phi, light_theta, y, x, 3), got {vals.shape}"
        )
    n_theta = vals.shape[1]
    fig = _figure(figsize=(3.2 * len(pixels), 2.0))
    axes = fig.subplots(1, len(pixels), squeeze=False)
    for ax, (y, x) in zip(axes.flat, pixels):
        f = vals[:, :, y, x, :]
        if centre_camera:
            f = np.roll(f, n_theta // 2, axis=1)
        ax.imshow(_srgb(f), interpolation="nearest")
        ax.set_title(f"pixel (y={y}, x={x})", fontsize=9)
        ax.set_xlabel("θ (azimuth)")
        ax.set_ylabel("φ (from +y)")
        ax.set_xticks([])
        ax.set_yticks([])
    return fig
