"""The batch bounded Levenberg-Marquardt solver of eq. 14 over all texels at once (Weyrich et al. 2006 §5.3).

Minimises, per texel, E(p)² = Σ [y − ρs g(p)]² with y = f_s cos θi over the
samples of eq. 14 (w = 1), for the lobes of :mod:`facestats.model.fitting.lobes`:

* Parameters (ρs, q = ln p): the lobe parameter is solved in log space, where
  the problem is well scaled.  Bounds are enforced by projection of each step,
  with per-texel damping λ (accepted steps divide it by 3, rejected ones
  multiply it by 4).
* Start: a weighted log-linear fit of ln(y/A) against z over the strongest
  samples gives p₀ (the slope is −1/m², or n); ρs₀ then follows in closed form
  and p₀ starts the iteration (see ``_COLD_STARTS``), unless a start is given
  (a previous fit, or the Beckmann-equivalent lobe of another model).
* Convergence: a texel stops when the Gauss-Newton decrement bᵀH⁻¹b (the most
  a full step could still lower E²) is below ``tol``/10 of E², when an accepted
  step changes E² by less than ``tol`` relative, when a step (accepted or not)
  changes ρs by less than 10⁻⁵ relative and ln p by less than 10⁻⁵, or when λ
  exceeds 10¹⁰.  (The decrement test saves the confirming evaluation; at
  ``tol``/10 the parameters stay within 2·10⁻³ relative of a fit run to
  tol = 10⁻¹³, as close as the E²-change test alone gets.)
* When fewer than 70 % of the texels are still moving the converged ones leave
  the working set.
* With ``d`` (∂y/∂α per sample), the grey diffuse level of eq. 10 is then fitted
  with (ρs, q) (:mod:`facestats.model.fitting.diffuse_level`).  E² and the
  standard errors come from explicit residuals at the solution
  (:mod:`facestats.model.fitting.uncertainty`).

Flags (:data:`facestats.core.conventions.FLAG_BITS`): ``few_samples`` when fewer than
``min_samples`` samples remain, ``not_converged`` when ``max_iter`` is reached,
``ill_conditioned`` when the normal matrix is singular or a parameter's relative
standard error (from σ² (JᵀJ)⁻¹) exceeds ``max_relative_error``, ``at_bound``
when the lobe parameter ends on a bound, or when the data ask for a ρs beyond
its bounds: the unconstrained optimum ρs* = Σyg/Σg² at the final lobe lies
outside [ρ_lo, ρ_hi] by more than ``max_relative_error`` × ρ_hi (a ρs clamped
a little at its bound is an ordinary fit; data a thousand times too bright are
not), ``implausible`` when the lobe lies outside :data:`PLAUSIBLE_LOBE` or, for Blinn-Phong, when the
texel would reflect more than it receives at normal incidence: ρs a(n) > 1
(:func:`facestats.model.brdf.blinn_phong_albedo`; on the default store before this check, 247 unflagged face texels
in 151 of 156 subjects, mostly on the nose and chin where the normals face down, e.g. ρs 0.40 and n 148 against a
true ρs of 0.0074, with a standard error of 121).
Flagged texels keep their values but are meant to be filled from neighbours
(:func:`facestats.model.fitting.maps.fill_flagged`).

Scale: E(p) is quadratic in y and the sums run in float32, so samples of
magnitude beyond 2³² (or below 2⁻³²) sr⁻¹ would overflow (underflow) them; such
inputs (and ∂y/∂α with them) are divided by a power of two (exact) and ρs, its
bounds, E(p) and the standard error of ρs scaled back, which gives the fit of
the unscaled problem.  Data of ordinary magnitude are not scaled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from facestats.core.conventions import FLAG_BITS
from facestats.core.validate import as_finite, check_choice, check_integer
from facestats.errors import ValidationError
from facestats.model.brdf import blinn_phong_albedo
from facestats.model.fitting.diffuse_level import STEPS, fit_diffuse_level
from facestats.model.fitting.engine import resolve_engine
from facestats.model.fitting.lobes import lobe_moments, lobe_sums
from facestats.model.fitting.normal_tilt import tilt_slopes
from facestats.model.fitting.samples import run_starts
from facestats.model.fitting.uncertainty import robust_variances, standard_errors

__all__ = ["SpecularFit", "DEFAULT_BOUNDS", "PLAUSIBLE_LOBE", "solve_specular"]


#: Default bounds (ρs, lobe parameter) per model.
DEFAULT_BOUNDS = {
    "torrance_sparrow": ((0.0, 5.0), (0.03, 1.0)),
    "blinn_phong": ((0.0, 1.0), (0.5, 5000.0)),
}
#: The range of the lobe parameter that skin can have; a fit outside it is flagged ``implausible``.
#: Torrance-Sparrow m in [0.1, 1]: Weyrich et al. 2006 Fig. 15 puts the region means at m = 0.23-0.31,
#: the widest regional spread (lips) within ±0.1, and the synthetic population spans 0.14-0.68
#: (0.18-0.49 for 99.8 % of texels); m = 0.1 is a lobe of about 6° half-width, sharper than any region.
#: Blinn-Phong n in [0, 198]: the same lobes by the Beckmann-Phong correspondence n = 2/m² − 2 (Walter et
#: al. 2007 §5.2).  Wider than the fit's bounds allow would make no difference; narrower lobes are
#: fits of a few bright samples (a Blinn-Phong lobe fitted to Torrance-Sparrow data at grazing angles,
#: ``docs/scale.md``), not skin.
PLAUSIBLE_LOBE = {"torrance_sparrow": (0.1, 1.0), "blinn_phong": (0.0, 198.0)}
_LOBE_NAME = {"torrance_sparrow": "m", "blinn_phong": "exponent"}
#: Multiples of the log-linear estimate tried as cold starts (the best one starts the iteration);
#: one suffices on skin-like lobes (extra starts at 0.625× and 1.6× changed 0.1 % of texels).
_COLD_STARTS = (1.0,)


@dataclass
class SpecularFit:
    """Result of :func:`fit_specular` (one entry per texel).

    Attributes
    ----------
    model : str
    rho_s : ndarray
        ρs.
    lobe : ndarray
        m (Torrance-Sparrow) or n (Blinn-Phong).
    error : ndarray
        E(p) of eq. 14 (sr⁻¹).
    flags : ndarray of uint8
        Bit flags (module docstring).
    n_samples : ndarray of int
        Samples that entered the fit (w = 1).
    iterations : int
        Levenberg-Marquardt iterations run.
    rho_s_std, lobe_std : ndarray
        Standard errors: the robust (sandwich) covariance of the fitted parameters
        (:mod:`facestats.model.fitting.uncertainty`).
    diffuse_shift : ndarray or None
        δ, the correction of the grey albedo α_R + α_G + α_B fitted with the lobe
        (:mod:`facestats.model.fitting.diffuse_level`); None when the fit had no ∂y/∂α.
    """

    model: str
    rho_s: np.ndarray
    lobe: np.ndarray
    error: np.ndarray
    flags: np.ndarray
    n_samples: np.ndarray
    iterations: int
    rho_s_std: np.ndarray
    lobe_std: np.ndarray
    diffuse_shift: np.ndarray | None = None

    @property
    def lobe_name(self) -> str:
        """Name of the lobe parameter: ``"m"`` (Torrance-Sparrow) or ``"exponent"`` (Blinn-Phong)."""
        return _LOBE_NAME[self.model]

    @property
    def params(self) -> dict:
        """``{"rho_s": ..., lobe_name: ...}``, keyword arguments of the model's BRDF."""
        return {"rho_s": self.rho_s, self.lobe_name: self.lobe}


