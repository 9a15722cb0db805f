"""The fit at population scale (issue: the population at scale, items 1, 2, 3 and 5).

Figures, each beside its named baseline:

* ``full_resolution``: one full-resolution subject (901,532 lumitexels × ~940
  samples, ``bench_simulate.full_resolution_capture``, or the capture at
  ``$FACESTATS_BENCH_CAPTURE``) fitted from zarr block by block on two local
  worker processes with the compiled kernels (``engine="numba"``) and, as the
  baseline, with the numpy engine (the pipeline before them); wall time against
  the 30 s target, nanoseconds per sample, peak resident memory (main process,
  workers), and the largest relative differences of the maps between the two
  engines over the face (the parameters must stay within 1e-3 of the numpy
  engine's).
* ``fit_stages``: where one process's fit time goes, ms per 2,048-lumitexel block of the
  full-resolution capture for reading and each stage of ``fit_lumitexels`` (no baseline: the figures
  to compare are the same benchmark at another commit).
* ``codec``: decoding the radiance of a capture stored with Blosc-LZ4 (what
  captures use) against zarr's default zstd (the baseline): µs per lumitexel
  and bytes.
* ``cluster_scaling``: ``n`` full-resolution subjects fitted into a store on a
  ``distributed.LocalCluster`` of 1 and of 2 workers (one process per worker,
  each fitting its subject's blocks in turn): subjects per hour, the scaling
  efficiency (speed-up / workers), the measured cost per subject and the plan
  for the 149-subject population on N workers.  The subjects are one simulated
  full-resolution capture under ``n`` ids (its arrays linked, not copied: the
  fit's cost does not depend on the subject, and twelve 7 GB captures would not
  fit on the disk).
* ``calibration``: coverage of the nominal 90 % intervals (±1.645 standard
  errors) of ρs and the lobe parameter over the unflagged texels of simulated
  captures with known truth, per model (Torrance-Sparrow on Torrance-Sparrow
  captures, Blinn-Phong on Blinn-Phong captures); the target is 85-95 %.  The
  baseline is the same with ``normal_tilt=False`` (errors conditional on the
  photometric-stereo normal, as before 2026-12-05); ``calibration_variants``
  compares the nuisance columns the pipeline's were chosen among.
* ``blinn_phong_maps``: Blinn-Phong fits of default-population subjects on
  Torrance-Sparrow captures, fitted within 80° (eq. 14 as printed, the
  baseline) and within 70° (``FitSettings.bp_max_angle_deg``): flagged share,
  95th percentile of the exponent on lips and chin, E_BP/E_TS on the same
  samples, relative RMSE of a held-out camera.

Every benchmark takes its sizes as arguments; ``SMOKE`` gives tiny ones that the
test suite runs (``tests/test_benchmarks.py``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

#: The issue's target for one full-resolution subject on this 2-core machine.
TARGET_FULL_RESOLUTION_S = 30.0
#: Subjects of the paper's population (Weyrich et al. 2006 §7).
POPULATION = 149

_FIT = r"""
import json, resource, sys, time
import numpy as np
from facestats.pipeline import FitSettings, fit_subject
from facestats.io.schema import FLAG_BITS
path, workers, block, engine, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], sys.argv[5]
t0 = time.perf_counter()
ds = fit_subject(path, settings=FitSettings(block=block, engine=engine), workers=workers)
t1 = time.perf_counter()
face = ds.region.values > 0
filled = FLAG_BITS["filled"]  # 2048² maps interpolate most texels of a 1152² lumitexel grid
np.savez(out, **{v: ds[v].values for v in ("albedo", "normal", "ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent",
                                            "ts_flag", "bp_flag", "region")})
prov = json.loads(ds.attrs["provenance"])["counts"]
print(json.dumps({"fit_s": t1 - t0, "peak_rss_main_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "peak_rss_workers_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
                  "samples": prov["samples_used"] + prov["samples_grazing"], "map_size": int(ds.sizes["u"]),
                  "bp_flagged": float(((ds.bp_flag.values[face] | filled) != filled).mean())}))  # by the fit
