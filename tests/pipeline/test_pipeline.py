"""The fit pipeline against known truth (Weyrich et al. 2006 §4-5) and its robustness."""

import json
import os

import numpy as np
import pytest

from facestats import FacestatsError
from facestats.acquire.capture import open_capture
from facestats.acquire.synthetic.population import synthesize_population
from facestats.acquire.synthetic.simulate import DomeSimulator
from facestats.face.procedural import procedural_face
from facestats.io.schema import FLAG_BITS, validate_subject
from facestats.model import brdf
from facestats.model.fitting import fit_specular
from facestats.pipeline import FitSettings, fit_lumitexels, fit_population, fit_subject, held_out_camera_error
from tests.helpers import hemisphere_pairs


@pytest.fixture(scope="module")
def pop():
    return synthesize_population(map_size=32, geometry=procedural_face(32), conditions=False)


@pytest.fixture(scope="module")
def geom():
    return procedural_face(32)


@pytest.fixture(scope="module")
def ts_case(pop, geom):
    truth = pop[10]
    cap = DomeSimulator(geom).simulate(truth)
    return truth, cap, fit_subject(cap, pop.sigma_tr_avg)


def _rel(a, b, mask):
    return np.abs(a[mask] / b[mask] - 1)


def test_recovers_truth_within_issue_tolerances(ts_case):
    truth, cap, ds = ts_case
    validate_subject(ds)
    face = truth.region_map > 0
    ok = face & (ds.ts_flag.values == 0)
    assert 1 - ok.sum() / face.sum() <= 0.02
    assert np.median(_rel(ds.albedo.values, truth.albedo, face)) <= 0.02
    assert np.median(_rel(ds.ts_rho_s.values, truth.ts_rho_s, ok)) <= 0.05
    assert np.median(_rel(ds.ts_m.values, truth.ts_m, ok)) <= 0.05
    assert np.median(np.abs(ds.site_sigma_tr.values / truth.site_sigma_tr - 1)) <= 0.05
    # σ's and σa of every site within a few standard errors of the truth.
    sp, sa = truth.site_scattering
    z = (ds.site_sigma_a.values - sa) / ds.site_sigma_a_std.values
    assert np.all(np.abs(z) < 5)


def test_blinn_phong_on_blinn_phong_captures(pop, geom):
    truth = pop[20]
    cap = DomeSimulator(geom, specular="blinn_phong").simulate(truth)
    ds = fit_subject(cap, pop.sigma_tr_avg, FitSettings(models=("blinn_phong",), micro_normals=False))
    face = truth.region_map > 0
    ok = face & (ds.bp_flag.values == 0)
    assert 1 - ok.sum() / face.sum() <= 0.02
    assert np.median(_rel(ds.bp_rho_s.values, truth.bp_rho_s, ok)) <= 0.05
    assert np.median(_rel(ds.bp_exponent.values, truth.bp_exponent, ok)) <= 0.05


def test_normals_by_photometric_stereo_beat_the_scan(ts_case, geom):
    truth, cap, ds = ts_case
    true_n = np.zeros((32, 32, 3))
    true_n[geom.grid_index[:, 0], geom.grid_index[:, 1]] = geom.normal
    face = truth.region_map > 0
    err = np.degrees(np.arccos(np.clip(np.sum(ds.normal.values * true_n, -1), -1, 1)))[face]
    scan = cap.array("scan_normal")
    err_scan = np.degrees(np.arccos(np.clip(np.sum(scan * geom.normal, -1), -1, 1)))
    assert np.median(err) < 0.5 < np.median(err_scan)


def test_micro_normals_are_half_vectors_of_the_largest_brdf_samples(ts_case):
    """Per camera, where it sees the texel within eq. 14's 80° (the micro-normals' domain): 48 % of the
    (camera, texel) pairs of this 32² map."""
    _, _, ds = ts_case
    mn = ds.micro_normal.values
    ok = np.all(np.isfinite(mn), -1)
    assert ok.mean() > 0.4
    np.testing.assert_allclose(np.linalg.norm(mn[ok], axis=-1), 1, atol=1e-5)
    # Micro-normals lie near the diffuse normal (within the LED spacing of the dome).
    cos = np.sum(mn * ds.normal.values[None], -1)[ok]
    assert np.median(np.degrees(np.arccos(np.clip(cos, -1, 1)))) < 15


