"""The grey diffuse level of eq. 10 fitted together with the specular lobe of eq. 14 (Weyrich et al. 2006 §5.2-5.3).

Eq. 10 subtracts the diffuse term (α/π) F_t(θi) F_t(θo) from every BRDF sample,
with the albedo α estimated beforehand (the stable minimum of eq. 9, refined over
the specular-free samples: :func:`facestats.model.fitting.refine_albedo`).  If
the true grey albedo α_R + α_G + α_B is the estimate plus δ, every y = f_s cos θi
of the texel holds −δ d of diffuse light too many, with

    d = ∂y/∂α = −F_t(θi) F_t(θo) cos θi / (3π)

(grey = mean of the three channels), which has the same sign on every sample.
A fit of (ρs, p) alone absorbs it into ρs and the lobe, a bias of several of its
standard errors: on simulated captures with a photometric-stereo normal the
nominal 90 % intervals of Blinn-Phong's ρs covered 62.8 % of the truth with δ = 0
(2026-12-04) against 79.2 % with δ fitted (2026-12-07; dipole transport, errors
conditional on the normal; ``docs/scale.md``, *Where the misses come from*).

Here δ is a third parameter of the texel's least squares,

    E² = Σ [y + δ d − ρs g(p)]²,

refined by :data:`STEPS` Gauss-Newton steps from the two-parameter solution
(ρs, q = ln p, δ = 0) with Jacobian rows J = (g, ρs ∂g/∂q, −d); a step that raises
E² is undone (and the texel stops), and ρs and q are projected on their bounds.  Starting at
the (ρs, q) optimum with δ small, the steps converge fast: on simulated captures
(subject S001 on the procedural face at 48², dipole transport, camera noise), after
two steps 99 % of the unflagged texels are within 3e-6 (Torrance-Sparrow) and
2e-4 / 5e-4 (Blinn-Phong ρs / n) relative of the solution after eight, at most
5e-3: a tenth of their standard errors or less.
The albedo stored in the maps stays the one of eq. 9 / its refinement; δ is the
fit's nuisance parameter, returned as :attr:`SpecularFit.diffuse_shift`.  Its
uncertainty enters the standard errors of ρs and p through the 3 × 3 sandwich of
:func:`facestats.model.fitting.uncertainty.robust_variances`.

The compiled engine runs the same steps per texel
(:mod:`facestats.model.fitting.kernels.lm`).
"""

from __future__ import annotations

import numpy as np

from facestats.model.fitting.lobes import lobe_base
from facestats.model.fitting.samples import run_starts
from facestats.model.fitting.uncertainty import gram_stack, inverse_stack, lobe_jacobian

__all__ = ["fit_diffuse_level", "STEPS"]

#: Gauss-Newton steps of (ρs, q, δ) from the two-parameter solution (module docstring).
STEPS = 2


def fit_diffuse_level(model, y, s1, a, d, n_use, good, rho, q, limits, steps=STEPS):
    """(ρs, q, δ) per texel: the two-parameter solution refined with the grey diffuse level (module docstring).

    Parameters
    ----------
    model : {"torrance_sparrow", "blinn_phong"}
    y, s1, a, d : ndarray, shape (S,)
        y = f_s cos θi, the lobe factors (z, A) and d = ∂y/∂α of every sample, in
        per-texel runs of ``n_use`` samples.
    n_use : ndarray of int, shape (T,)
        Samples of each texel.
    good : ndarray of bool, shape (T,)
        Texels to refine (the others keep their values, δ NaN).
    rho, q : ndarray of float64, shape (T,)
        The two-parameter solution (ρs and ln p).
    limits : tuple
        (ρs low, ρs high, ln p low, ln p high).
    steps : int
        Gauss-Newton steps (:data:`STEPS`).

    Returns
    -------
    rho, q, delta : ndarray of float64, shape (T,)
    """
    r_lo, r_hi, q_lo, q_hi = limits
    rho, q = np.array(rho, np.float64), np.array(q, np.float64)
    delta = np.full(rho.size, np.nan)
    delta[good] = 0.0
    if not good.any():
        return rho, q, delta
    cnt = n_use[good]
    kept = np.flatnonzero(np.repeat(good, n_use))
    z32, a32 = np.asarray(s1).take(kept), np.asarray(a).take(kept)
    yx, zx, dx = (np.asarray(x).take(kept).astype(np.float64) for x in (y, s1, d))
    starts = run_starts(cnt)
    par = np.stack([rho[good], q[good], np.zeros(cnt.size)])  # (3, T')
    prev = par.copy()
    e_prev = np.full(cnt.size, np.inf)
    moving = np.ones(cnt.size, bool)
    for k in range(steps + 1):
        rs, qs = np.repeat(par[0], cnt), np.repeat(par[1], cnt)
        g, dg = lobe_jacobian(model, qs, lobe_base(model, par[1], cnt, z32, a32).astype(np.float64), zx)
        r = yx + dx * np.repeat(par[2], cnt) - rs * g
        e = np.add.reduceat(r * r, starts)
        worse = moving & ~(e <= e_prev)  # a step that did not lower E² is undone, and the texel stops
        par[:, worse] = prev[:, worse]
        moving &= ~worse
        if k == steps or not moving.any():
            break
        jac = np.stack([g, rs * dg, -dx])
        step = inverse_stack(gram_stack(jac, jac, starts)) @ gram_stack(jac, r[None], starts)  # NaN if singular
        step = step[..., 0]
        moving &= np.isfinite(step).all(axis=1)
        prev, e_prev = par.copy(), e
        par[:, moving] += step[moving].T
        par[0, moving] = np.clip(par[0, moving], r_lo, r_hi)
        par[1, moving] = np.clip(par[1, moving], q_lo, q_hi)
    rho[good], q[good], delta[good] = par
    return rho, q, delta
