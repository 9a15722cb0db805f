"""The lobe's normal as nuisance parameters of the specular standard errors
(:mod:`facestats.model.fitting.normal_tilt`)."""

import numpy as np
import pytest

from facestats.model import brdf, fitting
from facestats.model.fitting.normal_tilt import diffuse_coefficients, factor_slopes, tangent_pair
from facestats.model.fresnel import (
    fresnel_reflectance_slope_unchecked,
    fresnel_reflectance_unchecked,
    fresnel_transmittance,
)
from tests.helpers import hemisphere_pairs

Z90 = 1.6448536269514722  # two-sided 90 % of a standard normal


ETA = 1.38


def _factors64(model, ci, co, io):
    """(z, ln A, ln D) of eq. 11-13 and of the diffuse term D = F_t F_t cos θi in float64, from the BRDF and
    Fresnel modules (independent of the fit's kernels)."""
    ln_d = np.log(fresnel_transmittance(ci, ETA) * fresnel_transmittance(co, ETA) * ci)
    if model == "torrance_sparrow":
        cos_d, k = brdf.torrance_sparrow_cosines(ci, co, io)
        return 1 / cos_d**2 - 1, np.log(k * ci / cos_d**4), ln_d
    return np.log((ci + co) / np.sqrt(2 + 2 * io)), np.log(ci / (2 * np.pi)), ln_d


def test_fresnel_slope_against_central_differences():
    c = np.linspace(0.01, 0.99, 99)
    for eta in (1.38, 1.5, 1 / 1.38):
        h = 1e-6
        ref = (fresnel_reflectance_unchecked(c + h, eta) - fresnel_reflectance_unchecked(c - h, eta)) / (2 * h)
        np.testing.assert_allclose(fresnel_reflectance_slope_unchecked(c, eta), ref, rtol=1e-6, atol=1e-9)
    assert fresnel_reflectance_slope_unchecked(0.5, 1 / 1.38) == 0  # total internal reflection: F_r = 1


@pytest.mark.parametrize("model", ["torrance_sparrow", "blinn_phong"])
def test_factor_slopes_are_the_derivatives_of_the_factors_under_a_tilt(rng, model):
    """Central differences of (z, ln A, ln D) with the normal itself tilted and renormalised (1e-6 rad), including
    samples where the V-groove term G < 1; and the compiled twin gives the same values."""
    from facestats.model.fitting.kernels.factors import texel_tilt_slopes

    wi, wo = (w.reshape(-1, 3) for w in hemisphere_pairs(rng, 1, 20_000))
    n = np.tile([0.0, 0.0, 1.0], (wi.shape[0], 1))
    t1, t2 = tangent_pair(n)
    ci, co, io = wi[:, 2], wo[:, 2], np.einsum("sk,sk->s", wi, wo)
    ok = (ci > 0.05) & (co > 0.05)
    wi, wo, n, t1, t2, ci, co, io = (x[ok] for x in (wi, wo, n, t1, t2, ci, co, io))
    h = 1e-6
    for t in (t1, t2):
        dci, dco = np.einsum("sk,sk->s", wi, t), np.einsum("sk,sk->s", wo, t)
        dz, d_ln_a = factor_slopes(model, ci, co, io, dci, dco)
        k_i, k_o = diffuse_coefficients(ci, co, ETA)
        d_ln_d = k_i * dci + k_o * dco
        ref = []
        for sign in (1, -1):
            nn = n + sign * h * t
            nn /= np.linalg.norm(nn, axis=1, keepdims=True)
            ref.append(_factors64(model, np.einsum("sk,sk->s", wi, nn), np.einsum("sk,sk->s", wo, nn), io))
        for got, i in ((dz, 0), (d_ln_a, 1), (d_ln_d, 2)):
            want = (ref[0][i] - ref[1][i]) / (2 * h)
            np.testing.assert_allclose(got, want, rtol=2e-5, atol=2e-5 * np.abs(want).max())
    if model == "torrance_sparrow":
        cos_d = (ci + co) / np.sqrt(2 + 2 * io)
        shadowed = 2 * cos_d * np.minimum(ci, co) / ((1 + io) / np.sqrt(2 + 2 * io)) < 1
        assert 0.01 < shadowed.mean() < 0.99  # both branches of G were differentiated
    f32 = [x.astype(np.float32) for x in (ci, co, io)]
    ti1, ti2, to1, to2 = (np.einsum("sk,sk->s", w, t).astype(np.float32) for w in (wi, wo) for t in (t1, t2))
    k_i, k_o = (k.astype(np.float32) for k in diffuse_coefficients(ci, co, ETA))
    light = np.stack([ti1, ti2, k_i, 1 / f32[0]], axis=1)  # one light and camera per sample
    camera = np.stack([to1, to2, k_o, 1 / f32[1]], axis=1)
    index = np.arange(ci.size)
    z = _factors64(model, *f32)[0].astype(np.float32)  # the kept samples' lobe factor
    got = np.empty((6, ci.size))
    tilt = (index, index, index, *f32, light, camera)
    texel_tilt_slopes(model == "torrance_sparrow", 6, tilt, z, 0, ci.size, got)
    want = np.stack(
        [
            *factor_slopes(model, *f32, ti1, to1),
            *factor_slopes(model, *f32, ti2, to2),
            k_i.astype(np.float64) * ti1 + k_o.astype(np.float64) * to1,
            k_i.astype(np.float64) * ti2 + k_o.astype(np.float64) * to2,
        ]
    )
    for row in range(6):
        np.testing.assert_allclose(got[row], want[row], rtol=1e-6, atol=1e-7 * np.abs(want[row]).max(), err_msg=row)


