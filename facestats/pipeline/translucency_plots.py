"""Figures of translucency from one image: Suzuki et al. Fig. 5 (measured R'_i and the fitted dipole), Table 3, faces.

Every function takes result objects and returns a :class:`matplotlib.figure.Figure`
(matplotlib is imported inside them).
"""

from __future__ import annotations

import numpy as np

from facestats.model.dipole import dipole_profile

__all__ = ["plot_profile_fit", "plot_noise_study", "plot_contactless"]

_COLOURS = ("tab:red", "tab:green", "tab:blue", "k")


def plot_profile_fit(fits, labels=None, *, title=None):
    """Suzuki et al. Fig. 5: measured R'_i (points) and the fitted dipole (line) on a log scale, per fit.

    Levels left out of the fit (beyond its range or with R' ≤ 0) are drawn hollow;
    the dashed line marks the fit range.

    Parameters
    ----------
    fits : ScatteringImageFit or list/tuple of ScatteringImageFit
        Results of :func:`facestats.model.fitting.fit_scattering_image` (levels in mm, R' in mm⁻²).
    labels : sequence of str, optional
        One name per fit (default ``"fit 1"``, ``"fit 2"``, ...).
    title : str, optional
        The axes' title (default names Suzuki et al. Fig. 5).

    Returns
    -------
    matplotlib.figure.Figure
        A pyplot figure (close it when done).
    """
    import matplotlib.pyplot as plt

    fits = list(fits) if isinstance(fits, (list, tuple)) else [fits]
    labels = labels or [f"fit {k + 1}" for k in range(len(fits))]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for k, (fit, name) in enumerate(zip(fits, labels)):
        col = _COLOURS[k % len(_COLOURS)] if len(fits) > 1 else "k"
        used = fit.profile_fit.used
        pos = fit.profile > 0
        ax.plot(fit.levels[used], fit.profile[used], "o", ms=3, color=col, label=f"{name}: measured R'")
        ax.plot(fit.levels[~used & pos], fit.profile[~used & pos], "o", ms=3, mfc="none", color=col, alpha=0.5)
        d = np.linspace(0, fit.levels[-1], 400)
        ax.plot(
            d,
            dipole_profile(d, fit.sigma_s_prime, fit.sigma_a, fit.eta),
            "-",
            color=col,
            label=f"{name}: dipole σ's={fit.sigma_s_prime:.3g}, σa={fit.sigma_a:.3g} mm⁻¹",
        )
        ax.axvline(fit.max_distance, ls="--", lw=0.8, color=col)
    ax.set_yscale("log")
    ax.set_xlabel("distance d (mm)")
    ax.set_ylabel("R(d) (mm⁻²)")
    ax.set_title(title or "Measured profile and fitted dipole (Suzuki et al. Fig. 5)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


def plot_noise_study(study, *, title=None):
    """Estimates and intervals of a :class:`~facestats.pipeline.suzuki_studies.NoiseStudy` against the truth.

    Parameters
    ----------
    study : NoiseStudy
        :func:`facestats.pipeline.suzuki_studies.noise_study`'s result.
    title : str, optional
        The figure's title (default: the noise level and the share of intervals that cover the truth).

    Returns
    -------
    matplotlib.figure.Figure
        A pyplot figure with two panels, σ's and σa (mm⁻¹) per seed (close it when done).
    """
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(8, 3.4))
    seeds = np.arange(study.sigma_s_prime.size)
    for ax, est, itv, truth, name in (
        (axes[0], study.sigma_s_prime, study.sigma_s_prime_interval, study.truth[0], "σ's (mm⁻¹)"),
        (axes[1], study.sigma_a, study.sigma_a_interval, study.truth[1], "σa (mm⁻¹)"),
    ):
        ax.errorbar(seeds, est, yerr=[est - itv[:, 0], itv[:, 1] - est], fmt="o", ms=3, capsize=2)
        ax.axhline(truth, color="k", lw=1, label="truth")
        ax.set_xlabel("noise seed")
        ax.set_ylabel(name)
        ax.legend(fontsize=7)
    fig.suptitle(title or f"{study.noise:.0%} radiance noise: {study.covered.mean():.0%} of intervals cover the truth")
    fig.tight_layout()
    return fig


def plot_contactless(table, *, title=None):
    """σtr from images against the truth and the contact sensor, per site and channel (a study's DataFrame).

    Parameters
    ----------
    table : pandas.DataFrame
        :func:`facestats.pipeline.contactless.contactless_study`'s result: columns ``site``, ``channel``,
        ``truth``, ``sensor`` and ``image`` (σtr, mm⁻¹); rows of sites other than cheek and forehead are not drawn.
    title : str, optional
        The figure's title.

    Returns
    -------
    matplotlib.figure.Figure
        A pyplot figure with two panels, image against truth and against the sensor (close it when done).
    """
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(8, 3.8))
    for ax, ref, name in ((axes[0], "truth", "truth"), (axes[1], "sensor", "contact-sensor fit")):
        for ch, col in zip("RGB", _COLOURS):
            for site, marker in (("cheek", "o"), ("forehead", "s")):
                sel = (table["channel"] == ch) & (table["site"] == site)
                ax.plot(
                    table.loc[sel, ref],
                    table.loc[sel, "image"],
                    marker,
                    ms=4,
                    color=col,
                    mfc="none",
                    label=f"{site} {ch}",
                )
        lim = [0, 1.05 * float(max(table["image"].max(), table[ref].max()))]
        ax.plot(lim, lim, "k-", lw=0.8)
        ax.set_xlabel(f"σtr, {name} (mm⁻¹)")
        ax.set_ylabel("σtr from one image (mm⁻¹)")
        err = float(np.median(np.abs(table["image"] / table[ref] - 1)))
        ax.set_title(f"median |relative error| {err:.2%}", fontsize=9)
    axes[0].legend(fontsize=6, ncol=2)
    fig.suptitle(title or "Contactless translucency (one image per site)")
    fig.tight_layout()
    return fig