def _check_solver_args(model, bounds, min_samples, max_iter, tol, max_relative_error):
    """The bounds ((ρ_lo, ρ_hi), (p_lo, p_hi)) of ``model``, after checking every solver argument."""
    check_choice(model, "model", DEFAULT_BOUNDS)  # first: the default bounds and PLAUSIBLE_LOBE are looked up by it
    try:
        (r_lo, r_hi), (p_lo, p_hi) = DEFAULT_BOUNDS[model] if bounds is None else bounds
        ordered = 0 <= r_lo < r_hi and 0 < p_lo < p_hi
    except (TypeError, ValueError):
        ordered = False
    if not ordered:
        raise ValidationError(
            "bounds must be ((rho_lo, rho_hi), (lobe_lo, lobe_hi)) with 0 <= rho_lo < rho_hi and "
            f"0 < lobe_lo < lobe_hi, got {bounds!r}"
        )
    check_integer(min_samples, "min_samples", 2)
    check_integer(max_iter, "max_iter", 0)
    as_finite(tol, "tol", 0, None)
    as_finite(max_relative_error, "max_relative_error", 0, None, low_inclusive=False)
    return (r_lo, r_hi), (p_lo, p_hi)


def _rsum(x, starts):
    """Per-run sums of ``x`` (float32 pairwise within a run), as float64."""
    return np.add.reduceat(x, starts).astype(np.float64)


