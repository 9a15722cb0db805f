"""The numba engine against the numpy engine and independent references (:mod:`facestats.model.fitting.kernels`)."""

import os
import subprocess
import sys

import numpy as np
import pytest

from facestats import FacestatsError
from facestats.core.conventions import FLAG_BITS
from facestats.model import brdf, fitting
from facestats.model.fitting import engine as engines
from tests.helpers import hemisphere_pairs

pytest.importorskip("numba")


def _grid(rng, n=40, n_cam=5, n_led=30, frac=0.6):
    """A random dome grid with float16 radiance (NaN, negative, −0 and +inf entries) and some unlit lights."""
    wi = rng.normal(size=(n, n_led, 3))
    wo = rng.normal(size=(n, n_cam, 3))
    wi[..., 2], wo[..., 2] = np.abs(wi[..., 2]) + 0.3, np.abs(wo[..., 2]) + 0.3
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=-1, keepdims=True)
    irr = rng.uniform(0.5, 2, (n, n_led, 3)).astype(np.float32)
    irr[3, :4, 1] = 0  # unlit
    rad = rng.uniform(0.01, 1, (n, n_cam, n_led, 3)).astype(np.float16)
    rad[rng.uniform(size=(n, n_cam, n_led)) > frac] = np.nan
    rad[5, 1, 2, 0] = -0.5  # negative: invalid
    rad[6, 0, 1, 2] = -0.0  # −0: valid
    rad[7, 2, 3, 1] = np.inf  # +inf: valid (clipped bright sample)
    rad[2] = np.nan  # a lumitexel without samples
    return wi.astype(np.float32), wo.astype(np.float32), irr, rad


def test_engine_selection(monkeypatch):
    monkeypatch.delenv(engines.ENGINE_VARIABLE, raising=False)
    assert engines.default_engine() == "numba"
    monkeypatch.setenv(engines.ENGINE_VARIABLE, "numpy")
    assert engines.default_engine() == "numpy" and engines.resolve_engine() == "numpy"
    assert engines.resolve_engine("numba") == "numba"  # an explicit choice wins over the variable
    monkeypatch.setenv(engines.ENGINE_VARIABLE, "cuda")
    with pytest.raises(FacestatsError, match="FACESTATS_ENGINE must be one of"):
        engines.default_engine()
    with pytest.raises(FacestatsError, match=r"engine must be one of \['numba', 'numpy'\], got 'fortran'"):
        engines.resolve_engine("fortran")


def test_fast_exponential_and_logarithm_against_numpy(rng):
    from facestats.model.fitting.kernels.fastexp import fill_lobe, fill_log

    x = np.concatenate([np.linspace(-87, 0, 200_001), rng.uniform(-87, 0, 100_000)]).astype(np.float32)
    out = np.empty_like(x)
    fill_lobe(np.float32(1.0), x, np.ones_like(x), 0, x.size, out, np.empty(x.size, np.int32))
    ref = np.exp(x.astype(np.float64))
    assert np.max(np.abs(out / ref - 1)) < 3e-7
    c = np.concatenate([np.geomspace(1e-6, 1, 200_001), rng.uniform(1e-6, 1, 100_000)]).astype(np.float32)
    lg = np.empty_like(c)
    fill_log(c, lg, np.empty(c.size, np.int32))
    ref = np.log(c.astype(np.float64))
    assert np.all(np.abs(lg - ref) <= 1.5e-7 + 6e-8 * np.abs(ref))  # about one float32 ulp of the result


def test_float16_to_float32_conversion_is_numpys_for_every_bit_pattern():
    """The kernel's conversion of the captured float16 radiance gives numpy's float32 bits for all 65,536 halves
    (zeros, subnormals, normals, ±inf and NaN payloads)."""
    from facestats.model.fitting.kernels.samples import halves_to_singles

    halves = np.arange(65536, dtype=np.uint32).astype(np.uint16)
    got = halves_to_singles(halves.astype(np.int32).reshape(2, -1).copy()).reshape(-1)
    np.testing.assert_array_equal(got.view(np.int32), halves.view(np.float16).astype(np.float32).view(np.int32))


