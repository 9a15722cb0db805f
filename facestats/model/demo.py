"""The physics demo: scattering coefficients and dipole profiles from a skin albedo.

Weyrich et al. 2006 §5.4: from an average albedo α_avg and the population's
σtrAvg, invert eq. 16 for the reduced albedo α' and derive σ's and σa; the dipole
(Jensen et al. 2001) then gives the profile R_d(r) and its total reflectance,
which reproduces α_avg.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.conventions import CHANNELS
from facestats.core.outputs import OutputSet, check_output_file
from facestats.core.published import ETA_SKIN, SIGMA_TR_AVG
from facestats.core.validate import as_finite, as_float, check_shape
from facestats.model import dipole
from facestats.model.skin_colour import skin_albedo

__all__ = ["DemoReport", "physics_demo", "light_skin_albedo", "plot_dipole_profiles"]


def light_skin_albedo() -> np.ndarray:
    """Linear sRGB reflectance of the measured ColorChecker 'light skin' patch under D65 (colour-science data)."""
    return skin_albedo(0.0)


@dataclass
class DemoReport:
    """Per-channel subsurface parameters derived from an albedo.

    Attributes
    ----------
    albedo : ndarray, shape (3,)
        Average albedo α_avg (R, G, B), the total diffuse reflectance the parameters reproduce.
    sigma_tr : ndarray, shape (3,)
        σtr in mm⁻¹, recomputed from ``sigma_a`` and ``sigma_s_prime`` (Weyrich eq. 15).
    eta : float
        Relative index of refraction.
    reduced_albedo : ndarray, shape (3,)
        α' from inverting Weyrich eq. 16 (:func:`facestats.model.dipole.reduced_albedo`).
    sigma_s_prime, sigma_a : ndarray, shape (3,)
        Reduced scattering and absorption coefficients in mm⁻¹.
    total_reflectance : ndarray, shape (3,)
        Total diffuse reflectance of the dipole with these coefficients (≈ ``albedo``).
    """

    albedo: np.ndarray
    sigma_tr: np.ndarray
    eta: float
    reduced_albedo: np.ndarray
    sigma_s_prime: np.ndarray
    sigma_a: np.ndarray
    total_reflectance: np.ndarray

    @property
    def ell_d(self):
        """Diffuse mean free path ℓd = 1/σtr in mm."""
        return dipole.diffuse_mean_free_path(self.sigma_tr)

    def to_text(self) -> str:
        """A table of the parameters per channel, with units."""
        rows = [
            ("albedo α_avg", self.albedo, ""),
            ("reduced albedo α'", self.reduced_albedo, ""),
            ("σ's", self.sigma_s_prime, "1/mm"),
            ("σa", self.sigma_a, "1/mm"),
            ("σtr", self.sigma_tr, "1/mm"),
            ("ℓd = 1/σtr", self.ell_d, "mm"),
            ("total diffuse reflectance", self.total_reflectance, ""),
        ]
        head = f"{'':28s}" + "".join(f"{c:>11s}" for c in CHANNELS) + "   unit"
        lines = [f"Dipole parameters from albedo (Weyrich et al. 2006 §5.4, η = {self.eta:g})", head]
        for name, vals, unit in rows:
            lines.append(f"{name:28s}" + "".join(f"{v:11.5f}" for v in vals) + f"   {unit}")
        return "\n".join(lines)


def plot_dipole_profiles(report: DemoReport, r_max: float = 10.0):
    """Figure of R_d(r) (mm⁻², Jensen et al. 2001 dipole) per channel, r in [0, ``r_max``] mm, log scale, ℓd marked.

    Parameters
    ----------
    report : DemoReport
        :func:`physics_demo`'s result: per-channel σ's, σa (mm⁻¹), σtr (ℓd = 1/σtr in mm) and η.
    r_max : float
        Largest distance plotted in mm, > 0 (400 samples from 0).

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    ValidationError
        A non-finite or non-positive ``r_max``.
    """
    as_finite(r_max, "r_max", 0, None, low_inclusive=False, unit="mm")
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    r = np.linspace(0.0, r_max, 400)
    fig, ax = plt.subplots(figsize=(6, 4))
    for c, colour_ in zip(range(3), ("tab:red", "tab:green", "tab:blue")):
        prof = dipole.dipole_profile(r, report.sigma_s_prime[c], report.sigma_a[c], report.eta)
        ax.semilogy(
            r,
            prof,
            color=colour_,
            label=f"{CHANNELS[c]}: σ's={report.sigma_s_prime[c]:.3g}, σa={report.sigma_a[c]:.3g} mm⁻¹",
        )
        ax.axvline(report.ell_d[c], color=colour_, ls=":", lw=1)
    ax.set_xlabel("distance r [mm]  (dotted: ℓd)")
    ax.set_ylabel("R_d(r) [mm⁻²]")
    ax.set_title("Dipole diffuse reflectance profiles")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    return fig


def physics_demo(albedo=None, sigma_tr=None, eta: float = ETA_SKIN, plot: str | None = None) -> DemoReport:
    """Derive σ's, σa, σtr and the total reflectance from an albedo; optionally save the profile plot.

    Parameters
    ----------
    albedo : array_like, shape (3,), optional
        Total diffuse reflectance per channel in (0, 1).  Default: the measured
        ColorChecker 'light skin' patch (:func:`light_skin_albedo`).
    sigma_tr : array_like, shape (3,), optional
        σtr in mm⁻¹.  Default: Weyrich's σtrAvg = [0.5508, 0.9791, 1.5497].
    eta : float
        Relative index of refraction.
    plot : str, optional
        Path of an image file for :func:`plot_dipole_profiles`, with a suffix
        matplotlib can write (``.png``, ``.svg``, ``.pdf``, ...); checked
        before anything is computed, written all or nothing
        (:mod:`facestats.core.outputs`).

    Returns
    -------
    DemoReport
    """
    if plot:
        from matplotlib.backend_bases import FigureCanvasBase

        formats = [f".{k}" for k in FigureCanvasBase.get_supported_filetypes()]
        plot = check_output_file(plot, "plot", suffixes=formats)
    a = light_skin_albedo() if albedo is None else check_shape(as_float(albedo, "albedo"), "albedo", (3,))
    t = SIGMA_TR_AVG.copy() if sigma_tr is None else check_shape(as_float(sigma_tr, "sigma_tr"), "sigma_tr", (3,))
    s_prime, s_a = dipole.scattering_from_albedo(a, t, eta)
    report = DemoReport(
        albedo=np.asarray(a, float),
        sigma_tr=dipole.transport_coefficient(s_a, s_prime),
        eta=float(eta),
        reduced_albedo=dipole.reduced_albedo(a, eta),
        sigma_s_prime=s_prime,
        sigma_a=s_a,
        total_reflectance=dipole.total_diffuse_reflectance(s_prime, s_a, eta),
    )
    if plot:
        import matplotlib.pyplot as plt

        fig = plot_dipole_profiles(report)
        try:
            with OutputSet(plot.parent) as out:
                fig.savefig(out.path(plot.name), dpi=120)
        finally:
            plt.close(fig)
    return report
