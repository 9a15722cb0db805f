"""Standard errors of the specular fit (:mod:`facestats.model.fitting.uncertainty`)."""

import numpy as np
import pytest

from facestats.model import brdf, fitting
from facestats.model.fitting.solver import solve_specular
from facestats.model.fitting.specular import specular_factors
from tests.helpers import hemisphere_pairs

Z90 = 1.6448536269514722  # two-sided 90 % of a standard normal


@pytest.mark.parametrize("engine", ["numba", "numpy"])
def test_intervals_cover_the_truth_when_the_model_holds(rng, engine):
    """Shot-like noise (standard deviation growing with the signal): nominal 90 % intervals cover ~90 %."""
    t, s = 600, 400
    wi, wo = hemisphere_pairs(rng, t, s)
    n = np.tile([0.0, 0.0, 1.0], (t, 1))
    rho, m = rng.uniform(0.15, 0.35, t), rng.uniform(0.2, 0.45, t)
    f = brdf.torrance_sparrow(n[:, None], wi, wo, rho[:, None], m[:, None])
    noisy = f + (0.08 * f + 0.002) * rng.standard_normal(f.shape)
    fit = fitting.fit_specular(wi, wo, n, noisy, np.ones((t, s), bool), "torrance_sparrow", engine=engine)
    ok = fit.flags == 0
    assert ok.mean() > 0.9
    cover_rho = np.mean(np.abs(fit.rho_s - rho)[ok] <= Z90 * fit.rho_s_std[ok])
    cover_m = np.mean(np.abs(fit.lobe - m)[ok] <= Z90 * fit.lobe_std[ok])
    assert 0.85 <= cover_rho <= 0.95 and 0.85 <= cover_m <= 0.95, (cover_rho, cover_m)
    # σ² (JᵀJ)⁻¹ alone would be far too small here: the noise is largest on the highlight samples.
    classic = _classic_std(fit, wi, wo, n, noisy)
    assert np.mean(np.abs(fit.rho_s - rho)[ok] <= Z90 * classic[ok]) < 0.75


def _classic_std(fit, wi, wo, n, f):
    """σ² (JᵀJ)⁻¹ of ρs per texel by finite differences in float64 (the reference of the classic errors)."""
    out = np.empty(fit.rho_s.size)
    for k in range(fit.rho_s.size):
        j, r = _jacobian(fit.rho_s[k], fit.lobe[k], wi[k], wo[k], n[k], f[k])
        cov = (r @ r / (r.size - 2)) * np.linalg.inv(j.T @ j)
        out[k] = np.sqrt(cov[0, 0])
    return out


def _jacobian(rho, m, wi, wo, n, f):
    """J = ∂(ρs g cos θi)/∂(ρs, ln m) by central differences, and the residuals, float64."""
    ci = wi @ n

    def model(p):
        return brdf.torrance_sparrow(n, wi, wo, p[0], np.exp(p[1])) * ci

    p = np.array([rho, np.log(m)], np.float64)
    j = np.stack([(model(p + e) - model(p - e)) / (2 * e.max()) for e in np.eye(2) * 1e-6], axis=1)
    return j, f * ci - model(p)


def test_standard_errors_against_a_brute_force_sandwich_with_the_albedo_term(rng):
    """HC3 sandwich plus b bᵀ σ_α², formed independently with finite-difference Jacobians in float64
    (the fit works on float32 factors: agreement to 1 %)."""
    t, s = 5, 300
    wi, wo = hemisphere_pairs(rng, t, s)
    n = np.tile([0.0, 0.0, 1.0], (t, 1))
    rho, m = rng.uniform(0.15, 0.35, t), rng.uniform(0.25, 0.45, t)
    f = brdf.torrance_sparrow(n[:, None], wi, wo, rho[:, None], m[:, None])
    f = f + (0.05 * f + 0.003) * rng.standard_normal(f.shape)
    samples = fitting.Samples.from_arrays(wi, wo, np.ones((t, s), bool), engine="numpy")
    ci = np.einsum("tk,tsk->ts", n, wi).reshape(-1)
    y = (f.reshape(-1) * ci).astype(np.float32)
    s1, a = specular_factors(samples, n, "torrance_sparrow")
    d = rng.uniform(-0.05, -0.01, t * s).astype(np.float32)  # ∂y/∂α per sample
    alb_std = rng.uniform(0.001, 0.01, t)
    for engine in ("numba", "numpy"):
        fit = solve_specular(
            "torrance_sparrow",
            y,
            s1,
            a,
            np.full(t, s),
            bounds=None,
            min_samples=30,
            max_iter=60,
            tol=1e-10,
            max_relative_error=0.5,
            engine=engine,
            d=d,
            albedo_std=alb_std,
        )
        for k in range(t):
            j, r = _jacobian(fit.rho_s[k], fit.lobe[k], wi[k], wo[k], n[k], f[k])
            hi = np.linalg.inv(j.T @ j)
            lev = np.einsum("si,ij,sj->s", j, hi, j)
            meat = (j * (r**2 / (1 - lev) ** 2)[:, None]).T @ j
            b = hi @ j.T @ d[k * s : (k + 1) * s].astype(np.float64)
            cov = hi @ meat @ hi + np.outer(b, b) * alb_std[k] ** 2
            np.testing.assert_allclose(fit.rho_s_std[k], np.sqrt(cov[0, 0]), rtol=1e-2, err_msg=engine)
            np.testing.assert_allclose(fit.lobe_std[k], fit.lobe[k] * np.sqrt(cov[1, 1]), rtol=1e-2, err_msg=engine)