def test_flattened_grid_and_cosines_are_the_numpy_ones(rng):
    wi, wo, irr, rad = _grid(rng)
    keep = np.array([True, False, True, True, True])
    a, inv_a = fitting.Samples.from_dome(wi, wo, irr, rad, keep_cameras=keep, engine="numpy")
    b, inv_b = fitting.Samples.from_dome(wi, wo, irr, rad, keep_cameras=keep, engine="numba")
    np.testing.assert_array_equal(inv_a, inv_b)
    for name in ("texel", "camera_index", "light_index", "radiance", "irradiance"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    np.testing.assert_array_equal(a.counts, b.counts)
    np.testing.assert_array_equal(a._grid_index(), b._grid_index())
    for x, y in zip(a.camera_runs(), b.camera_runs()):
        np.testing.assert_array_equal(x, y)
    normal = rng.normal(size=(a.n_texels, 3)).astype(np.float32)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    for x, y in zip(a.cos(normal), b.cos(normal)):  # the same float32 operations in the same order
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.cos_io(), b.cos_io())


def assert_equal_bits(x, y):
    """Equal arrays, NaNs included (the same float bits up to NaN payloads)."""
    np.testing.assert_array_equal(x, y, strict=True)


def test_stages_agree_between_engines(rng):
    """Normals, micro-normals, the BRDF samples of eq. 8, N·H and the stable minimum are the same bits; the
    refined albedo to float32 rounding."""
    wi, wo, irr, rad = _grid(rng, n=60, n_cam=6, n_led=40, frac=0.8)
    scan = np.tile(np.float32([0, 0, 1]), (60, 1))
    out = {}
    for eng in ("numpy", "numba"):
        s, _ = fitting.Samples.from_dome(wi, wo, irr, rad, engine=eng)
        normal, cam = fitting.photometric_normals(s, scan, 6, min_lights=4)
        brdf = fitting.brdf_samples(s, normal, max_angle_deg=80.2)
        ci, co, ft2, use, f_r = brdf
        micro = fitting.micro_normals(s, 6, ci, use)
        with np.errstate(divide="ignore", invalid="ignore"):
            assert_equal_bits(f_r, s.radiance / (s.irradiance * np.maximum(ci, 0)))  # eq. 8
        assert_equal_bits(ft2, fitting.fresnel_factors(s, normal)[2])
        alb, n_used = fitting.albedo_stable_minimum(s, f_r, ci, co, ft2, use, discard=2, grazing_penalty=1.5)
        cos_half = s.cos_half(ci, co)
        ref, n_ref, grey_std = fitting.refine_albedo(s, f_r, ft2, cos_half, use, min_half_angle=0.3, with_std=True)
        # The standard error of the grey albedo by hand: std (n − 1) of v_R + v_G + v_B over √n, v = π f_r/F_t F_t.
        sel = use & (cos_half < np.cos(0.3))
        t = int(np.argmax(n_ref))
        run = slice(s.starts[t], s.starts[t] + s.counts[t])
        v = (np.pi * f_r[:, run][:, sel[run]] / ft2[run][sel[run]]).sum(0)
        assert v.size == n_ref[t] > 3
        assert grey_std[t] == pytest.approx(np.std(v, ddof=1) / np.sqrt(v.size), rel=1e-5)
        out[eng] = (normal, cam, micro, *brdf, cos_half, alb, n_used, ref, n_ref)
    (*same0, r0, k0), (*same1, r1, k1) = out["numpy"], out["numba"]
    assert np.isfinite(same0[0]).all() and np.isfinite(same0[-2][:, 0]).sum() > 40
    assert 0 < same0[6].mean() < 1  # some samples beyond the angle limit
    for x, y in zip(same0 + [k0], same1 + [k1]):
        assert_equal_bits(x, y)
    np.testing.assert_allclose(r1, r0, rtol=2e-6, equal_nan=True)


def test_brdf_samples_at_a_signed_zero_cosine_are_numpys():
    """cos θi = −0 exactly (every product −0): f_r = L/(E max(cos θi, 0)) is +inf in both engines (numpy's
    maximum(−0, 0) is +0)."""
    wi = np.float32([[[-0.6, -0.8, -0.0], [0.0, 0.6, 0.8]]])
    wo = np.float32([[[0.0, 0.0, 1.0]]])
    irr = np.ones((1, 2, 3), np.float32)
    rad = np.full((1, 1, 2, 3), 0.5, np.float16)
    normal = np.float32([[0.0, 0.0, 1.0]])
    out = {}
    for eng in ("numpy", "numba"):
        s, _ = fitting.Samples.from_dome(wi, wo, irr, rad, engine=eng)
        out[eng] = fitting.brdf_samples(s, normal)
    assert np.signbit(out["numba"].cos_i[0]) and out["numba"].f_r[0, 0] == np.inf
    for x, y in zip(out["numpy"], out["numba"]):
        assert_equal_bits(x, y)


