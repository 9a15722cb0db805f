"""Suzuki, Mukaigawa & Yagi §4.1 reproduced on the pyramid, and the studies that go beyond it.

* :func:`render_scene` — the pyramid (or any :class:`~facestats.acquire.synthetic.scenes.PatchScene`)
  rendered with the dipole: irradiance c (eq. 16, shadow-mapped), the point
  kernel l = R c (eq. 17, :func:`facestats.acquire.synthetic.subsurface.render_exitance`)
  or the quantised model l = W r (eq. 34) at a given width, and the visible rows.
* :func:`table3` — Table 3: (σ's, σa) for the quantisation widths 8 … 0.03125 mm,
  with the paper's solve (``"pinv"``) and the default (``"monotone"``), beside
  the published row.
* :func:`noise_study` — multiplicative radiance noise (1 %) over seeds: the
  estimates, their spread, and how often the interval covers the truth.

The system W depends only on the scene, not on the image, so the studies build
it once per width and solve it for every image
(:func:`facestats.model.fitting.fit_scattering_system`).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from facestats.acquire.lights import patch_irradiance
from facestats.acquire.scene import camera_sees
from facestats.acquire.synthetic.subsurface import render_exitance
from facestats.core.progress import progress_bar
from facestats.core.published import SUZUKI_TABLE1, SUZUKI_TABLE3
from facestats.core.validate import as_scalar, check_choice, check_integer
from facestats.errors import FitError, QuantisationWarning, ValidationError
from facestats.model.dipole import dipole_profile
from facestats.model.fitting.quantisation_choice import auto_width
from facestats.model.fitting.quantised import SELF_TERMS, quantised_system, self_term_keywords
from facestats.model.fitting.scattering_image import fit_scattering_system

__all__ = ["RenderedScene", "render_scene", "table3", "format_table3", "noise_study", "NoiseStudy"]


@dataclass
class RenderedScene:
    """A scene rendered with known (σ's, σa) (:func:`render_scene`).

    Attributes
    ----------
    patches : facestats.acquire.patches.Patches
        The scene's m patches.
    irradiance : ndarray, shape (m,)
        c (Suzuki eq. 16) per patch, in the rendered channel.
    exitance : ndarray, shape (m,)
        l per patch, in the unit of c: the point kernel (eq. 17) or the quantised model W r (eq. 34).
    visible : ndarray of bool, shape (m,)
        The patches the camera sees: the rows the studies fit.
    sigma_s_prime, sigma_a : float
        The true σ's and σa, mm⁻¹.
    eta : float
        The scene's relative index of refraction.
    kernel : {"point", "quantised"}
        The kernel the exitance was rendered with.
    self_term : {"point", "footprint", "surface"}
        How a patch's own light was taken (:func:`render_scene`); the studies' W takes it the same way.
    """

    patches: object
    irradiance: np.ndarray
    exitance: np.ndarray
    visible: np.ndarray
    sigma_s_prime: float
    sigma_a: float
    eta: float
    kernel: str
    self_term: str = "point"


def render_scene(
    scene, sigma_s_prime=None, sigma_a=None, *, kernel="point", width=None, channel=0, self_term="point"
) -> RenderedScene:
    """Render a patch scene with the dipole (module docstring); default parameters Suzuki Table 1.

    Parameters
    ----------
    scene : PatchScene
    sigma_s_prime, sigma_a : float, optional
        mm⁻¹; default Table 1 (2.19, 0.0021).
    kernel : {"point", "quantised"}
        Point kernel R(d_jk) (eq. 17) or the quantised model W r (eq. 34) at ``width``.
    width : float
        Quantisation width of the quantised kernel, mm.
    channel : int
        Channel of the lights used (0-2).
    self_term : {"point", "footprint", "surface"}
        A patch's own light: eq. 17's R(0) c_j A_j (default, the paper's discretisation and its Table 3) or over
        the disk of its area, as a continuous surface gives it, and with ``"surface"`` the near neighbours' over
        theirs too (:mod:`facestats.model.fitting.quantised`); the studies' W takes it the same way.

    Returns
    -------
    RenderedScene
        The rendered scene.
    """

    check_choice(kernel, "kernel", ("point", "quantised"))
    check_choice(self_term, "self_term", SELF_TERMS)
    s = SUZUKI_TABLE1["sigma_s_prime"] if sigma_s_prime is None else float(sigma_s_prime)
    a = SUZUKI_TABLE1["sigma_a"] if sigma_a is None else float(sigma_a)
    p = scene.patches
    c = patch_irradiance(p, scene.lights, eta=scene.eta)[:, int(channel)]
    seen = camera_sees(scene.camera, p)
    if kernel == "point":
        l = render_exitance(p.centre, p.area, c, s, a, eta=scene.eta, radius=np.inf, self_term=self_term)
    else:
        w = as_scalar(width, "width", 0, None, low_inclusive=False, unit="mm")
        own = self_term_keywords(self_term, p.area)
        system = quantised_system(p.centre, c * p.area, np.arange(len(p)), width=w, **own)
        l = system.matrix @ dipole_profile(system.levels, s, a, scene.eta)
    return RenderedScene(p, c, l, seen, s, a, scene.eta, kernel, self_term)


def _system(rendered, width):
    p = rendered.patches
    own = self_term_keywords(rendered.self_term, p.area)
    return quantised_system(p.centre, rendered.irradiance * p.area, np.nonzero(rendered.visible)[0], width=width, **own)


def table3(rendered: RenderedScene, widths=tuple(SUZUKI_TABLE3), methods=("pinv", "monotone"), **fit_options) -> list:
    """Suzuki Table 3 on a rendered scene: one row per width with each method's estimate and the paper's.

    Parameters
    ----------
    rendered : RenderedScene
        :func:`render_scene`'s result; its visible rows' exitance is fitted.
    widths : sequence of float
        Quantisation widths, mm (default the widths of Suzuki Table 3, 8 … 0.03125 mm).
    methods : sequence of str
        Solve methods of :func:`facestats.model.fitting.fit_scattering_system` (default the paper's ``"pinv"``
        and the default ``"monotone"``).
    **fit_options
        Further keyword arguments of :func:`facestats.model.fitting.fit_scattering_system` (not ``method``,
        ``eta`` or ``width``, which this function passes).

    Returns
    -------
    list of dict
        ``{"width": w, "paper": (σ's, σa), method: (σ's, σa) or None, method + "_fit": fit}``
        (None where the fit failed: fewer than 3 usable levels; ``"paper"`` is None for a width not in Table 3).
    """

    rows = []
    l = rendered.exitance[rendered.visible]
    for w in widths:  # loop over the table's widths
        system = _system(rendered, float(w))
        row = {"width": float(w), "paper": SUZUKI_TABLE3.get(float(w))}
        for method in methods:  # the paper's solve and the default
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", QuantisationWarning)
                try:
                    fit = fit_scattering_system(system, l, method=method, eta=rendered.eta, width=w, **fit_options)
                    row[method], row[method + "_fit"] = (fit.sigma_s_prime, fit.sigma_a), fit
                except FitError:
                    row[method], row[method + "_fit"] = None, None
        rows.append(row)
    return rows


def format_table3(rows, truth=(SUZUKI_TABLE1["sigma_s_prime"], SUZUKI_TABLE1["sigma_a"])) -> str:
    """Table 3 as text: the paper's estimates beside ours, per width (σ's, σa in mm⁻¹).

    Parameters
    ----------
    rows : list of dict
        :func:`table3`'s rows (at least one); the methods are taken from the first row's keys.
    truth : tuple of float
        (σ's, σa) in mm⁻¹ printed as the ``truth`` row, default Suzuki Table 1 (2.19, 0.0021).

    Returns
    -------
    str
        A header, a rule, the truth row and one row per width; a cell whose estimate is None reads ``failed``, the
        paper's cell of a width not in Suzuki Table 3 reads ``-``.

    Raises
    ------
    ValidationError
        ``rows`` is empty.
    """
    rows = list(rows)
    if not rows:
        raise ValidationError("rows must hold at least one row of table3 (one per width), got none")
    methods = [k for k in rows[0] if k not in ("width", "paper") and not k.endswith("_fit")]
    head = f"{'width (mm)':>11} | {'paper':^15} | " + " | ".join(f"{m:^15}" for m in methods)
    lines = [
        head,
        "-" * len(head),
        f"{'truth':>11} | {truth[0]:6.2f} {truth[1]:7.4f} | "
        + " | ".join(f"{truth[0]:6.2f} {truth[1]:7.4f}" for _ in methods),
    ]

    def cell(v, missing="failed"):
        return f"{missing:^15}" if v is None else f"{v[0]:6.2f} {v[1]:7.4f}"

    for r in rows:
        paper = cell(r["paper"], missing="-")  # None: a width Suzuki Table 3 does not list
        lines.append(f"{r['width']:>11g} | {paper} | " + " | ".join(cell(r[m]) for m in methods))
    return "\n".join(lines)


@dataclass
class NoiseStudy:
    """Estimates over noise seeds: arrays (seeds,) of σ's, σa, their intervals (seeds, 2) and coverage.

    Attributes
    ----------
    sigma_s_prime, sigma_a : ndarray, shape (seeds,)
        The estimates, mm⁻¹.
    sigma_s_prime_interval, sigma_a_interval : ndarray, shape (seeds, 2)
        Their intervals (low, high), mm⁻¹.
    widths : ndarray, shape (seeds,)
        The quantisation width used, mm (the same for every seed).
    truth : tuple of float
        The true (σ's, σa), mm⁻¹.
    noise : float
        Relative standard deviation of the radiance noise.
    """

    sigma_s_prime: np.ndarray
    sigma_a: np.ndarray
    sigma_s_prime_interval: np.ndarray
    sigma_a_interval: np.ndarray
    widths: np.ndarray
    truth: tuple
    noise: float

    @property
    def covered(self) -> np.ndarray:
        """Seeds whose joint interval holds both true values."""
        s, a = self.truth
        return (
            (self.sigma_s_prime_interval[:, 0] <= s)
            & (s <= self.sigma_s_prime_interval[:, 1])
            & (self.sigma_a_interval[:, 0] <= a)
            & (a <= self.sigma_a_interval[:, 1])
        )

    def summary(self) -> dict:
        """The study's figures as a JSON-ready dict: seeds, noise, largest errors, spreads and interval coverage."""
        s, a = self.truth
        ds, da = self.sigma_s_prime - s, self.sigma_a - a
        return {
            "seeds": int(ds.size),
            "noise": self.noise,
            "max_abs_error_sigma_s_prime": float(np.abs(ds).max()),
            "max_abs_error_sigma_a": float(np.abs(da).max()),
            "std_sigma_s_prime": float(self.sigma_s_prime.std(ddof=1)) if ds.size > 1 else 0.0,
            "std_sigma_a": float(self.sigma_a.std(ddof=1)) if ds.size > 1 else 0.0,
            "coverage": float(self.covered.mean()),
        }


def noise_study(rendered: RenderedScene, *, noise=0.01, seeds=20, width="auto", method="monotone", progress=False):
    """Fit ``seeds`` images with multiplicative Gaussian radiance noise of relative std ``noise`` (module docstring).

    With ``width="auto"`` the width is chosen once (on the first image) and the
    system reused: the choice depends on the geometry, not on the noise.

    Parameters
    ----------
    rendered : RenderedScene
        The noise-free render (its patches, visibility, exitance and true σ's, σa).
    noise : float
        Relative standard deviation of the radiance noise, in [0, 1].
    seeds : int
        Number of noisy images (seeds 0 … seeds − 1 of numpy's default generator).
    width : "auto" or float
        Quantisation width, mm (:func:`facestats.model.fitting.fit_scattering_image`).
    method : str
        Solve of the quantised system, as :func:`facestats.model.fitting.fit_scattering_system`.
    progress : bool
        Show a progress bar over the seeds.

    Returns
    -------
    NoiseStudy
        Per seed: σ's, σa (mm⁻¹), their intervals and the width used.
    """

    check_integer(seeds, "seeds", 1)
    nz = as_scalar(noise, "noise", 0, 1)
    p = rendered.patches
    rows = np.nonzero(rendered.visible)[0]
    w = auto_width(p.centre, rendered.irradiance * p.area, rows)[0] if width == "auto" else float(width)
    system = _system(rendered, w)
    it = range(int(seeds))
    it = progress_bar(it, desc="noise seeds", unit="image", enabled=progress)
    out = []
    for seed in it:  # loop over noisy images; each solve is vectorised
        rng = np.random.default_rng(seed)
        l = rendered.exitance[rows] * (1 + nz * rng.standard_normal(rows.size))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", QuantisationWarning)
            fit = fit_scattering_system(system, np.maximum(l, 0), method=method, eta=rendered.eta, width=w)
        out.append(fit)
    return NoiseStudy(
        sigma_s_prime=np.array([f.sigma_s_prime for f in out]),
        sigma_a=np.array([f.sigma_a for f in out]),
        sigma_s_prime_interval=np.array([f.sigma_s_prime_interval for f in out]),
        sigma_a_interval=np.array([f.sigma_a_interval for f in out]),
        widths=np.full(len(out), w),
        truth=(rendered.sigma_s_prime, rendered.sigma_a),
        noise=nz,
    )