class _WorkingSet:
    """The samples of the texels still moving, with their runs renumbered 0..k-1 (module docstring)."""

    def __init__(self, moving, n_use, y, a, s1, dtype):
        self.work, self.n_use = np.nonzero(moving)[0], n_use
        if not moving.all():
            kept = np.flatnonzero(np.repeat(moving, n_use))
            self.y, self.a, self.s = y.take(kept), a.take(kept), s1.take(kept)
        else:
            self.y, self.a, self.s = y, a, s1
        self.counts = n_use[self.work]
        self.starts = run_starts(self.counts) if self.work.size else None
        self.scratch = np.empty((3, self.y.size), dtype)  # per-sample work buffers of the lobe sums

    def lobe_sums(self, model, q):
        """The five lobe sums of every texel of the set at log-lobe ``q`` (:func:`lobe_sums`)."""
        return lobe_sums(model, q, self.counts, self.starts, self.s, self.a, self.y, self.scratch)

    def keep(self, live):
        """Drop the texels that stopped moving (``~live``)."""
        kept = np.flatnonzero(np.repeat(live, self.counts))
        self.y, self.a, self.s = (x.take(kept) for x in (self.y, self.a, self.s))
        self.work = self.work[live]
        self.counts = self.n_use[self.work]
        self.starts = run_starts(self.counts)
        self.scratch = self.scratch[:, : self.y.size]


def _log_linear_start(model, ws, dt):
    """Lobe starts p₀ from a weighted log-linear fit over each texel's strongest samples.

    ln(y/A) = ln ρs − t/m² (Torrance-Sparrow) or ln(ρs (n+2)) + n ln cos δ
    (Blinn-Phong): the slope against the per-sample abscissa gives p₀.
    """
    wy, wa, st_w = ws.y, ws.a, ws.starts
    ymax = np.maximum.reduceat(wy, st_w)
    strong = (wy > np.repeat(np.float32(0.25) * ymax.astype(dt), ws.counts)) & (wy > 0)
    lr = np.log(np.maximum(wy, np.float32(1e-30)) / wa)  # finite: A > 0 on every kept sample
    wt = wy * wy * strong
    wx = wt * ws.s
    sw_, sx_, sy_ = _rsum(wt, st_w), _rsum(wx, st_w), _rsum(wt * lr, st_w)
    sxy_, sxx_ = _rsum(wx * lr, st_w), _rsum(wx * ws.s, st_w)
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = (sxy_ - sx_ * sy_ / sw_) / (sxx_ - sx_ * sx_ / sw_)
        if model == "torrance_sparrow":
            pc = np.where(slope < 0, 1 / np.sqrt(np.abs(slope)), 0.3)
        else:
            pc = np.where(slope > 0, slope, 20.0)
    return np.nan_to_num(pc, nan=0.3 if model == "torrance_sparrow" else 20.0)


def _best_start(model, ws, swyy_w, p0, cold, r_bounds, q_bounds):
    """(log-lobe, ρs, lobe sums) of the best of the candidate starts of each texel (least E)."""
    (r_lo, r_hi), (q_lo, q_hi) = r_bounds, q_bounds
    k = ws.work.size
    factors = (1.0,) if not cold.any() else _COLD_STARTS
    best_e = np.full(k, np.inf)
    best_q = np.log(p0)
    best_r = np.zeros(k)
    best_s = None
    for f in factors:  # candidate starts
        qq = np.clip(np.log(p0 * np.where(cold, f, 1.0)), q_lo, q_hi)
        sums = ws.lobe_sums(model, qq)
        syg, sgg = lobe_moments(model, qq, sums)[:2]
        with np.errstate(invalid="ignore", divide="ignore"):
            rr = np.clip(np.nan_to_num(syg / sgg), r_lo, r_hi)
        e = swyy_w - 2 * rr * syg + rr * rr * sgg
        better = e < best_e
        best_e, best_q, best_r = (
            np.where(better, e, best_e),
            np.where(better, qq, best_q),
            np.where(better, rr, best_r),
        )
        best_s = sums if best_s is None else tuple(np.where(better, x, b) for x, b in zip(sums, best_s))
    return best_q, best_r, best_s