def test_photometric_stereo_with_non_finite_values_in_both_engines(rng):
    """A grey value that is NaN (+inf radiance over an irradiance whose channel sum overflows) is left out
    alike by both engines; a light direction that is not finite is refused by name."""
    wi, wo, irr, rad = _grid(rng, n=30, n_cam=6, n_led=40, frac=0.9)
    irr[3, :5] = 3e38  # Σ E⊥ overflows to inf
    rad[3, :, :5] = np.inf  # valid (≥ 0): L/E = inf/inf = NaN
    scan = np.tile(np.float32([0, 0, 1]), (30, 1))
    out = {}
    for eng in ("numpy", "numba"):
        s, _ = fitting.Samples.from_dome(wi, wo, irr, rad, engine=eng)
        with np.errstate(invalid="ignore", over="ignore"):
            assert np.isnan(s.grey()).any()
            out[eng] = fitting.photometric_normals(s, scan, 6, min_lights=4)
    assert np.isfinite(out["numba"][0]).all()
    for x, y in zip(out["numpy"], out["numba"]):
        assert_equal_bits(x, y)
    wi[2, 7] = np.nan
    for eng in ("numpy", "numba"):
        s, _ = fitting.Samples.from_dome(wi, wo, irr, rad, engine=eng)
        with pytest.raises(FacestatsError, match="wi_grid must hold finite directions.*lumitexel 2, light 7"):
            fitting.photometric_normals(s, scan, 6, min_lights=4)


def test_specular_fits_agree_between_engines_and_recover_the_truth(rng):
    t, s = 300, 500
    wi, wo = hemisphere_pairs(rng, t, s)
    n = np.tile([0.0, 0.0, 1.0], (t, 1))
    rho, m = rng.uniform(0.15, 0.35, t), rng.uniform(0.2, 0.45, t)
    f = brdf.torrance_sparrow(n[:, None], wi, wo, rho[:, None], m[:, None]) + 0.01 * rng.standard_normal((t, s))
    valid = rng.uniform(size=(t, s)) > 0.2
    fits = {e: fitting.fit_specular(wi, wo, n, f, valid, "torrance_sparrow", engine=e) for e in ("numpy", "numba")}
    a, b = fits["numpy"], fits["numba"]
    # float64 (numba) and float32 (numpy) sums can end a rare texel on either side of max_iter.
    assert np.mean(a.flags == b.flags) >= 0.99
    ok = (a.flags == 0) & (b.flags == 0)
    assert ok.mean() > 0.95
    # Both stop within the solver's tolerance of the same minimum: tol = 1e-6 on E² bounds parameter changes ~1e-3.
    for name in ("rho_s", "lobe"):
        np.testing.assert_allclose(getattr(b, name)[ok], getattr(a, name)[ok], rtol=1e-3, err_msg=name)
    for name in ("rho_s_std", "lobe_std"):  # formed from the residuals at those parameters
        np.testing.assert_allclose(getattr(b, name)[ok], getattr(a, name)[ok], rtol=2e-2, err_msg=name)
    # numpy forms E² from float32 sums where it does not cancel (≥ 1 % of Σy²): ~1e-5 relative.
    np.testing.assert_allclose(b.error[ok], a.error[ok], rtol=1e-4)
    # Both recover the truth to within a few standard errors.
    z = (b.lobe[ok] - m[ok]) / b.lobe_std[ok]
    assert np.percentile(np.abs(z), 95) < 3


