"""The residual of each fitted specular model against its capture, by angle (Weyrich et al. 2006 §5.3, Fig. 7).

§5.3 compares renderings of the spatially varying Blinn-Phong and Torrance-Sparrow
fits with the photographs and finds that Blinn-Phong "overestimates the specular
component" (Fig. 7c).  :func:`residuals_by_angle` measures where: every valid
sample of a capture is rendered with each fitted model
(:func:`facestats.pipeline.render.predict_radiance`, the same renderer the
held-out camera check uses), and the residual (model − measurement, grey: the
mean of R, G, B) is binned by the larger of θi and θo about the fitted normal —
the angle at which Torrance-Sparrow's G F/(N·ωi N·ωo) grows and a Blinn-Phong
lobe does not.  Residuals are divided by the RMS measured radiance of the
samples within the fit's domain (θ < 80°), so the bins of one model add up (in
quadrature, weighted by their sample fractions) to its relative RMSE.
:func:`plot_residual_by_angle` draws the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.published import GRAZING_LIMIT_DEG
from facestats.core.validate import as_finite, check_integer
from facestats.errors import ValidationError
from facestats.face.geometry import uv_to_texel
from facestats.pipeline.render import predict_radiance
from facestats.pipeline.settings import MAP_VARS, MODEL_PREFIX

__all__ = ["AngleResiduals", "residuals_by_angle", "plot_residual_by_angle"]

_LABEL = {"torrance_sparrow": "Torrance-Sparrow", "blinn_phong": "Blinn-Phong"}


@dataclass
class AngleResiduals:
    """Residuals of the fitted models by angle (:func:`residuals_by_angle`).

    Attributes
    ----------
    edges : ndarray, shape (B + 1,)
        Bin edges of max(θi, θo), degrees.
    fraction : ndarray, shape (B,)
        Share of the samples in each bin.
    rms : dict
        ``{model: (B,) RMS residual / RMS measurement}`` per bin.
    mean : dict
        ``{model: (B,) mean residual / RMS measurement}`` per bin (> 0: the model predicts too much).
    relative_rmse : dict
        ``{model: float}`` over the samples below ``max_angle_deg``.
    samples : int
    subject_id : str
    """

    edges: np.ndarray
    fraction: np.ndarray
    rms: dict
    mean: dict
    relative_rmse: dict
    samples: int
    subject_id: str = ""

    def to_dict(self) -> dict:
        """JSON-ready: ``edges_deg``, ``fraction``, ``rms``, ``mean`` (lists per model), ``relative_rmse``."""
        return {
            "subject_id": self.subject_id,
            "samples": int(self.samples),
            "edges_deg": [float(e) for e in self.edges],
            "fraction": [float(f) for f in self.fraction],
            "rms": {m: [float(x) for x in v] for m, v in self.rms.items()},
            "mean": {m: [float(x) for x in v] for m, v in self.mean.items()},
            "relative_rmse": {m: float(v) for m, v in self.relative_rmse.items()},
        }

    def to_text(self) -> str:
        """A table: one row per angle bin, RMS and mean residual of each model."""
        models = list(self.rms)
        head = "max(θi,θo)  share  " + "  ".join(f"{_LABEL[m][:16]:>16} rms/mean" for m in models)
        rows = [head]
        for b in range(len(self.fraction)):
            cells = "  ".join(f"{self.rms[m][b]:>12.3f} {self.mean[m][b]:+.3f}" for m in models)
            rows.append(f"{self.edges[b]:4.0f}-{self.edges[b + 1]:<4.0f}°  {self.fraction[b]:5.2f}  {cells}")
        rows.append("relative RMSE: " + ", ".join(f"{_LABEL[m]} {v:.3f}" for m, v in self.relative_rmse.items()))
        return "\n".join(rows)


def residuals_by_angle(subject, capture, *, models=None, edges=None, max_angle_deg=GRAZING_LIMIT_DEG, cameras=None):
    """Residual of each fitted model by max(θi, θo) over a capture's samples (module docstring).

    Parameters
    ----------
    subject : xarray.Dataset
        A subject fitted to ``capture`` (:func:`facestats.pipeline.fit_subject`; its
        ``normal`` map and the maps of each model).
    capture : Capture
    models : sequence of {"torrance_sparrow", "blinn_phong"}, optional
        Default: every model the subject holds.
    edges : array_like, optional
        Bin edges in degrees (default 0, 20, 40, 50, 60, 65, 70, 75, 80).
    max_angle_deg : float
        Samples beyond it are left out (the fit's domain, eq. 14: 80°).
    cameras : sequence of int, optional
        Only these cameras' samples (e.g. a camera held out of the fit).

    Returns
    -------
    AngleResiduals
    """

    as_finite(max_angle_deg, "max_angle_deg", 0, 90, low_inclusive=False, unit="deg")
    edges = np.asarray([0, 20, 40, 50, 60, 65, 70, 75, max_angle_deg] if edges is None else edges, np.float64)
    if edges.ndim != 1 or edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ValidationError(f"edges must be increasing bin edges in degrees, got {edges.tolist()!r}")
    if models is None:
        models = [m for m, k in MODEL_PREFIX.items() if MAP_VARS[k][0] in subject.data_vars]
    angle, meas, preds = _samples(subject, capture, models, cameras, predict_radiance)
    inside = angle < max_angle_deg
    scale = np.sqrt(np.mean(meas[inside] ** 2))
    which = np.clip(np.searchsorted(edges, angle, side="right") - 1, 0, edges.size - 2)
    within = inside & (angle >= edges[0]) & (angle < edges[-1])
    counts = np.bincount(which[within], minlength=edges.size - 1)
    rms, mean, rel = {}, {}, {}
    for m in models:
        r = (preds[m] - meas) / scale
        with np.errstate(invalid="ignore", divide="ignore"):
            rms[m] = np.sqrt(np.bincount(which[within], r[within] ** 2, edges.size - 1) / counts)
            mean[m] = np.bincount(which[within], r[within], edges.size - 1) / counts
        rel[m] = float(np.sqrt(np.mean(r[inside] ** 2)))
    return AngleResiduals(
        edges=edges,
        fraction=counts / max(counts.sum(), 1),
        rms=rms,
        mean=mean,
        relative_rmse=rel,
        samples=int(within.sum()),
        subject_id=str(subject.attrs.get("subject_id", "")),
    )


def _samples(subject, capture, models, cameras, predict_radiance):
    """max(θi, θo) (deg), grey measured radiance and each model's grey prediction of the valid samples."""

    preds, meas = {}, None
    for m in models:
        pred, measured = predict_radiance(subject, capture, specular=m)
        preds[m] = pred.mean(-1)
        meas = measured.mean(-1)
    lt = capture.lumitexels()
    texel = uv_to_texel(lt.uv, int(subject.sizes["u"]))
    normal = np.asarray(subject["normal"].values)[texel[:, 0], texel[:, 1]].astype(np.float64)
    ci = np.einsum("nk,nlk->nl", normal, lt.wi)  # (n, L)
    co = np.einsum("nk,nck->nc", normal, lt.wo)  # (n, C)
    angle = np.degrees(np.arccos(np.clip(np.minimum(ci[:, None, :], co[:, :, None]), -1, 1)))  # (n, C, L)
    keep = np.isfinite(meas)
    if cameras is not None:
        cams = np.zeros(meas.shape[1], bool)
        cams[[check_integer(c, "cameras", 0, meas.shape[1] - 1) for c in cameras]] = True
        keep &= cams[None, :, None]
    return angle[keep], meas[keep], {m: p[keep] for m, p in preds.items()}


def plot_residual_by_angle(result, ax=None):
    """RMS and mean residual of each model against max(θi, θo) (a :class:`AngleResiduals`); returns the figure.

    The share of the samples per bin is drawn as grey bars on a second y axis.

    Parameters
    ----------
    result : AngleResiduals
        :func:`residuals_by_angle`'s result.
    ax : matplotlib.axes.Axes, optional
        Axes to draw into (default a new :class:`matplotlib.figure.Figure`, not registered with pyplot).

    Returns
    -------
    matplotlib.figure.Figure
        The figure of ``ax``.
    """
    from matplotlib.figure import Figure

    if ax is None:
        fig = Figure(figsize=(6.4, 4.2), layout="constrained")
        ax = fig.add_subplot()
    else:
        fig = ax.figure
    centres = 0.5 * (result.edges[:-1] + result.edges[1:])
    colours = {"torrance_sparrow": "tab:blue", "blinn_phong": "tab:red"}
    for m in result.rms:
        label = f"{_LABEL[m]} (relative RMSE {result.relative_rmse[m]:.3f})"
        ax.plot(centres, result.rms[m], "o-", color=colours.get(m), label=f"{label}: RMS")
        ax.plot(
            centres, result.mean[m], "s--", color=colours.get(m), alpha=0.7, label=f"{_LABEL[m]}: mean (model − data)"
        )
    ax.axhline(0, color="0.6", lw=0.8)
    ax2 = ax.twinx()
    ax2.bar(centres, result.fraction, width=0.8 * np.diff(result.edges), color="0.85", zorder=0)
    ax2.set_ylabel("share of samples")
    ax.set_zorder(ax2.get_zorder() + 1)
    ax.patch.set_visible(False)
    ax.set_xlabel("max(θi, θo) about the fitted normal (°)")
    ax.set_ylabel("residual / RMS radiance")
    ax.set_title(f"Model residual by angle {result.subject_id}".strip())
    ax.legend(fontsize=7, loc="upper left")
    return fig