def _lm_iterations(model, ws, state, sums, swyy, r_bounds, q_bounds, max_iter, tol):
    """Levenberg-Marquardt, vectorised over the texels still moving; returns (all lobe sums, iterations).

    ``state`` holds per-texel ``rho``, ``q``, ``lam`` and ``done`` arrays, updated in
    place.  Every iteration evaluates the lobe once, at the trial point: its five sums
    give E there and, if the step is accepted, the gradient and Hessian of the next step.
    """
    (r_lo, r_hi), (q_lo, q_hi) = r_bounds, q_bounds
    rho, q, lam, done = state["rho"], state["q"], state["lam"], state["done"]
    all_sums = np.zeros((5, rho.size))  # lobe sums of every texel, written when it leaves the working set
    iterations = 0
    for iterations in range(1, int(max_iter) + 1):
        work = ws.work
        r0, q0, lm = rho[work], q[work], lam[work]
        syg, sgg, sydg, sgdg, sdgdg = lobe_moments(model, q0, sums)
        e0 = swyy[work] - 2 * r0 * syg + r0 * r0 * sgg
        h00, h01, h11 = sgg, r0 * sgdg, r0 * r0 * sdgdg
        b0, b1 = syg - r0 * sgg, r0 * (sydg - r0 * sgdg)
        with np.errstate(invalid="ignore", divide="ignore"):
            # Gauss-Newton decrement bᵀH⁻¹b: the most a full step could still lower E².
            decrement = (h11 * b0 * b0 - 2 * h01 * b0 * b1 + h00 * b1 * b1) / (h00 * h11 - h01 * h01)
        done[work] |= decrement < 0.1 * tol * e0
        live = ~done[work]
        if not live.any():
            break
        if live.mean() < 0.7:  # compact the working set
            all_sums[:, work[~live]] = np.array(sums)[:, ~live]
            ws.keep(live)
            work = ws.work
            sums = tuple(x[live] for x in sums)
            r0, q0, lm, e0, h00, h01, h11, b0, b1 = (x[live] for x in (r0, q0, lm, e0, h00, h01, h11, b0, b1))
        d00 = h00 * (1 + lm) + 1e-30
        d11 = h11 * (1 + lm) + 1e-30
        det = d00 * d11 - h01 * h01
        with np.errstate(invalid="ignore", divide="ignore"):
            dr = (d11 * b0 - h01 * b1) / det
            dq = (d00 * b1 - h01 * b0) / det
        r1 = np.clip(r0 + np.nan_to_num(dr), r_lo, r_hi)
        q1 = np.clip(q0 + np.nan_to_num(dq), q_lo, q_hi)
        sums1 = ws.lobe_sums(model, q1)
        syg1, sgg1 = lobe_moments(model, q1, sums1)[:2]
        e1 = swyy[work] - 2 * r1 * syg1 + r1 * r1 * sgg1
        accept = e1 < e0
        rho[work] = np.where(accept, r1, r0)
        q[work] = np.where(accept, q1, q0)
        lam[work] = np.where(accept, lm / 3, lm * 4)
        sums = tuple(np.where(accept, x1, x0) for x1, x0 in zip(sums1, sums))
        rel = (e0 - np.minimum(e1, e0)) / np.maximum(e0, 1e-30)
        # A step this small, accepted or not, means the minimum is reached (to float32 precision).
        small_step = (np.abs(r1 - r0) <= 1e-5 * np.maximum(np.abs(r0), 1e-6)) & (np.abs(q1 - q0) <= 1e-5)
        done[work] |= (accept & (rel < tol)) | small_step | (lam[work] > 1e10)
    all_sums[:, ws.work] = sums
    return all_sums, iterations