def test_angle_limits_give_each_model_its_domain_in_both_engines(rng):
    """fit_specular_models with per-model angle limits (the compiled engine forms the full domain and the first
    limit in one pass, any further limit in another) fits each model on its own domain's samples (as a fit of
    those samples alone), and both engines form the same domains."""
    wi, wo, irr, rad = _grid(rng, n=60, n_cam=6, n_led=40, frac=0.9)
    scan = np.tile(np.float32([0, 0, 1]), (60, 1))
    models = ("torrance_sparrow", "blinn_phong")
    results = {}
    for eng in ("numpy", "numba"):
        s, _ = fitting.Samples.from_dome(wi, wo, irr, rad, engine=eng)
        normal, _ = fitting.photometric_normals(s, scan, 6, min_lights=4)
        ci, co, ft2, use, f_r = fitting.brdf_samples(s, normal)
        alb, _ = fitting.albedo_stable_minimum(s, f_r, ci, co, ft2, use)
        f_s = fitting.specular_residual(s, f_r, np.nan_to_num(alb), ft2)
        common = dict(cos=(ci, co), ft2=ft2, min_samples=10)
        for limits in ({"blinn_phong": np.radians(60)}, {"blinn_phong": np.radians(60), "torrance_sparrow": 1.2}):
            fits = fitting.fit_specular_models(s, normal, f_s, use, models, max_angle=limits, **common)
            for m in models:
                if m not in limits:
                    continue
                c = np.float32(np.cos(limits[m]))
                alone = fitting.fit_specular_models(
                    s, normal, f_s, use & (ci > c) & (co > c), (m,), start=fits[m].lobe * 0 + np.nan, **common
                )[m]
                if m == models[0]:  # the first model starts cold in both fits
                    np.testing.assert_array_equal(fits[m].rho_s, alone.rho_s)
                np.testing.assert_array_equal(fits[m].n_samples, alone.n_samples)
                assert (
                    fits[m].n_samples < fitting.fit_specular_models(s, normal, f_s, use, (m,), **common)[m].n_samples
                ).any()
            results[(eng, len(limits))] = fits
        # float64 cosines: the limits are compared in float64 in both engines (the float32 factors follow)
        limits = {"blinn_phong": np.radians(60)}
        cos64 = (ci.astype(np.float64), co.astype(np.float64))
        cos64[0][::7] = np.float64(np.float32(np.cos(limits["blinn_phong"]))) + 1e-12  # above the limit only in float64
        results[(eng, "float64")] = fitting.fit_specular_models(
            s, normal, f_s, use, models, max_angle=limits, **{**common, "cos": cos64}
        )
        c = np.cos(limits["blinn_phong"]).astype(np.float32)
        want = s.count(use & (cos64[0] > c) & (cos64[1] > c) & np.isfinite(f_s))
        np.testing.assert_array_equal(results[(eng, "float64")]["blinn_phong"].n_samples, want)
    for k in (1, 2, "float64"):  # the same domains in both engines
        for m in models:
            np.testing.assert_array_equal(results[("numpy", k)][m].n_samples, results[("numba", k)][m].n_samples)


def test_lumitexels_without_valid_samples_are_flagged_few_samples_in_both_engines(rng):
    wi, wo, irr, rad = _grid(rng, n=20, n_cam=4, n_led=30, frac=0.8)
    rad[:] = np.nan  # no valid sample anywhere
    normal = np.tile(np.float32([0, 0, 1]), (20, 1))
    for eng in ("numpy", "numba"):
        s, _ = fitting.Samples.from_dome(wi, wo, irr, rad, engine=eng)
        ci, co, ft2, use, f_r = fitting.brdf_samples(s, normal)
        f_s = fitting.specular_residual(s, f_r, np.zeros((20, 3), np.float32), ft2)
        models = ("torrance_sparrow", "blinn_phong")
        fits = fitting.fit_specular_models(
            s, normal, f_s, use, models, cos=(ci, co), ft2=ft2, max_angle={models[1]: 1.2}
        )
        for fit in fits.values():
            assert s.n == 0 and fit.n_samples.shape == (20,) and (fit.n_samples == 0).all()
            assert (fit.flags == FLAG_BITS["few_samples"]).all() and np.isnan(fit.rho_s).all()


def test_a_block_of_no_lumitexels_gives_empty_results_in_both_engines():
    """Zero lumitexels (an empty block) run through every stage: empty results, no crash (the compiled
    kernels once read a run start that did not exist)."""
    e = np.zeros(0, np.float32)
    grid = (np.zeros((0, 4, 3), np.float32), np.zeros((0, 2, 3), np.float32), np.ones((0, 4, 3), np.float32))
    for eng in ("numpy", "numba"):
        s, n_invalid = fitting.Samples.from_dome(*grid, np.ones((0, 2, 4, 3), np.float16), engine=eng)
        assert s.starts.shape == s.counts.shape == n_invalid.shape == (0,)
        normal, _ = fitting.photometric_normals(s, np.zeros((0, 3), np.float32), 2)
        ci, co, ft2, use, f_r = fitting.brdf_samples(s, normal)
        alb, _ = fitting.albedo_stable_minimum(s, f_r, ci, co, ft2, use)
        ref, _ = fitting.refine_albedo(s, f_r, ft2, s.cos_half(ci, co), use)
        assert normal.shape == alb.shape == ref.shape == (0, 3)
        for limits in (None, {"blinn_phong": 1.2}):
            fits = fitting.fit_specular_models(
                s, normal, e, use, ("torrance_sparrow", "blinn_phong"), cos=(ci, co), ft2=ft2, max_angle=limits
            )
            assert all(f.rho_s.shape == (0,) for f in fits.values())