"""


def _capture(grid, map_size):
    """The full-resolution capture: ``$FACESTATS_BENCH_CAPTURE`` if set, else the cached simulated one."""
    if os.environ.get("FACESTATS_BENCH_CAPTURE") and grid is None:
        return os.environ["FACESTATS_BENCH_CAPTURE"], {}
    from bench_simulate import FULL_GRID, FULL_MAP_SIZE, full_resolution_capture

    return full_resolution_capture(grid or FULL_GRID, map_size or FULL_MAP_SIZE)


def _fit_in_subprocess(path, workers, block, engine, out):
    res = subprocess.run(
        [sys.executable, "-c", _FIT, path, str(workers), str(block), engine, out],
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(res.stdout.strip().splitlines()[-1])


def _max_relative(a, b, mask):
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.abs(a[mask] / b[mask] - 1)
    rel = rel[np.isfinite(rel)]
    return (float(np.max(rel)), float(np.percentile(rel, 99)), float(np.median(rel))) if rel.size else (0.0,) * 3


def bench_full_resolution(workers=2, block=2048, grid=None, map_size=None, baseline=True):
    """Numba engine against the numpy engine (baseline) on one full-resolution subject (module docstring)."""
    path, simulated = _capture(grid, map_size)
    figures = {f"simulate_{k}": v for k, v in simulated.items()}
    with tempfile.TemporaryDirectory() as tmp:
        fast = _fit_in_subprocess(path, workers, block, "numba", os.path.join(tmp, "numba.npz"))
        figures.update({f"numba_{k}": v for k, v in fast.items()})
        figures["numba_ns_per_sample"] = 1e9 * fast["fit_s"] / fast["samples"]
        figures["target_s"] = TARGET_FULL_RESOLUTION_S
        if baseline:
            slow = _fit_in_subprocess(path, workers, block, "numpy", os.path.join(tmp, "numpy.npz"))
            figures.update({f"numpy_{k}": v for k, v in slow.items() if k != "samples"})
            figures["speedup"] = slow["fit_s"] / fast["fit_s"]
            a, b = np.load(os.path.join(tmp, "numba.npz")), np.load(os.path.join(tmp, "numpy.npz"))
            face = a["region"] > 0
            for var in ("albedo", "ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent"):
                ok = face if var == "albedo" else face & (a[f"{var[:2]}_flag"] == 0) & (b[f"{var[:2]}_flag"] == 0)
                mask = np.broadcast_to(ok[..., None], a[var].shape) if a[var].ndim == 3 else ok
                mx, p99, med = _max_relative(a[var], b[var], mask)
                figures[f"max_rel_diff_{var}"] = mx
                figures[f"p99_rel_diff_{var}"] = p99
                figures[f"median_rel_diff_{var}"] = med
    figures["workers"] = workers
    return figures


def bench_fit_stages(blocks=20, block=2048, grid=None, map_size=None, engine="numba", normal_tilt=True):
    """Where one process's fit time goes: ms per ``block``-lumitexel block for reading and each stage.

    ``blocks`` blocks from the middle third of the full-resolution capture (``_capture``), one process,
    after one warm-up block (the one before them); stages as :func:`facestats.pipeline.fit_lumitexels` times them
    (``timings=``), reading as :meth:`facestats.acquire.capture.Capture.lumitexels`.  The projected
    one-core time of the whole capture is the per-block total times its blocks.  ``normal_tilt=False`` fits
    without the tilts' columns in the standard errors (:class:`facestats.pipeline.FitSettings`): their cost is
    the difference.  ``budget_ms_per_block``: what the 30 s target leaves a block on two workers, before the
    maps are assembled (an upper bound: the maps take seconds more).
    """
    from facestats.acquire.capture import open_capture
    from facestats.pipeline import FitSettings
    from facestats.pipeline.lumitexels import fit_lumitexels

    path, _ = _capture(grid, map_size)
    capture = open_capture(path)
    settings = FitSettings(block=block, engine=engine, normal_tilt=normal_tilt)
    ranges = list(capture.blocks(block))
    first = max(1, len(ranges) // 3)
    chosen = ranges[first : first + blocks]
    fit_lumitexels(capture.lumitexels(*ranges[first - 1]), settings)  # warm-up (kernels loaded), not measured
    timings = {"read": 0.0}
    for a, b in chosen:
        t0 = time.perf_counter()
        lt = capture.lumitexels(a, b)
        timings["read"] += time.perf_counter() - t0
        fit_lumitexels(lt, settings, timings=timings)
    out = {f"{k}_ms_per_block": 1e3 * v / len(chosen) for k, v in timings.items()}
    total = sum(timings.values()) / len(chosen)
    return {
        "total_ms_per_block": 1e3 * total,
        **out,
        "blocks": len(chosen),
        "block": block,
        "projected_one_core_s": total * len(ranges),
        "budget_ms_per_block": 1e3 * TARGET_FULL_RESOLUTION_S * 2 / len(ranges),
    }


def bench_codec(grid=256, map_size=512, lumitexels=8192):
    """Radiance decoding: Blosc-LZ4 (captures) against zarr's default zstd (module docstring)."""
    import zarr
    from zarr.codecs import BloscCodec

    from facestats.acquire.capture import open_capture

    # The capture of bench_simulate.full_resolution_capture at these sizes (one input, one key: the codec's own
    # copy of it was named alike with other parameters, and each rebuilt the other's under the same name).
    path, _ = _capture(grid, map_size)
    data = open_capture(path).arrays["radiance"][:lumitexels]
    out = {"lumitexels": int(data.shape[0])}
    with tempfile.TemporaryDirectory() as tmp:
        for name, comp in (("lz4", [BloscCodec(cname="lz4", clevel=5, shuffle="noshuffle")]), ("zstd", None)):
            g = zarr.open_group(os.path.join(tmp, name), mode="w")
            kw = {} if comp is None else {"compressors": comp}
            arr = g.create_array("r", shape=data.shape, chunks=(2048,) + data.shape[1:], dtype=data.dtype, **kw)
            arr[:] = data
            best = np.inf
            for _ in range(3):
                t0 = time.process_time()
                arr[:]
                best = min(best, time.process_time() - t0)
            size = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(os.path.join(tmp, name)) for f in fs)
            out[f"{name}_decode_us_per_lumitexel"] = 1e6 * best / data.shape[0]
            out[f"{name}_bytes_per_lumitexel"] = size / data.shape[0]
    out["decode_speedup"] = out["zstd_decode_us_per_lumitexel"] / out["lz4_decode_us_per_lumitexel"]
    out["size_ratio"] = out["lz4_bytes_per_lumitexel"] / out["zstd_bytes_per_lumitexel"]
    return out