def solve_specular(
    model,
    y,
    s1,
    a,
    n_use,
    *,
    bounds,
    min_samples,
    max_iter,
    tol,
    max_relative_error,
    dtype=np.float32,
    start=None,
    engine=None,
    d=None,
    tilt=None,
    albedo=None,
):
    """Batch bounded Levenberg-Marquardt on flat samples in per-texel runs of ``n_use`` samples (module docstring).

    ``engine`` (:mod:`facestats.model.fitting.engine`) picks the numpy iteration
    below or the compiled per-texel solve of :mod:`facestats.model.fitting.kernels.lm`.
    ``d`` (per sample, ∂y/∂α of the grey albedo): the grey diffuse level is fitted too
    (:mod:`facestats.model.fitting.diffuse_level`).  ``tilt``
    (:class:`~facestats.model.fitting.normal_tilt.TiltInputs` of the samples): the standard errors
    allow the lobe's normal two tilts, and with its ``diffuse`` and ``d`` the normal of the diffuse
    term eq. 10 removed with the grey albedo ``albedo`` (T,) too
    (:mod:`facestats.model.fitting.normal_tilt`).

    Parameters
    ----------
    model : {"torrance_sparrow", "blinn_phong"}
        The lobe (a key of :data:`DEFAULT_BOUNDS`).
    y : ndarray, shape (S,)
        y = f_s cos θi of the kept samples (w = 1), each texel's samples one contiguous run.
    s1, a : ndarray, shape (S,)
        The per-sample factors (z, A) of :func:`~facestats.model.fitting.specular.specular_factors`.
    n_use : array_like of int, shape (T,)
        Samples per texel (the run lengths).
    bounds : ((rho_lo, rho_hi), (lobe_lo, lobe_hi)) or None
        Bounds of ρs and of the lobe parameter (m or n), 0 ≤ rho_lo < rho_hi, 0 < lobe_lo < lobe_hi;
        None: :data:`DEFAULT_BOUNDS`.
    min_samples : int
        Texels with fewer samples are not solved (flag ``few_samples``, values NaN), ≥ 2.
    max_iter : int
        Iteration cap, ≥ 0 (flag ``not_converged`` when reached).
    tol : float
        Relative convergence tolerance on E(p)², ≥ 0.
    max_relative_error : float
        Relative standard error above which a texel is flagged ``ill_conditioned``, > 0.
    dtype : numpy dtype
        Float dtype of the result's arrays (and of the numpy iteration's parameters).
    start : array_like, shape (T,), optional
        Starting lobe parameter per texel; non-finite or non-positive entries take the log-linear start.
    engine : {"numba", "numpy"}, optional
        Default: the configured one.
    d : ndarray, shape (S,), optional
        ∂y/∂α per sample: fit the grey diffuse level δ too.
    tilt : TiltInputs, optional
        Normal tilts allowed in the standard errors.
    albedo : ndarray, shape (T,), optional
        Grey albedo α_R + α_G + α_B per texel, with a ``tilt`` whose diffuse normal tilts.

    Returns
    -------
    SpecularFit
        One entry per texel; ρs, its standard error, E(p) and δ are those of the unscaled ``y`` (module
        docstring: Scale).

    Raises
    ------
    ValidationError
        Invalid ``model``, ``bounds``, ``min_samples``, ``max_iter``, ``tol``, ``max_relative_error`` or ``engine``.
    """
    (r_lo, r_hi), (p_lo, p_hi) = _check_solver_args(model, bounds, min_samples, max_iter, tol, max_relative_error)
    engine = resolve_engine(engine)
    dt = np.dtype(dtype)
    scale = _y_scale(y)
    if scale != 1.0:
        y = y / y.dtype.type(scale)
        d = None if d is None else d / np.asarray(d).dtype.type(scale)
        r_lo, r_hi = r_lo / scale, r_hi / scale
    n_use = np.asarray(n_use, np.int64)
    few = n_use < min_samples
    p0 = None if start is None else np.asarray(start, np.float64)
    bnd = ((r_lo, r_hi), (p_lo, p_hi))
    if engine == "numba":
        fit = _solve_compiled(model, y, s1, a, d, (tilt, albedo), n_use, ~few, p0, bnd, max_iter, tol)
    else:
        fit = _solve_numpy(model, y, s1, a, d, (tilt, albedo), n_use, ~few, p0, bnd, max_iter, tol, dt)
    return _result(model, n_use, few, fit, max_relative_error, (r_lo, r_hi, p_lo, p_hi), scale, dt)