def test_numba_engine_rejects_bad_input_like_numpy():
    with pytest.raises(FacestatsError, match="wi must have shape"):
        fitting.fit_specular(
            np.zeros((2, 3, 3)),
            np.zeros((2, 4, 3)),
            np.zeros((2, 3)),
            np.zeros((2, 4)),
            np.ones((2, 4), bool),
            "torrance_sparrow",
            engine="numba",
        )


def _fit_digest() -> str:
    """SHA-256 of the normals, albedo and both specular models' fits of a fixed random dome, numba engine."""
    import hashlib

    rng = np.random.default_rng(7)
    wi, wo, irr, rad = _grid(rng, n=80, n_cam=6, n_led=60, frac=0.8)
    s, _ = fitting.Samples.from_dome(wi, wo, irr, rad, engine="numba")
    normal, _ = fitting.photometric_normals(s, np.tile(np.float32([0, 0, 1]), (80, 1)), 6, min_lights=4)
    ci, co, ft2 = fitting.fresnel_factors(s, normal)
    f_r = s.radiance / (s.irradiance * np.maximum(ci, 0))
    use = (ci > 0.17) & (co > 0.17)
    alb, _ = fitting.albedo_stable_minimum(s, f_r, ci, co, ft2, use)
    f_s = fitting.specular_residual(s, f_r, alb, ft2)
    fits = fitting.fit_specular_models(s, normal, f_s, use, ("torrance_sparrow", "blinn_phong"), min_samples=10)
    h = hashlib.sha256()
    for a in (normal, alb, *(getattr(f, k) for f in fits.values() for k in ("rho_s", "lobe", "error", "rho_s_std"))):
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


@pytest.mark.slow
def test_compiled_kernels_give_the_same_bits_on_any_cpu(tmp_path):
    """Kernels compiled for a generic x86-64 CPU (no AVX) and for this host's CPU give the same bits.

    LLVM vectorises the kernels with the widest vectors the CPU has; without fastmath it may not
    reorder sums or fuse multiply-adds, so the results must not change.
    """
    import platform

    if platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip("the generic CPU name used here is x86-64's")
    if os.environ.get("NUMBA_CPU_NAME", "host") != "host":  # this process would not hold the host's kernels
        pytest.skip(f"NUMBA_CPU_NAME={os.environ['NUMBA_CPU_NAME']} is set: the host's kernels cannot be compared")
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    # The generic CPU's kernels are compiled afresh into a temporary cache, in a process of their own; this
    # process's kernels are the host's.
    env = {**os.environ, "PYTHONPATH": root, "NUMBA_CPU_NAME": "x86-64", "NUMBA_CPU_FEATURES": ""}
    env["NUMBA_CACHE_DIR"] = str(tmp_path)
    script = "from tests.model.fitting.test_engines import _fit_digest; print(_fit_digest())"
    generic = subprocess.Popen([sys.executable, "-c", script], env=env, cwd=root, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        host = _fit_digest()  # while the generic kernels compile
        out, err = generic.communicate(timeout=900)
    finally:
        if generic.poll() is None:  # this process failed first: stop the compile
            generic.kill()
            generic.wait()
    assert generic.returncode == 0, err[-2000:]
    assert out.strip().splitlines()[-1] == host


@pytest.mark.parametrize("engine", ["numba", "numpy"])
@pytest.mark.parametrize("eta, message", [(np.nan, "finite"), (0.0, "eta must lie"), (None, "numeric"),
                                          (-1.0, "eta must lie"), ([1.3, 1.4], "eta must be one number")])  # fmt: skip
def test_both_engines_check_eta(engine, eta, message):
    """The compiled path read eta unchecked: NaN, 0 or None fitted ρs 0.0036 for 0.1 with no flag (a red team)."""
    wi, wo = hemisphere_pairs(np.random.default_rng(3), 2, 60)
    n = np.tile([0.0, 0.0, 1.0], (2, 1))
    fs = brdf.torrance_sparrow(n[:, None], wi, wo, 0.1, 0.3)
    with pytest.raises(FacestatsError, match=message):
        fitting.fit_specular(wi, wo, n, fs, np.ones((2, 60), bool), "torrance_sparrow", eta=eta, engine=engine)