def test_tangent_pair_is_orthonormal_also_at_the_poles(rng):
    n = rng.normal(size=(500, 3))
    n[:3] = [[0, 1, 0], [0, -1, 0], [1e-5, 1, 0]]
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    t1, t2 = tangent_pair(n)
    for a, b in ((n, t1), (n, t2), (t1, t2)):
        np.testing.assert_allclose(np.einsum("sk,sk->s", a, b), 0, atol=1e-12)
    for t in (t1, t2):
        np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1, rtol=1e-12)


def _diffuse(n, wi, wo):
    """D = F_t(θi) F_t(θo) cos θi per sample at normal ``n`` (float64)."""
    ci, co = wi @ n, wo @ n
    return fresnel_transmittance(ci, ETA) * fresnel_transmittance(co, ETA) * ci


def _brute_force_std(model, par, wi, wo, n, y, alpha):
    """HC3 standard errors of (ρs, lobe) with J = ∂ŷ/∂(ρs, ln p, δ, ε₁, ε₂, η₁, η₂) by central differences of the
    BRDF and Fresnel modules' functions, float64, for ŷ = ρs f(N_s) cos θi(N_s) + (α + δ) D(N_d)/(3π)
    − α D(N)/(3π): the lobe at N_s = N + ε₁ t₁ + ε₂ t₂, the diffuse term at N_d = N + η₁ t₁ + η₂ t₂ (both
    renormalised), less the diffuse term eq. 10 removed at N."""
    t1, t2 = (t[0] for t in tangent_pair(n[None]))

    def unit(v):
        return v / np.linalg.norm(v)

    def model_y(p):
        ns, nd = unit(n + p[3] * t1 + p[4] * t2), unit(n + p[5] * t1 + p[6] * t2)
        if model == "torrance_sparrow":
            f = brdf.torrance_sparrow(ns, wi, wo, p[0], np.exp(p[1]))
        else:
            f = brdf.blinn_phong(ns, wi, wo, p[0], np.exp(p[1]))
        return f * (wi @ ns) + ((alpha + p[2]) * _diffuse(nd, wi, wo) - alpha * _diffuse(n, wi, wo)) / (3 * np.pi)

    j = np.stack([(model_y(par + e) - model_y(par - e)) / (2 * e.max()) for e in np.eye(7) * 1e-6], axis=1)
    r = y - model_y(par)
    hi = np.linalg.inv(j.T @ j)
    lev = np.einsum("si,ij,sj->s", j, hi, j)
    cov = hi @ ((j * (r**2 / (1 - lev) ** 2)[:, None]).T @ j) @ hi
    return np.sqrt(cov[0, 0]), np.exp(par[1]) * np.sqrt(cov[1, 1])