def _y_scale(y) -> float:
    """The power of two samples are divided by before the fit (module docstring: Scale); 1.0 for ordinary data."""
    ymax = float(np.max(np.abs(y))) if y.size else 0.0
    if not np.isfinite(ymax) or 2.0**-32 <= ymax <= 2.0**32 or ymax == 0.0:
        return 1.0
    return 2.0 ** math.ceil(math.log2(ymax))


def _rho_outside(model, good, q, all_sums, r_lo, r_hi, max_relative_error):
    """Texels whose unconstrained optimum ρs* = Σyg/Σg² at the final lobe leaves [ρ_lo, ρ_hi] by more than the
    margin ``max_relative_error`` × ρ_hi (module docstring)."""
    out = np.zeros(good.size, bool)
    if good.any():
        syg, sgg = lobe_moments(model, q[good], all_sums[:, good])[:2]
        margin = max_relative_error * r_hi
        with np.errstate(invalid="ignore", divide="ignore"):
            rho_star = syg / sgg
            out[good] = (rho_star > r_hi + margin) | (rho_star < r_lo - margin)
    return out


def _solve_numpy(model, y, s1, a, d, tilt, n_use, solve, p_start, bounds, max_iter, tol, dt):
    """The numpy iteration, then the diffuse level (with ``d``): (ρs, ln p, δ, converged, iterations, lobe
    sums, (E², var ρs, var ln p)) per texel (module docstring); ``tilt`` = (tilt, albedo) of
    :func:`solve_specular`."""
    (r_lo, r_hi), (p_lo, p_hi) = bounds
    q_lo, q_hi = np.log(p_lo), np.log(p_hi)
    n_tex = n_use.size
    state = {
        "rho": np.full(n_tex, np.nan, dt),
        "q": np.full(n_tex, np.nan, dt),
        "lam": np.full(n_tex, 1e-3, dt),
        "done": ~solve,
    }
    ws = _WorkingSet(solve, n_use, y, a, s1, y.dtype)
    swyy = np.zeros(n_tex)
    iterations = 0
    all_sums = np.zeros((5, n_tex))
    if ws.work.size:
        work = ws.work
        swyy[work] = _rsum(ws.y * ws.y, ws.starts)
        p0 = np.full(work.size, np.nan)
        if p_start is not None:  # a given start wins where it is finite
            st0 = p_start[work]
            p0 = np.where(np.isfinite(st0) & (st0 > 0), st0, np.nan)
        cold = ~np.isfinite(p0)
        if cold.any():
            p0 = np.where(cold, _log_linear_start(model, ws, dt), p0)
        p0 = np.clip(p0, p_lo, p_hi)
        q0, r0, sums = _best_start(model, ws, swyy[work], p0, cold, (r_lo, r_hi), (q_lo, q_hi))
        state["q"][work], state["rho"][work] = q0, r0
        all_sums, iterations = _lm_iterations(model, ws, state, sums, swyy, (r_lo, r_hi), (q_lo, q_hi), max_iter, tol)
    rho = state["rho"].astype(np.float64)
    q = state["q"].astype(np.float64)
    delta = None
    if d is not None:
        rho, q, delta = fit_diffuse_level(model, y, s1, a, d, n_use, solve, rho, q, (r_lo, r_hi, q_lo, q_hi))
        all_sums = _final_lobe_sums(model, y, s1, a, d, n_use, solve, q, delta)
    slopes = None if tilt[0] is None else tilt_slopes(model, tilt[0])
    robust = robust_variances(model, y, s1, a, d, n_use, solve, rho, q, delta, slopes, tilt[1])
    return rho, q, delta, state["done"] & solve, iterations, all_sums, robust


def _final_lobe_sums(model, y, s1, a, d, n_use, solve, q, delta):
    """The five lobe sums at the solution ``q`` of y + δ d (zeros where not ``solve``)."""
    out = np.zeros((5, n_use.size))
    if solve.any():
        cnt = n_use[solve]
        kept = np.flatnonzero(np.repeat(solve, n_use))
        y_shifted = (y.take(kept) + d.take(kept) * np.repeat(delta[solve], cnt)).astype(y.dtype)
        zk, ak = s1.take(kept), a.take(kept)
        scratch = np.empty((3, kept.size), y.dtype)
        out[:, solve] = lobe_sums(model, q[solve], cnt, run_starts(cnt), zk, ak, y_shifted, scratch)
    return out