def _subject_views(path, n, root):
    """``n`` captures sharing ``path``'s arrays (symlinks) under ids X000, X001, ... (one zarr.json each)."""
    views = []
    meta = json.loads(open(os.path.join(path, "zarr.json")).read())
    for i in range(n):
        view = os.path.join(root, f"X{i:03d}.zarr")
        os.makedirs(view)
        for name in os.listdir(path):
            if name != "zarr.json":
                os.symlink(os.path.join(os.path.abspath(path), name), os.path.join(view, name))
        m = json.loads(json.dumps(meta))
        m["attributes"].update(subject_id=f"X{i:03d}", person_id=f"X{i:03d}")
        with open(os.path.join(view, "zarr.json"), "w") as fh:
            json.dump(m, fh)
        views.append(view)
    return views


def bench_cluster_scaling(n=12, grid=None, map_size=None, workers=(1, 2), block=2048):
    """Subjects per hour on a LocalCluster of 1 and 2 workers, and the plan for 149 (module docstring)."""
    from distributed import Client, LocalCluster

    from facestats.pipeline import FitSettings, fit_population

    path, _ = _capture(grid, map_size)
    settings = FitSettings(micro_normals=False, block=block)
    out = {"subjects": n}
    with tempfile.TemporaryDirectory() as tmp:
        views = _subject_views(path, n, tmp)
        for w in workers:
            store = os.path.join(tmp, f"store{w}.zarr")
            with (
                LocalCluster(n_workers=w, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
                Client(cluster) as client,
            ):
                client.run(_warm)  # imports and compiled kernels loaded in every worker
                t0 = time.perf_counter()
                fit_population(views, settings, client=client, store=store)
                seconds = time.perf_counter() - t0
                rss = client.run(_peak_rss_mb)
            out[f"subjects_per_hour_{w}_workers"] = 3600 * n / seconds
            out[f"seconds_{w}_workers"] = seconds
            out[f"peak_rss_per_worker_mb_{w}_workers"] = max(rss.values())
    w0, w1 = workers[0], workers[-1]
    speedup = out[f"subjects_per_hour_{w1}_workers"] / out[f"subjects_per_hour_{w0}_workers"]
    out["scaling_efficiency"] = speedup / (w1 / w0)
    per_subject = out[f"seconds_{w0}_workers"] / n * w0  # worker-seconds per subject
    out["worker_seconds_per_subject"] = per_subject
    for n_workers in (2, 8, 32):
        out[f"hours_{POPULATION}_subjects_{n_workers}_workers"] = (
            POPULATION * per_subject / (n_workers * out["scaling_efficiency"]) / 3600
        )
    return out


def _warm():
    from facestats.model.fitting.kernels import factors, lm, runs, samples  # noqa: F401  (compiled, cached)

    return True


def _peak_rss_mb():
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def bench_calibration(n_subjects=4, grid=48, face="procedural", transport="dipole", normal_tilt=True):
    """Coverage of nominal 90 % intervals on simulated captures with known truth, per model (module docstring).

    ``n_subjects`` of the default population spread over it, on ``face`` ("procedural" or "ict", at ``grid``),
    each model fitted by the pipeline to captures rendered with it, with the simulator's dipole transport
    over the surface or the local (flat-patch) transport of a simulator streaming in three blocks
    (``transport="local"``); ``normal_tilt`` as :class:`facestats.pipeline.FitSettings`.
    """
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.face.named import named_face
    from facestats.pipeline import FitSettings, fit_subject

    z90 = 1.6448536269514722
    geometry = named_face(f"{face}-{grid}")
    pop = synthesize_population(map_size=grid, geometry=geometry)
    block = {"dipole": 8192, "local": max(1, len(geometry.position) // 3)}[transport]
    hits = {k: [] for k in ("ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent")}
    for i in np.linspace(0, len(pop.subjects) - 1, n_subjects).astype(int):
        truth = pop[int(i)]
        on_face = truth.region_map > 0
        for model, params in (("torrance_sparrow", ("ts_rho_s", "ts_m")), ("blinn_phong", ("bp_rho_s", "bp_exponent"))):
            capture = DomeSimulator(geometry, specular=model, block=block).simulate(truth)
            settings = FitSettings(models=(model,), micro_normals=False, normal_tilt=normal_tilt)
            ds = fit_subject(capture, pop.sigma_tr_avg, settings)
            ok = on_face & (ds[f"{params[0][:2]}_flag"].values == 0)
            for p in params:
                err = np.abs(ds[p].values[ok] - getattr(truth, p)[ok])
                hits[p].append(err <= z90 * ds[f"{p}_std"].values[ok])
    out = {f"coverage90_{p}": float(np.mean(np.concatenate(v))) for p, v in hits.items()}
    out["target"] = "0.85-0.95"
    out["texels"] = int(sum(h.size for h in hits["ts_m"]))
    return out


def bench_calibration_variants(subjects=None, grid=48, face="procedural"):
    """Coverage of nominal 90 % intervals with other nuisance columns than the pipeline's (docs/scale.md).

    The variants among which the pipeline's columns were chosen: the HC3 sandwich of (ρs, ln p, δ) with
    no tilt (``none``), the lobe's two tilts (``lobe``), the diffuse term's two (``diffuse``), one tilt
    shared by both (``shared``: the columns summed) and both (``both``, the pipeline's).  Stages 1-4 as
    the pipeline runs them (numpy engine), on ``subjects`` of the default population on ``face`` at
    ``grid`` (default: four spread over it, those of :func:`bench_calibration`), each model on captures rendered
    with it (dipole transport, camera noise).  The columns
    are formed here from the package's slopes (:func:`facestats.model.fitting.normal_tilt.tilt_slopes`).
    """
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.core.published import ETA_SKIN
    from facestats.face.named import named_face
    from facestats.model import fitting
    from facestats.model.fitting.lobes import lobe_base, lobe_rate, lobe_scale
    from facestats.model.fitting.normal_tilt import tilt_grids, tilt_inputs, tilt_slopes
    from facestats.model.fitting.samples import run_starts
    from facestats.model.fitting.uncertainty import LEVERAGE_CAP, gram_stack, inverse_stack, lobe_jacobian

    z90 = 1.6448536269514722
    geometry = named_face(f"{face}-{grid}")
    pop = synthesize_population(map_size=grid, geometry=geometry)
    if subjects is None:  # four spread over the population, as bench_calibration picks them
        subjects = np.linspace(0, len(pop.subjects) - 1, 4).astype(int).tolist()
    v, u = geometry.face_texel_index().T
    hits = {}
    for subject in subjects:
        truth = pop[subject]
        for model, pre, lobe_name in (("torrance_sparrow", "ts", "ts_m"), ("blinn_phong", "bp", "bp_exponent")):
            lt = DomeSimulator(geometry, specular=model).simulate(truth).lumitexels()
            samples, _ = fitting.Samples.from_dome(lt.wi, lt.wo, lt.irradiance, lt.radiance, engine="numpy")
            normal, _ = fitting.photometric_normals(samples, lt.scan_normal, lt.wo.shape[1])
            ci, co, ft2, use, f_r = fitting.brdf_samples(samples, normal)
            albedo, _ = fitting.refine_albedo(samples, f_r, ft2, samples.cos_half(ci, co), use)
            albedo = np.nan_to_num(albedo).astype(np.float32)
            f_s = fitting.specular_residual(samples, f_r, albedo, ft2)
            limit = {"blinn_phong": np.radians(70)} if model == "blinn_phong" else None
            kw = dict(cos=(ci, co), ft2=ft2, max_angle=limit, engine="numpy")
            fit = fitting.fit_specular_models(samples, normal, f_s, use, (model,), **kw)[model]
            # The kept samples of eq. 14 (the fit's domain) and their columns.
            keep = use & np.isfinite(f_s) & (ci > 0) & (co > 0)
            if limit:
                c = np.float32(np.cos(limit[model]))
                keep &= (ci > c) & (co > c)
            s1, a = fitting.specular_factors(samples, normal, model, cos=(ci, co))
            keep &= a > 0
            index = np.flatnonzero(keep)
            cnt = samples.count(keep)
            texel = np.repeat(np.arange(cnt.size), cnt)
            q = np.log(np.where(np.isfinite(fit.lobe) & (fit.lobe > 0), fit.lobe, 1.0))
            rho, delta = (
                np.nan_to_num(fit.rho_s).astype(np.float64),
                np.nan_to_num(fit.diffuse_shift).astype(np.float64),
            )
            s1k = s1[index].astype(np.float64)
            base = lobe_base(model, q, cnt, s1k, a[index].astype(np.float64))
            g, dg = lobe_jacobian(model, q[texel], base, s1k)
            y = (f_s[index] * ci[index]).astype(np.float64)
            d = -(ft2[index] * ci[index]).astype(np.float64) / (3 * np.pi)
            r = y + delta[texel] * d - rho[texel] * lobe_scale(model, q[texel]) * base
            grids = tilt_grids(samples, normal.astype(np.float64), ETA_SKIN)
            slopes = tilt_slopes(model, tilt_inputs(samples, index, (ci, co, samples.cos_io()), grids, True)).astype(
                np.float64
            )
            rate = lobe_rate(model, np.exp(q[texel]))
            level = np.repeat(albedo.sum(axis=1, dtype=np.float32).astype(np.float64), cnt) + delta[texel]
            lobe_t = [rho[texel] * g * (slopes[k + 1] + rate * slopes[k]) for k in (0, 2)]
            diffuse_t = [-level * d * slopes[k] for k in (4, 5)]
            core = [g, rho[texel] * dg, -d]
            variants = {
                "none": core,
                "lobe": core + lobe_t,
                "diffuse": core + diffuse_t,
                "shared": core + [lobe_t[0] + diffuse_t[0], lobe_t[1] + diffuse_t[1]],
                "both": core + lobe_t + diffuse_t,
            }
            starts = run_starts(cnt)
            ok = fit.flags == 0
            true_rho, true_lobe = getattr(truth, f"{pre}_rho_s")[v, u], getattr(truth, lobe_name)[v, u]
            for name, columns in variants.items():
                jac = np.stack(columns)
                h_inv = inverse_stack(gram_stack(jac, jac, starts))
                lev = np.einsum("is,sij,js->s", jac, np.repeat(h_inv, cnt, axis=0), jac)
                w = r * r / np.square(1 - np.clip(np.nan_to_num(lev), 0, LEVERAGE_CAP))
                cov = h_inv @ gram_stack(jac, w * jac, starts) @ h_inv
                std_rho, std_lobe = np.sqrt(cov[:, 0, 0]), np.exp(q) * np.sqrt(cov[:, 1, 1])
                for par, value, std, true in (
                    ("rho_s", fit.rho_s, std_rho, true_rho),
                    ("lobe", fit.lobe, std_lobe, true_lobe),
                ):
                    hit = np.abs(value[ok] - true[ok]) <= z90 * std[ok]
                    hits.setdefault(f"{name}_{pre}_{par}", []).append(hit)
    return {f"coverage90_{k}": float(np.mean(np.concatenate(h))) for k, h in hits.items()}


def bench_calibration_budget(subject=0, grid=48, passes=None):
    """Where the intervals' misses come from: coverage with the truth's normals and albedo swapped in (docstring).

    One default-population subject on the procedural face, each model fitted to
    captures rendered with it: with the dipole transport over the surface (what the
    default simulator renders), with and without camera noise, and with the local
    (flat-patch) transport of a simulator streaming in blocks, with noise.  Stages
    1-4 as :func:`facestats.pipeline.fit_lumitexels` runs them (photometric normal,
    albedo refined over specular-free samples, eq. 10, eq. 14 with the standard
    errors), then again with the true normal and/or the true grey albedo in place
    of the estimates, and once with the diffuse removed at the photometric normal
    but the lobe fitted at the true normal (``normal_estimated_lobe_normal_true``:
    what a specular normal of its own would gain).  Per case: coverage of the nominal 90 % intervals and the
    median relative bias of ρs and of the lobe over the unflagged lumitexels.
    ``passes``: the photometric-stereo passes (None: the default of
    :func:`facestats.model.fitting.photometric_normals`; 3 gives the fit before 2026-12-04).
    """
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.face.procedural import procedural_face
    from facestats.model import fitting

    geometry = procedural_face(grid)
    pop = synthesize_population(map_size=grid, geometry=geometry)
    truth = pop[subject]
    v, u = geometry.face_texel_index().T
    out = {}
    for model, pre, lobe_name in (("torrance_sparrow", "ts", "ts_m"), ("blinn_phong", "bp", "bp_exponent")):
        true_rho, true_lobe = getattr(truth, f"{pre}_rho_s")[v, u], getattr(truth, lobe_name)[v, u]
        local_block = max(1, len(geometry.position) // 3)  # several blocks: the local transport
        for transport, noise, block in (("dipole", True, 8192), ("dipole", False, 8192), ("local", True, local_block)):
            sim = DomeSimulator(geometry, specular=model, noise=noise, block=block)
            lt = sim.simulate(truth).lumitexels()
            samples, _ = fitting.Samples.from_dome(lt.wi, lt.wo, lt.irradiance, lt.radiance)
            kw = {} if passes is None else {"iterations": passes}
            ps_normal, _ = fitting.photometric_normals(samples, lt.scan_normal, lt.wo.shape[1], **kw)
            case = f"{pre}_{transport}_{'noise' if noise else 'noise_free'}"
            cos_err = np.clip(np.einsum("nk,nk->n", ps_normal.astype(np.float64), geometry.normal), -1, 1)
            out[f"{case}_normal_error_deg_median"] = float(np.degrees(np.median(np.arccos(cos_err))))
            true_normal = geometry.normal.astype(np.float32)
            for normal_source, normal in (("estimated", ps_normal), ("true", true_normal)):
                ci, co, ft2, use, f_r = fitting.brdf_samples(samples, normal)
                cos_half = samples.cos_half(ci, co)
                est, _, grey_std = fitting.refine_albedo(samples, f_r, ft2, cos_half, use, with_std=True)
                true_grey = truth.albedo[v, u].sum(axis=1)
                with np.errstate(invalid="ignore"):
                    alb_err = est.sum(axis=1) - true_grey
                    out[f"{case}_normal_{normal_source}_albedo_median_bias"] = float(np.nanmedian(alb_err / true_grey))
                    out[f"{case}_normal_{normal_source}_albedo_error_over_std_median"] = float(
                        np.nanmedian(np.abs(alb_err) / grey_std)
                    )
                for albedo_source, albedo in (("estimated", est), ("true", truth.albedo[v, u].astype(np.float32))):
                    f_s = fitting.specular_residual(samples, f_r, albedo, ft2)
                    key = f"{case}_normal_{normal_source}_albedo_{albedo_source}"
                    out.update(_coverage(key, model, samples, normal, f_s, use, (ci, co), ft2, true_rho, true_lobe))
                if normal_source == "estimated":
                    # Diffuse removed with the photometric normal and the estimated albedo, as the pipeline
                    # does; the lobe evaluated at the true normal.
                    f_s = fitting.specular_residual(samples, f_r, est, ft2)
                    ci_t, co_t, _, use_t, _ = fitting.brdf_samples(samples, true_normal)
                    with np.errstate(invalid="ignore", divide="ignore"):
                        ratio = ci / ci_t  # the same specular radiance over E; d = −F_t F_t cos θi/(3π) at the
                        f_s_t, ft2_t = (f_s * ratio).astype(np.float32), (ft2 * ratio).astype(np.float32)  # PS θi
                    key = f"{case}_normal_estimated_lobe_normal_true"
                    cos, both = (ci_t, co_t), use & use_t
                    out.update(
                        _coverage(key, model, samples, true_normal, f_s_t, both, cos, ft2_t, true_rho, true_lobe)
                    )
    return out


def _coverage(key, model, samples, normal, f_s, use, cos, ft2, true_rho, true_lobe):
    """Coverage of nominal 90 % intervals and median relative bias of ρs and the lobe of one fit (unflagged)."""
    from facestats.model import fitting

    z90 = 1.6448536269514722
    fit = fitting.fit_specular_models(
        samples,
        normal,
        f_s,
        use,
        (model,),
        cos=cos,
        ft2=ft2,
        max_angle={"blinn_phong": np.radians(70)} if model == "blinn_phong" else None,
    )[model]
    ok = fit.flags == 0
    out = {}
    for name, value, std, true in (
        ("rho_s", fit.rho_s, fit.rho_s_std, true_rho),
        ("lobe", fit.lobe, fit.lobe_std, true_lobe),
    ):
        err = (value - true)[ok]
        out[f"{key}_{name}_coverage90"] = float(np.mean(np.abs(err) <= z90 * std[ok]))
        out[f"{key}_{name}_median_bias"] = float(np.median(err / true[ok]))
    return out


def bench_normal_passes(subject=0, grid=48, passes=(1, 2, 3, 4, 5, 6)):
    """Median, 99th-percentile and largest angle (deg) between photometric-stereo and true normals after each
    number of F_t passes.

    Subject ``subject`` of the default population on the procedural face, Torrance-Sparrow captures
    with the local transport (several simulator blocks), without and with camera noise
    (:func:`facestats.model.fitting.photometric_normals`, its module docstring quotes the figures).
    """
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.face.procedural import procedural_face
    from facestats.model import fitting

    geometry = procedural_face(grid)
    truth = synthesize_population(map_size=grid, geometry=geometry)[subject]
    out = {}
    for noise in (False, True):
        sim = DomeSimulator(geometry, noise=noise, block=max(1, len(geometry.position) // 3))
        lt = sim.simulate(truth).lumitexels()
        samples, _ = fitting.Samples.from_dome(lt.wi, lt.wo, lt.irradiance, lt.radiance)
        for k in passes:
            normal, _ = fitting.photometric_normals(samples, lt.scan_normal, lt.wo.shape[1], iterations=k)
            cos = np.clip(np.einsum("nk,nk->n", normal.astype(np.float64), geometry.normal), -1, 1)
            angle = np.degrees(np.arccos(cos))
            key = f"{'noise' if noise else 'noise_free'}_passes_{k}"
            out[f"{key}_median_deg"] = float(np.median(angle))
            out[f"{key}_p99_deg"] = float(np.percentile(angle, 99))
            out[f"{key}_max_deg"] = float(angle.max())
    return out


def bench_blinn_phong_maps(n_subjects=6, grid=48):
    """Blinn-Phong on Torrance-Sparrow captures within 80° (baseline) and 70° (module docstring)."""
    from bench_fit import _default_case

    from facestats.pipeline import FitSettings, fit_subject, held_out_camera_error

    pop, _, sim = _default_case(grid=grid)
    rows = {80.0: [], 70.0: []}
    for i in np.linspace(0, len(pop.subjects) - 1, n_subjects).astype(int):
        truth = pop[int(i)]
        cap = sim.simulate(truth)
        for limit in rows:
            ds = fit_subject(
                cap, pop.sigma_tr_avg, FitSettings(micro_normals=False, exclude_cameras=(7,), bp_max_angle_deg=limit)
            )
            face, reg = ds.region.values > 0, ds.region.values
            good = (ds.bp_flag.values == 0) & (ds.ts_flag.values == 0)
            rows[limit].append(
                (
                    float((ds.bp_flag.values[face] != 0).mean()),
                    ds.bp_exponent.values[(reg == 8) & (ds.bp_flag.values == 0)],
                    ds.bp_exponent.values[(reg == 9) & (ds.bp_flag.values == 0)],
                    float(np.median(ds.bp_error.values[face & good] / ds.ts_error.values[face & good])),
                    held_out_camera_error(ds, cap, 7, specular="blinn_phong"),
                    held_out_camera_error(ds, cap, 7),
                )
            )
    out = {}
    for limit, r in rows.items():
        key = f"{int(limit)}deg"
        out[f"bp_flagged_{key}"] = float(np.mean([x[0] for x in r]))
        out[f"bp_exponent_p95_lips_{key}"] = float(np.percentile(np.concatenate([x[1] for x in r]), 95))
        out[f"bp_exponent_p95_chin_{key}"] = float(np.percentile(np.concatenate([x[2] for x in r]), 95))
        out[f"E_bp_over_E_ts_{key}"] = float(np.median([x[3] for x in r]))
        out[f"held_out_rmse_bp_{key}"] = float(np.median([x[4] for x in r]))
    out["held_out_rmse_ts"] = float(np.median([x[5] for x in rows[70.0]]))
    return out


BENCHMARKS = [
    ("full_resolution", bench_full_resolution),
    ("fit_stages", bench_fit_stages),
    ("codec", bench_codec),
    ("cluster_scaling", bench_cluster_scaling),
    ("calibration", bench_calibration),
    ("calibration_variants", bench_calibration_variants),
    ("calibration_budget", bench_calibration_budget),
    ("normal_passes", bench_normal_passes),
    ("blinn_phong_maps", bench_blinn_phong_maps),
]

#: Tiny sizes for the test suite (the full-resolution case keeps its maps finer than its grid).
SMOKE = {
    "full_resolution": {"workers": 1, "block": 256, "grid": 24, "map_size": 64},
    "fit_stages": {"blocks": 2, "block": 64, "grid": 24, "map_size": 64},
    "codec": {"grid": 16, "map_size": 32, "lumitexels": 200},
    # one cluster of one worker: every code path runs (the efficiency and plan figures then compare the size with
    # itself), with one worker process started instead of two
    "cluster_scaling": {"n": 2, "grid": 16, "map_size": 32, "workers": (1,), "block": 256},
    "calibration": {"n_subjects": 1, "grid": 16},
    "calibration_variants": {"subjects": (0,), "grid": 16},
    "calibration_budget": {"grid": 16},
    "normal_passes": {"grid": 16, "passes": (1, 5)},
    "blinn_phong_maps": {"n_subjects": 1, "grid": 16},
}