@pytest.mark.parametrize("model", ["torrance_sparrow", "blinn_phong"])
def test_tilt_errors_against_brute_force(rng, model):
    """fit_specular_models(normal_tilt=True), both engines: the 7 × 7 HC3 sandwich of the lobe, the diffuse level
    and the tilts of both normals formed independently with finite-difference Jacobians (the fit's float32
    factors: 1 %)."""
    t, s = 6, 400
    wi, wo = hemisphere_pairs(rng, t, s)
    n = rng.normal([0, 0, 4], 1, (t, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    ci = np.einsum("tk,tsk->ts", n, wi)
    co = np.einsum("tk,tsk->ts", n, wo)
    valid = (ci > 0.2) & (co > 0.2)
    rho = rng.uniform(0.15, 0.35, t)
    if model == "torrance_sparrow":
        lobe = rng.uniform(0.25, 0.45, t)
        f = brdf.torrance_sparrow(n[:, None], wi, wo, rho[:, None], lobe[:, None])
    else:
        lobe = rng.uniform(10, 40, t)
        f = brdf.blinn_phong(n[:, None], wi, wo, rho[:, None], lobe[:, None])
    f = f + (0.05 * f + 0.003) * rng.standard_normal(f.shape)
    ft2 = fresnel_transmittance(np.clip(ci, 0, 1), ETA) * fresnel_transmittance(np.clip(co, 0, 1), ETA)
    albedo = rng.uniform(0.1, 0.3, (t, 3))
    samples = fitting.Samples.from_arrays(wi, wo, valid, engine="numpy")
    f_s, ft2_s = f[valid].astype(np.float32), ft2[valid].astype(np.float32)
    use = np.ones(samples.n, bool)
    for engine in ("numba", "numpy"):
        kw = dict(ft2=ft2_s, engine=engine, max_relative_error=0.5)
        fit = fitting.fit_specular_models(samples, n, f_s, use, (model,), normal_tilt=True, albedo=albedo, **kw)[model]
        plain = fitting.fit_specular_models(samples, n, f_s, use, (model,), **kw)[model]
        np.testing.assert_array_equal(fit.rho_s, plain.rho_s)  # the estimate does not move
        for k in range(t):
            v = valid[k]
            par = np.array([fit.rho_s[k], np.log(fit.lobe[k]), fit.diffuse_shift[k], 0, 0, 0, 0], np.float64)
            alpha = albedo[k].astype(np.float32).sum(dtype=np.float32)
            std_rho, std_lobe = _brute_force_std(model, par, wi[k, v], wo[k, v], n[k], f[k, v] * ci[k, v], alpha)
            np.testing.assert_allclose(fit.rho_s_std[k], std_rho, rtol=1e-2, err_msg=engine)
            np.testing.assert_allclose(fit.lobe_std[k], std_lobe, rtol=1e-2, err_msg=engine)


def test_engines_agree_on_tilt_errors(rng):
    """Both engines' tilt errors on a simulated capture agree as their errors without the tilt do: HC3 weights
    amplify the engines' float32 differences in the estimates (≤ 2e-4) up to a hundredfold in an ill-conditioned
    texel.  Measured 2026-12-07: medians ≤ 5e-6, 99th percentiles ≤ 9.1e-4, largest 3.3e-3 (Torrance-Sparrow ρs's
    error in one texel of 172, whose ρs differs by 3.3e-5)."""
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.face.procedural import procedural_face

    geometry = procedural_face(16)
    truth = synthesize_population(map_size=16, geometry=geometry, subjects=["S001"])[0]
    lt = DomeSimulator(geometry).simulate(truth).lumitexels()
    fits = {}
    for engine in ("numba", "numpy"):
        samples, _ = fitting.Samples.from_dome(lt.wi, lt.wo, lt.irradiance, lt.radiance, engine=engine)
        normal, _ = fitting.photometric_normals(samples, lt.scan_normal, lt.wo.shape[1])
        ci, co, ft2, use, f_r = fitting.brdf_samples(samples, normal)
        albedo, _ = fitting.refine_albedo(samples, f_r, ft2, samples.cos_half(ci, co), use)
        albedo = np.nan_to_num(albedo).astype(np.float32)
        f_s = fitting.specular_residual(samples, f_r, albedo, ft2)
        fits[engine] = fitting.fit_specular_models(
            samples,
            normal,
            f_s,
            use,
            ("torrance_sparrow", "blinn_phong"),
            cos=(ci, co),
            ft2=ft2,
            max_angle={"blinn_phong": np.radians(70)},
            engine=engine,
            normal_tilt=True,
            albedo=albedo,
        )
    for model in ("torrance_sparrow", "blinn_phong"):
        a, b = fits["numba"][model], fits["numpy"][model]
        ok = (a.flags == 0) & (b.flags == 0)
        assert ok.mean() > 0.9
        for name in ("rho_s_std", "lobe_std"):
            rel = np.abs(getattr(a, name)[ok] / getattr(b, name)[ok] - 1)
            assert np.median(rel) < 1e-4 and np.percentile(rel, 99) < 2e-3 and rel.max() < 1e-2, (model, name)


def test_tilt_of_the_diffuse_term_needs_its_albedo(rng):
    from facestats import FacestatsError

    wi, wo = hemisphere_pairs(rng, 2, 50)
    n = np.tile([0.0, 0.0, 1.0], (2, 1))
    samples = fitting.Samples.from_arrays(wi, wo, np.ones((2, 50), bool), engine="numpy")
    f_s, ft2 = np.full(samples.n, 0.1, np.float32), np.full(samples.n, 0.9, np.float32)
    use = np.ones(samples.n, bool)
    with pytest.raises(FacestatsError, match="albedo .* is required with normal_tilt and ft2"):
        fitting.fit_specular_models(samples, n, f_s, use, "torrance_sparrow", ft2=ft2, normal_tilt=True)
    with pytest.raises(FacestatsError, match=r"albedo must have shape \(2, 3\)"):
        fitting.fit_specular_models(
            samples, n, f_s, use, "torrance_sparrow", ft2=ft2, normal_tilt=True, albedo=np.ones((3, 3))
        )


def test_tilt_grids_of_both_engines_agree(rng):
    """The compiled grids equal numpy's: the dot products bit for bit, κ and 1/N·ω to float32 rounding; below the
    horizon both are 0."""
    from facestats.model.fitting.normal_tilt import tilt_grids

    n, lights, cams = 30, 40, 6
    wi = rng.normal(size=(n, lights, 3))
    wo = rng.normal(size=(n, cams, 3))
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    irr = np.ones((n, lights, 3), np.float32)
    rad = np.ones((n, cams, lights, 3), np.float32)
    samples, _ = fitting.Samples.from_dome(wi.astype(np.float32), wo.astype(np.float32), irr, rad, engine="numpy")
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    a, b = tilt_grids(samples, normal, ETA, "numpy"), tilt_grids(samples, normal, ETA, "numba")
    for grid_a, grid_b in zip(a, b):
        np.testing.assert_array_equal(grid_a[:, :2], grid_b[:, :2])
        np.testing.assert_allclose(grid_a[:, 2:], grid_b[:, 2:], rtol=2e-7, atol=0)
        assert np.any(grid_a[:, 3] == 0) and np.all((grid_a[:, 3] == 0) == (grid_a[:, 2] == 0))