def test_provenance_and_units(ts_case):
    _, _, ds = ts_case
    prov = json.loads(ds.attrs["provenance"])
    assert prov["fit_settings"]["discard"] == 2 and prov["software"].startswith("facestats")
    assert prov["counts"]["samples_masked"] > 0
    assert ds.site_sigma_tr.attrs["units"] == "mm-1" and ds.sensor_profile.attrs["units"] == "mm-2"


def test_bad_samples_are_masked_and_counted(pop, geom):
    cap = DomeSimulator(geom).simulate(pop[4])
    lt = cap.lumitexels()
    base = fit_lumitexels(lt, FitSettings(models=("torrance_sparrow",), micro_normals=False))
    rad = lt.radiance.copy()
    rng = np.random.default_rng(0)
    good = np.argwhere(lt.valid)
    good = good[good[:, 0] != 5]  # lumitexel 5 loses a light below
    pick = good[rng.choice(len(good), 3000, replace=False)]
    rad[pick[:1000, 0], pick[:1000, 1], pick[:1000, 2], 1] = np.nan  # one channel NaN
    rad[pick[1000:2000, 0], pick[1000:2000, 1], pick[1000:2000, 2], 0] = -0.1  # negative radiance
    irr = lt.irradiance.copy()
    irr[5, 7, :] = 0  # a light without irradiance at one lumitexel
    lt.radiance, lt.irradiance = rad, irr
    out = fit_lumitexels(lt, FitSettings(models=("torrance_sparrow",), micro_normals=False))
    lost_light = int(cap.lumitexels().valid[5, :, 7].sum())
    assert out["n_invalid"].sum() - base["n_invalid"].sum() == 2000 + lost_light
    # Every (camera, light) slot is used, masked as invalid, or left out as grazing (> 80°).
    np.testing.assert_array_equal(out["n_samples"] + out["n_grazing"] + out["n_invalid"], 16 * 150)
    assert np.all(np.isfinite(out["albedo"]))
    np.testing.assert_allclose(np.median(out["ts_m"] / base["ts_m"]), 1, atol=0.01)


def test_texel_with_too_few_samples_is_flagged_and_filled_never_nan(pop, geom):
    cap = DomeSimulator(geom).simulate(pop[6])
    rad = cap.arrays["radiance"].copy()
    starved = np.arange(40, 60)
    keep = np.zeros(rad.shape[1:3], bool)
    keep[:2, :10] = True  # 2 cameras x 10 lights: at most 20 samples, below min_samples
    rad[starved] = np.where(keep[None, ..., None], rad[starved], np.nan)
    cap.arrays["radiance"] = rad
    ds = fit_subject(cap, pop.sigma_tr_avg, FitSettings(micro_normals=False))
    t = geom.grid_index[starved]
    flags = ds.ts_flag.values[t[:, 0], t[:, 1]]
    assert np.all(flags & FLAG_BITS["few_samples"]) and np.all(flags & FLAG_BITS["filled"])
    for var in ("albedo", "ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent", "normal"):
        assert np.all(np.isfinite(ds[var].values)), var
    truth = pop[6]
    filled = ds.ts_m.values[t[:, 0], t[:, 1]]
    assert np.median(np.abs(filled / truth.ts_m[t[:, 0], t[:, 1]] - 1)) < 0.15  # neighbours' values


def test_held_out_camera_is_predicted(pop, geom):
    cap = DomeSimulator(geom).simulate(pop[8])
    ds = fit_subject(
        cap, pop.sigma_tr_avg, FitSettings(exclude_cameras=(5,), models=("torrance_sparrow",), micro_normals=False)
    )
    err = held_out_camera_error(ds, cap, 5)
    assert err < 0.05