def _solve_compiled(model, y, s1, a, d, tilt, n_use, solve, p_start, bounds, max_iter, tol):
    """The compiled per-texel solve (:func:`facestats.model.fitting.kernels.lm.solve_runs`): the tuple of
    :func:`_solve_numpy`."""
    # local import: the kernels import numba
    from facestats.model.fitting.kernels import lm

    (r_lo, r_hi), (p_lo, p_hi) = bounds
    n_tex = n_use.size
    p0 = np.full(n_tex, np.nan) if p_start is None else np.where(np.isfinite(p_start) & (p_start > 0), p_start, np.nan)
    code = lm.TORRANCE_SPARROW if model == "torrance_sparrow" else lm.BLINN_PHONG
    limits = np.array([r_lo, r_hi, np.log(p_lo), np.log(p_hi), p_lo, p_hi], np.float64)
    rho, q, delta, done, its, all_sums, robust = lm.solve_runs(
        code,
        np.ascontiguousarray(y, np.float32),
        np.ascontiguousarray(s1, np.float32),
        np.ascontiguousarray(a, np.float32),
        np.zeros(0, np.float32) if d is None else np.ascontiguousarray(d, np.float32),
        0 if tilt[0] is None else tilt[0].rows,
        _kernel_tilt(tilt[0]),
        np.zeros(n_tex) if tilt[1] is None else np.ascontiguousarray(tilt[1], np.float64),
        run_starts(n_use),
        n_use,
        solve,
        p0,
        limits,
        int(max_iter),
        float(tol),
        STEPS,
    )
    return rho, q, None if d is None else delta, done, int(its.max(initial=0)), all_sums, tuple(robust)


def _kernel_tilt(tilt):
    """The arrays of :class:`~facestats.model.fitting.normal_tilt.TiltInputs` as the compiled solve takes them
    (empty ones without ``tilt``)."""
    if tilt is None:
        i, f, g = np.zeros(0, np.int64), np.zeros(0, np.float32), np.zeros((0, 4), np.float32)
        return (i, i, i, f, f, f, g, g)
    return (tilt.index, tilt.light_index, tilt.camera_index, tilt.ci, tilt.co, tilt.io, tilt.light, tilt.camera)


def _result(model, n_use, few, fit, max_relative_error, limits, scale, dt):
    """The :class:`SpecularFit` of a solve: standard errors, flags, NaN where too few samples; ρs, δ, E and the
    standard error of ρs scaled back by ``scale`` (module docstring: Scale)."""
    rho, q, delta, done, iterations, all_sums, (e2, var_rho, var_q) = fit
    r_lo, r_hi, p_lo, p_hi = limits
    q_lo, q_hi = np.log(p_lo), np.log(p_hi)
    good = ~few
    robust = (e2, var_rho, var_q)
    err, r_std, p_std, ill = standard_errors(model, n_use, good, rho, q, all_sums, *robust, max_relative_error)
    rho_out = _rho_outside(model, good, q, all_sums, r_lo, r_hi, max_relative_error)
    rho, err, r_std = rho * scale, err * scale, r_std * scale
    p = np.exp(q)
    at_bound = good & ((q <= q_lo + 1e-6) | (q >= q_hi - 1e-6) | rho_out)
    plausible_lo, plausible_hi = PLAUSIBLE_LOBE[model]
    implausible = good & ((p < plausible_lo) | (p > plausible_hi))
    if model == "blinn_phong":  # a lobe that reflects more than it receives (normal incidence) is no skin
        with np.errstate(invalid="ignore"):
            implausible |= good & (rho * blinn_phong_albedo(np.where(good, p, 0.0)) > 1)
    bit = FLAG_BITS
    flags = (
        (few * bit["few_samples"])
        | ((good & ~done) * bit["not_converged"])
        | (ill * bit["ill_conditioned"])
        | (at_bound * bit["at_bound"])
        | (implausible * bit["implausible"])
    )
    return SpecularFit(
        model=model,
        rho_s=np.where(few, np.nan, rho).astype(dt),
        lobe=np.where(few, np.nan, p).astype(dt),
        error=err.astype(dt),
        flags=flags.astype(np.uint8),
        n_samples=n_use,
        iterations=iterations,
        rho_s_std=r_std.astype(dt),
        lobe_std=p_std.astype(dt),
        diffuse_shift=None if delta is None else np.where(few, np.nan, delta).astype(dt),  # y and d scale alike
    )