def test_fit_specular_public_api_recovers_parameters(rng):
    t, s = 400, 600
    wi, wo = hemisphere_pairs(rng, t, s)
    n = np.tile([0.0, 0.0, 1.0], (t, 1))
    rho, m = rng.uniform(0.15, 0.35, t), rng.uniform(0.2, 0.45, t)
    f = brdf.torrance_sparrow(n[:, None], wi, wo, rho[:, None], m[:, None])
    valid = rng.uniform(size=(t, s)) > 0.2
    res = fit_specular(wi, wo, n, f, valid, "torrance_sparrow")
    assert np.all(res.flags == 0)
    np.testing.assert_allclose(res.rho_s, rho, rtol=1e-3)
    np.testing.assert_allclose(res.lobe, m, rtol=1e-3)
    assert np.all(res.error < 1e-4)
    nexp = 2 / m**2 - 2
    fb = brdf.blinn_phong(n[:, None], wi, wo, rho[:, None] * 0.03, nexp[:, None]) + 0.002 * rng.standard_normal((t, s))
    rb = fit_specular(wi, wo, n, fb, valid, "blinn_phong")
    ok = rb.flags == 0
    assert ok.mean() > 0.95
    assert np.median(np.abs(rb.lobe[ok] / nexp[ok] - 1)) < 0.05
    # A Blinn-Phong texel that reflects more than it receives is flagged implausible (rho_s a(n) > 1), however well
    # it fits: rho_s 0.4 with n 148 reflects 1.56 at normal incidence (a default-store nose texel's fit)
    bright = brdf.blinn_phong(n[:4, None], wi[:4], wo[:4], np.array([[0.4], [0.2], [0.27], [0.24]]), 148.0)
    rbb = fit_specular(wi[:4], wo[:4], n[:4], bright, valid[:4], "blinn_phong")
    np.testing.assert_allclose(rbb.rho_s, [0.4, 0.2, 0.27, 0.24], rtol=1e-3)
    implausible = (rbb.flags & FLAG_BITS["implausible"]) != 0
    assert implausible.tolist() == [True, False, True, False]  # a(148) = 3.89: the limit is rho_s 0.257
    with pytest.raises(FacestatsError, match="model must be one of"):
        fit_specular(wi, wo, n, f, valid, "phong")
    with pytest.raises(FacestatsError, match="wi must have shape"):
        fit_specular(wi[:, :10], wo, n, f, valid, "torrance_sparrow")


def test_streaming_from_zarr_blocks_equals_in_memory(tmp_path, pop, geom):
    cap = DomeSimulator(geom).simulate(pop[3])
    path = cap.to_zarr(tmp_path / "c.zarr", chunk=256)
    a = fit_subject(cap, pop.sigma_tr_avg, FitSettings(micro_normals=False))
    b = fit_subject(open_capture(path), pop.sigma_tr_avg, FitSettings(micro_normals=False, block=200))
    for var in ("albedo", "ts_rho_s", "ts_m"):
        np.testing.assert_allclose(b[var].values, a[var].values, rtol=1e-4, atol=1e-7, err_msg=var)
    # Blinn-Phong on Torrance-Sparrow data has flat minima in a few texels (lips, n > 100): the
    # last-bit differences of float32 sums over differently aligned blocks move them slightly.
    face = a.region.values > 0
    rel = np.abs(b.bp_exponent.values[face] / a.bp_exponent.values[face] - 1)
    assert np.median(rel) < 1e-4 and rel.max() < 0.02


@pytest.mark.slow
def test_two_workers_give_the_one_worker_dataset(tmp_path, pop, geom):
    """Blocks on two worker processes and the stage-5 map jobs on two threads change nothing."""
    path = DomeSimulator(geom).simulate(pop[5]).to_zarr(tmp_path / "c.zarr", chunk=256)
    st = FitSettings(block=256)
    one = fit_subject(path, pop.sigma_tr_avg, st)
    two = fit_subject(path, pop.sigma_tr_avg, st, workers=2)
    assert set(one.data_vars) == set(two.data_vars) and "micro_normal" in one
    for var in one.data_vars:
        np.testing.assert_array_equal(two[var].values, one[var].values, err_msg=var)


@pytest.mark.slow
def test_population_fit_sigma_tr_avg_and_dask_parity(tmp_path, pop, geom):
    sim = DomeSimulator(geom)
    paths = [sim.simulate(pop[i]).to_zarr(tmp_path / f"{i}.zarr") for i in (0, 1, 2)]
    st = FitSettings(models=("torrance_sparrow",), micro_normals=False)
    serial, stra = fit_population(paths, st, scheduler="synchronous")
    parallel, stra2 = fit_population(paths, st, scheduler="processes", num_workers=2)
    np.testing.assert_array_equal(stra, stra2)
    tr = np.stack([d.site_sigma_tr.values[:2] for d in serial])  # cheek, forehead
    np.testing.assert_allclose(stra, tr.mean(axis=(0, 1)))
    for a, b in zip(serial, parallel):
        np.testing.assert_array_equal(a.ts_m.values, b.ts_m.values)


def test_distributed_client_blocks(tmp_path, pop, geom):
    distributed = pytest.importorskip("distributed")
    cap = DomeSimulator(geom).simulate(pop[1])
    path = cap.to_zarr(tmp_path / "d.zarr", chunk=256)
    st = FitSettings(models=("torrance_sparrow",), micro_normals=False, block=256)
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=2, dashboard_address=None) as client:
        a = fit_subject(path, settings=st, client=client)
    b = fit_subject(path, settings=st)
    np.testing.assert_array_equal(a.ts_m.values, b.ts_m.values)


def _random_samples(rng, n_tex=30, n_smp=40):
    from facestats.model.fitting import Samples

    wi, wo = hemisphere_pairs(rng, n_tex, n_smp)
    valid = rng.uniform(size=(n_tex, n_smp)) > 0.3
    valid[3] = False  # a lumitexel without samples
    valid[4, :2] = True
    valid[4, 2:] = False  # and one with only two
    return Samples.from_arrays(wi, wo, valid)


def test_stable_minimum_and_refined_albedo_against_per_texel_loops(rng):
    from facestats.model.fitting import albedo_stable_minimum, refine_albedo

    s = _random_samples(rng)
    brdf = rng.uniform(0.05, 0.5, (3, s.n)).astype(np.float32)
    brdf[:, s.texel == 4] = 0.001  # the lumitexel with too few samples has the smallest values of all
    ci, co = rng.uniform(0.05, 1, (2, s.n)).astype(np.float32)
    ft2 = rng.uniform(0.8, 0.95, s.n).astype(np.float32)
    use = rng.uniform(size=s.n) > 0.1
    use[s.texel == 4] = True
    k, gamma = 2, 1.0
    alb, n_used = albedo_stable_minimum(s, brdf, ci, co, ft2, use, discard=k, grazing_penalty=gamma)
    c0, c1 = np.cos(np.radians(60.0)), np.cos(np.radians(80.0))
    for t in range(s.n_texels):  # independent per-texel loop: sort by the penalised value, take the (k+1)-th
        sel = np.flatnonzero((s.texel == t) & use)
        assert n_used[t] == sel.size
        if sel.size <= k:
            assert np.all(np.isnan(alb[t]))
            continue
        pen = 1 + gamma * np.clip((c0 - np.minimum(ci[sel], co[sel])) / (c0 - c1), 0, 1)
        for c in range(3):
            val = np.pi * brdf[c, sel] / ft2[sel]
            np.testing.assert_allclose(alb[t, c], val[np.argsort(val * pen)[k]], rtol=1e-6)
    cos_half = rng.uniform(0, 1, s.n).astype(np.float32)
    ref, cnt = refine_albedo(s, brdf, ft2, cos_half, use)
    for t in range(s.n_texels):
        sel = np.flatnonzero((s.texel == t) & use & (cos_half < np.cos(np.radians(50.0))))
        assert cnt[t] == sel.size
        if sel.size:
            np.testing.assert_allclose(ref[t], (np.pi * brdf[:, sel] / ft2[sel]).mean(1), rtol=1e-5)
        else:
            assert np.all(np.isnan(ref[t]))
    # The padded layout: row t holds the values of lumitexel t's kept samples, in order.
    pad, counts = s.padded(np.arange(s.n, dtype=float), -1.0, mask=use)
    for t in (0, 3, 4, 17):
        kept = np.flatnonzero((s.texel == t) & use)
        np.testing.assert_array_equal(pad[t, : counts[t]], kept)
        assert np.all(pad[t, counts[t] :] == -1)


def test_fit_stages_reject_bad_arguments(rng):
    from facestats.model.fitting import (
        albedo_stable_minimum,
        fit_translucency,
        micro_normals,
        photometric_normals,
        scatter_to_map,
    )

    s = _random_samples(rng)
    ones = np.ones(s.n, np.float32)
    brdf = np.ones((3, s.n), np.float32)
    with pytest.raises(FacestatsError, match=r"discard must be an integer in \[0, inf\], got -1"):
        albedo_stable_minimum(s, brdf, ones, ones, ones, ones > 0, discard=-1)
    with pytest.raises(FacestatsError, match="grazing_start must be < grazing_end"):
        albedo_stable_minimum(s, brdf, ones, ones, ones, ones > 0, grazing_start=1.4, grazing_end=1.2)
    with pytest.raises(FacestatsError, match=r"ft2 must have shape \(%d\)" % s.n):
        albedo_stable_minimum(s, brdf, ones, ones, ones[1:], ones > 0)
    with pytest.raises(FacestatsError, match="samples must hold one wo_grid direction per camera"):
        photometric_normals(s, np.tile([0, 0, 1.0], (s.n_texels, 1)), 16)
    with pytest.raises(FacestatsError, match="n_cameras must be an integer"):
        micro_normals(s, 0, np.ones(s.n), np.ones(s.n, bool))
    with pytest.raises(FacestatsError, match=r"texel must lie in \[0, 4\)"):
        scatter_to_map(np.ones(2), np.array([[0, 0], [4, 1]]), 4)
    r = np.linspace(0.5, 5, 10)
    prof = np.exp(-r)[None]
    with pytest.raises(FacestatsError, match=r"std must have the shape of profile, \(1, 10\), got \(10,\)"):
        fit_translucency(r, prof, np.ones(10))
    with pytest.raises(FacestatsError, match=r"eta must lie in \[1, 3\]"):
        fit_translucency(r, prof, eta=0.5)


def test_photometric_normals_runs_at_least_one_pass(ts_case):
    from facestats.model import fitting

    _, cap, _ = ts_case
    lt = cap.lumitexels(0, 50)
    samples = fitting.Samples.from_grid(lt.wi, lt.wo, lt.irradiance, lt.radiance, lt.valid)
    one, _ = fitting.photometric_normals(samples, lt.scan_normal, 16, iterations=1)
    three, _ = fitting.photometric_normals(samples, lt.scan_normal, 16)
    assert np.median(np.degrees(np.arccos(np.clip(np.sum(one * three, 1), -1, 1)))) < 2  # refinement, not a new answer
    with pytest.raises(FacestatsError, match=r"iterations must be an integer in \[1, inf\], got 0"):
        fitting.photometric_normals(samples, lt.scan_normal, 16, iterations=0)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"discard": -1}, r"discard must be an integer in \[0, inf\]"),
        ({"min_samples": 1}, r"min_samples must be an integer in \[2, inf\]"),
        ({"block": 0}, r"block must be an integer in \[1, inf\]"),
        ({"models": ()}, "models must name at least one model"),
        ({"models": "torrance_sparrow"}, "models must be a tuple of model names"),
        ({"models": ("phong",)}, "models must be among"),
        ({"exclude_cameras": (-1,)}, r"exclude_cameras must be an integer in \[0, inf\]"),
        ({"grazing_penalty": -1.0}, r"grazing_penalty must lie in \[0, inf\]"),
        ({"max_angle_deg": 95.0}, r"max_angle_deg must lie in \(0, 90\] deg"),
        ({"max_relative_error": 0.0}, r"max_relative_error must lie in \(0, inf\]"),
        ({"eta": 0.5}, r"eta must lie in \[1, 3\]"),
        ({"normal_tilt": "yes"}, r"normal_tilt must be True or False, got 'yes'"),
    ],
)
def test_fit_settings_validation(kwargs, message):
    with pytest.raises(FacestatsError, match=message):
        FitSettings(**kwargs)


def test_fit_subject_and_build_store_reject_bad_arguments_early(tmp_path, ts_case):
    from facestats.pipeline.build import build_store

    _, cap, _ = ts_case
    with pytest.raises(FacestatsError, match=r"sigma_tr_avg must have shape \(3\)"):
        fit_subject(cap, [0.5, 1.0])
    with pytest.raises(FacestatsError, match=r"sigma_tr_avg must lie in \(0, inf\] mm\^-1"):
        fit_subject(cap, [0.5, 0.0, 1.5])
    with pytest.raises(FacestatsError, match=r"workers must be an integer in \[1, inf\]"):
        fit_subject(cap, workers=0)
    store = tmp_path / "s.zarr"
    with pytest.raises(FacestatsError, match=r"subjects must be ids of the population, got unknown \['S999'\]"):
        build_store(store, map_size=16, subjects=["S999"], workers=1)
    with pytest.raises(FacestatsError, match="subjects must be a sequence of subject ids, got the string"):
        build_store(store, map_size=16, subjects="S001", workers=1)
    with pytest.raises(FacestatsError, match=r"map_size must be an integer in \[8, inf\]"):
        build_store(store, map_size=4)
    assert not store.exists()  # bad arguments leave no empty store behind


def test_a_resumed_build_with_other_parameters_never_mixes_populations(tmp_path):
    from facestats.io import open_store
    from facestats.pipeline.build import build_store

    store = tmp_path / "s.zarr"
    assert build_store(store, map_size=8, subjects=["S001"], workers=1).written == ["S001"]
    for kw, differ in (({"seed": 7}, "seed"), ({"map_size": 12}, "geometry 'ict-8' stored, 'ict-12'"),
                       ({"specular": "blinn_phong"}, "specular"),  # and resumed with --no-micro-normals (a red team):
                       ({"micro_normals": False}, "micro-normal maps True stored, False in this build")):  # fmt: skip
        with pytest.raises(FacestatsError, match=f"holds S001 built with other parameters.*{differ}"):
            build_store(store, **{"map_size": 8, **kw}, subjects=["S001", "S002"], workers=1)
    with open_store(store) as st:
        assert st.ids() == ["S001"]  # nothing was added
    assert build_store(store, map_size=8, subjects=["S001", "S001"], workers=1).skipped == ["S001"]  # same build


def test_a_build_with_other_parameters_that_commits_meanwhile_is_caught_at_the_commit(tmp_path, monkeypatch):
    """Two builds with other seeds started into one empty store both passed the check made before anything ran,
    and the later commits replaced the other build's subjects: a store of two populations, every build reported
    "written" (a red team, with a distributed and a local build). Each commit checks the store again."""
    from facestats.io import open_store
    from facestats.pipeline import build

    other = tmp_path / "other.zarr"
    assert build.build_store(other, map_size=8, seed=7, subjects=["S001"], workers=1).written == ["S001"]
    with open_store(other) as st:
        foreign = st.subject("S001")
    store = tmp_path / "s.zarr"
    real_fit = build.fit_subject

    def fit_while_another_build_commits(*args, **kwargs):  # the other build commits while this one fits
        with open_store(store, mode="r+") as st:
            if "S001" not in st:
                st.write_subject(foreign)
        return real_fit(*args, **kwargs)

    monkeypatch.setattr(build, "fit_subject", fit_while_another_build_commits)
    report = build.build_store(store, map_size=8, subjects=["S002"], workers=1, retries=1)
    assert report.written == [] and "holds S001 built with other parameters" in report.failed["S002"]
    with open_store(store) as st:
        assert st.ids() == ["S001"]  # the other build's subject, and nothing of this one


_DETERMINISM = """
import hashlib, sys
import numpy as np
from facestats.pipeline.build import _population, _simulator, sensor_fits
from facestats.pipeline import FitSettings, fit_subject
pop = _population(2006, 48, False)
truth = pop["S007"]
ds = fit_subject(_simulator(48, "torrance_sparrow").simulate(truth), np.array([0.55, 0.98, 1.55]),
                 FitSettings(micro_normals=False))
h = hashlib.sha256()
for v in sorted(ds.data_vars):
    h.update(np.ascontiguousarray(ds[v].values).tobytes())
print(h.hexdigest())
"""


@pytest.mark.slow
def test_fit_does_not_depend_on_the_blas_kernel():
    """The simulator and the fit give the same bits whichever BLAS kernel the CPU selects.

    OpenBLAS picks its kernels by CPU (Haswell, SkylakeX, Zen, ...) and each sums matrix products in
    its own order; the default store was once built on a SkylakeX machine and could not be reproduced
    on a Zen one.  The pipeline therefore keeps BLAS out of the float32 paths (elementwise dot products)
    and sums over lights in float64.  Both kernels forced here run on any x86-64 CPU with AVX.
    """
    import subprocess
    import sys

    import numpy as np

    cfg = np.show_config(mode="dicts") if hasattr(np, "show_config") else {}
    blas = str(cfg.get("Build Dependencies", {}).get("blas", {}).get("name", ""))
    if "openblas" not in blas.lower():
        pytest.skip(f"numpy is not built with OpenBLAS (blas: {blas!r})")
    out = {}
    for core in ("Haswell", "Sandybridge"):
        env = {**os.environ, "OPENBLAS_CORETYPE": core}
        res = subprocess.run([sys.executable, "-c", _DETERMINISM], env=env, capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr[-2000:]
        out[core] = res.stdout.strip().splitlines()[-1]
    assert out["Haswell"] == out["Sandybridge"]
