"""Dynamic skin microstructure (issue 14, Nagano et al. 2015): convolution, strain and kernel-fit throughput.

Requirements and baselines, printed side by side:

* ``convolve``: a 4096² float32 map with per-texel axes and kernel parameters
  (two passes, σ up to 100 µm at 10 µm/texel) at ≥ 8 Mtexel/s (≤ 2.1 s per
  frame) on the 2-core machine, and ≥ 20× the straightforward two-pass
  implementation in numpy (one whole-map read per tap offset, below; until
  2026-12-07, when taps were read bilinearly, :func:`scipy.ndimage.map_coordinates`),
  compared in texels per second: the baseline runs on the top-left 1024² of the
  same input (a 4096² frame would take it about 25 minutes).  The
  input fields are smooth random fields: axis angle over [0, π), α_s ∈ [0, 1],
  α_t ∈ [−2, 0] and σ_s, σ_t ∈ [1, 100] µm (mean about 50 µm, so about 31 taps
  per pass; ``table=True`` draws σ and α from the forehead table for r ∈ [0.7,
  1.35] instead, the realistic case).  The numpy fallback is timed on a crop.
  Peak memory: tracemalloc of the compiled run (inputs excluded).
* ``strain``: per-frame strain of the ICT-FaceKit face (9,409 vertices, 18,460
  triangles; the sample in ``tests/data``) ≤ 50 ms — per-triangle T, their
  UV-vertex averages and the SVDs (``MeshStrain.vertices_strain``); the
  triangles alone and the texels of a 1024² map alongside.
* ``fit``: the 59,899-combination brute force on a 512² patch ≤ 60 s,
  coarse-to-fine ≤ 5 s, both returning the same argmin (a target made from the
  same patch, so the minimum is distinct).
* ``independent``: not a speed figure but the measurement behind the open accuracy item: from
  independent realisations of the same procedural skin (the tests' statistics), the joint argmin of
  eq. 7 for targets (0.5, 30 µm) and (−1, 20 µm) along u, at two patch sizes and several seeds, with
  each realisation's slope standard deviation and kurtosis along u and the TV at the argmin against
  the ridge tolerance (the histograms' sampling noise).
* ``generate``: a store subject's neutral map (``subject_microstructure``, what ``facestats microstructure
  generate --subject`` writes) as a window of the 16K map and as the whole 16K map: time and tracemalloc
  peak.  The generator works in blocks of rows, so the whole map should need its float32 output plus about
  100 MB (it held about 88 bytes a texel at once until 2026-12-08: about 22 GiB at 16,384²).
"""

from __future__ import annotations

import math
import pathlib
import sys
import time
import tracemalloc

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

ICT_SAMPLE = ROOT / "tests" / "data" / "ict-facekit"


def _smooth(rng, shape, lo, hi):
    from scipy.ndimage import zoom

    f = zoom(rng.random((9, 9)), (shape[0] / 9, shape[1] / 9), order=3)[: shape[0], : shape[1]]
    f = (f - f.min()) / max(f.max() - f.min(), 1e-12)
    return (lo + (hi - lo) * f).astype(np.float32)


def _inputs(size, table, seed=0):
    from facestats.model.microstructure import kernel_parameters

    rng = np.random.default_rng(seed)
    shape = (size, size)
    d = rng.normal(0, 10, shape).astype(np.float32)
    theta = _smooth(rng, shape, 0, np.pi)
    axis = np.stack([np.cos(theta), np.sin(theta)], -1).astype(np.float32)
    if table:
        r_s, r_t = _smooth(rng, shape, 1.0, 1.35), _smooth(rng, shape, 0.7, 1.0)
        (a_s, s_s), (a_t, s_t) = kernel_parameters(r_s), kernel_parameters(r_t)
        params = [x.astype(np.float32) for x in (a_s, s_s, a_t, s_t)]
    else:
        params = [_smooth(rng, shape, 0, 1), _smooth(rng, shape, 1, 100), _smooth(rng, shape, -2, 0),
                  _smooth(rng, shape, 1, 100)]  # fmt: skip
    return d, axis, params


def _baseline_pass(src, au, av, alpha, sigma_px, truncate):
    """One pass, straightforwardly: a whole-map read of every tap offset, the taps of
    :mod:`facestats.model.microstructure.taps` (whole texels along the axis's major direction, Lanczos-3
    across it), written independently: weights from ``np.sinc`` at the exact (unrounded) position, taps that
    read outside the map skipped."""
    h, w = src.shape
    rows, cols = np.indices((h, w))
    au, av = au.astype(np.float64), av.astype(np.float64)
    u_major = np.abs(au) >= np.abs(av)
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.where(u_major, av / au, au / av)
    s = sigma_px * np.where(u_major, np.abs(au), np.abs(av))  # sigma in taps (taps 1/|a_major| texels apart)
    radius = np.ceil(truncate * s)
    acc, wsum = src.astype(np.float64), np.ones((h, w))
    for i in range(1, int(radius.max()) + 1):  # tap offsets
        g = np.where(radius >= i, np.exp(-(i * i) / (2 * s * s)), 0.0)
        for sign in (1, -1):
            pos = sign * i * slope
            y0 = np.floor(pos)
            frac = pos - y0
            sample, norm = np.zeros((h, w)), np.zeros((h, w))
            inside = np.ones((h, w), bool)
            for k in range(-2, 4):  # the six texels across
                x = k - frac
                wk = np.sinc(x) * np.sinc(x / 3)
                across = y0.astype(np.int64) + k
                r = np.where(u_major, rows + across, rows + sign * i)
                c = np.where(u_major, cols + sign * i, cols + across)
                ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
                inside &= ok | (np.abs(wk) < 1e-12)
                sample += wk * src[np.clip(r, 0, h - 1), np.clip(c, 0, w - 1)]
                norm += wk
            acc += np.where(inside, g * sample / norm, 0.0)
            wsum += np.where(inside, g, 0.0)
    return ((1 - alpha) * src + alpha * (acc / wsum)).astype(src.dtype)


def _baseline(d, axis, params, texel_um, truncate):
    a_s, s_s, a_t, s_t = params
    au, av = axis[..., 0], axis[..., 1]
    d_s = _baseline_pass(d, au, av, a_s, s_s / texel_um, truncate)
    return _baseline_pass(d_s, -av, au, a_t, s_t / texel_um, truncate)


def _mean_taps(axis, params, texel_um):
    """Taps a texel reads in both passes, 2 ceil(3 σ_px |a_major|) + 1 each (taps 1/|a_major| texels apart)."""
    from facestats.model.microstructure.kernel import TRUNCATE
    from facestats.model.microstructure.taps import major_axis

    taps = 0.0
    for a, sigma in ((axis, params[1]), (np.stack([-axis[..., 1], axis[..., 0]], -1), params[3])):
        major = major_axis(a[..., 0], a[..., 1])[2].astype(np.float64)
        taps += np.mean(2 * np.ceil(TRUNCATE * sigma / texel_um * major) + 1)
    return float(taps)


def bench_convolve(size=4096, texel_um=10.0, table=False, crop=512, baseline=True, repeat=2, baseline_size=1024):
    from facestats.model.microstructure import convolve_displacement
    from facestats.model.microstructure.kernel import TRUNCATE

    d, axis, params = _inputs(size, table)
    convolve_displacement(d[:64, :64], axis[:64, :64], *[p[:64, :64] for p in params], texel_um)  # compile
    best, cpu = math.inf, math.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        out = convolve_displacement(d, axis, *params, texel_um)
        best, cpu = min(best, time.perf_counter() - t0), min(cpu, time.process_time() - c0)
    tracemalloc.start()
    convolve_displacement(d, axis, *params, texel_um)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    c = slice(0, min(crop, size))
    compiled_crop = convolve_displacement(d[c, c], axis[c, c], *[p[c, c] for p in params], texel_um)
    t0 = time.perf_counter()
    fallback = convolve_displacement(d[c, c], axis[c, c], *[p[c, c] for p in params], texel_um, backend="numpy")
    t_numpy = time.perf_counter() - t0
    fig = {
        "compiled_s_per_frame": best,
        "compiled_Mtexel_per_s": size * size / best / 1e6,
        # CPU seconds summed over threads: on a loaded machine wall time overstates the cost;
        # cpu_s / n_cores is the wall time of an otherwise idle machine with perfect scaling.
        "compiled_cpu_s_per_frame": cpu,
        "compiled_Mtexel_per_cpu_s": size * size / cpu / 1e6,
        "numpy_fallback_Mtexel_per_s": crop * crop / t_numpy / 1e6,
        "fallback_max_abs_diff": float(np.abs(fallback - compiled_crop).max()),
        "peak_memory_MB": peak / 2**20,
        "map_MB": d.nbytes / 2**20,
        "mean_taps_per_texel": _mean_taps(axis, params, texel_um),
        "size": size,
    }  # fmt: skip
    if baseline:
        # The baseline takes minutes a megatexel (342 s for a 2048² frame): it runs on the top-left
        # ``baseline_size``² of the same input and is compared texel for texel with the compiled frame's
        # crop of the same size (a whole-map method per tap offset: its time is proportional to the texels).
        b = slice(0, min(baseline_size, size))
        t0 = time.perf_counter()
        ref = _baseline(d[b, b], axis[b, b], [p[b, b] for p in params], texel_um, TRUNCATE)
        t_ref = time.perf_counter() - t0
        n_ref = ref.size
        fig["numpy_baseline_size"] = n_ref
        fig["numpy_baseline_Mtexel_per_s"] = n_ref / t_ref / 1e6
        fig["speedup_vs_numpy_baseline"] = fig["compiled_Mtexel_per_s"] / fig["numpy_baseline_Mtexel_per_s"]
        # Agreement: the baseline reads each tap at its exact position, the compiled pass at the position
        # rounded to 1/1024 texel (the Lanczos table), so interior texels differ by about the map's slope
        # times 5e-4 texel; at the crop's border the baseline skips a tap outside it where the compiled
        # frame reads on (it has the whole map), so border texels differ more.
        m = int(2 * np.ceil(TRUNCATE * 100.0 / texel_um) + 2)
        diff = np.abs(ref - out[b, b])
        inner = diff[m:-m, m:-m]
        fig["baseline_max_abs_diff_interior"] = float(inner.max()) if inner.size else float("nan")
        fig["baseline_fraction_interior_differing_1e-3"] = float(np.mean(inner > 1e-3)) if inner.size else float("nan")
    return fig


def bench_convolve_table(size=4096, texel_um=10.0, crop=512, baseline=False):
    return bench_convolve(size=size, texel_um=texel_um, table=True, crop=crop, baseline=baseline)


def bench_strain(frames=20, texel_size=1024):
    from facestats.io.ict_facekit import read_ict_facekit
    from facestats.model.strain import MeshStrain

    neutral, targets = read_ict_facekit(ICT_SAMPLE, ["mouthSmile_L", "mouthSmile_R", "jawOpen"])
    ms = MeshStrain(neutral.vertices, neutral.triangles, neutral.uv, neutral.uv_triangles)
    w = np.linspace(0, 1, frames)
    shapes = [neutral.vertices + w[k] * (targets["mouthSmile_L"] + targets["mouthSmile_R"] - 2 * neutral.vertices)
              + (1 - w[k]) * (targets["jawOpen"] - neutral.vertices) for k in range(frames)]  # fmt: skip
    ms.vertices_strain(shapes[0])
    t0 = time.perf_counter()
    for v in shapes:  # frames
        ms.triangles_strain(v)
    t_tri = (time.perf_counter() - t0) / frames
    t0, c0 = time.perf_counter(), time.process_time()
    for v in shapes:
        ms.vertices_strain(v)
    t_vert, c_vert = (time.perf_counter() - t0) / frames, (time.process_time() - c0) / frames
    ms.texels_strain(shapes[0], texel_size)  # rasterisation, cached
    t0 = time.perf_counter()
    ms.texels_strain(shapes[-1], texel_size)
    t_tex = time.perf_counter() - t0
    return {
        "strain_ms_per_frame": 1e3 * t_vert,  # per-triangle T, UV-vertex averages and their SVD: one call
        "strain_cpu_ms_per_frame": 1e3 * c_vert,
        "triangle_only_ms_per_frame": 1e3 * t_tri,
        "texel_s_per_frame": t_tex,
        "texels": texel_size**2,
        "vertices": neutral.n_vertices,
        "triangles": len(neutral.triangles),
    }


def bench_fit(size=512, texel_um=10.0, brute=True):
    from facestats.acquire.synthetic.microstructure import procedural_microstructure
    from facestats.model.microstructure import convolve_displacement, fit_kernel

    neutral = procedural_microstructure(size, texel_um, seed=1).astype(np.float64)
    target = convolve_displacement(neutral, (0.6, 0.8), 0.47, 30.5, 0.0, 1.0, texel_um)
    fit_kernel(neutral[:100, :100], target[:100, :100], (0.6, 0.8), 1.0, texel_um, alphas=[0.0, 0.5], sigmas_um=[10.0])
    t0, c0 = time.perf_counter(), time.process_time()
    fast = fit_kernel(neutral, target, (0.6, 0.8), 1.0, texel_um, method="coarse-to-fine")
    fig = {"coarse_to_fine_s": time.perf_counter() - t0, "coarse_to_fine_cpu_s": time.process_time() - c0,
           "coarse_to_fine_evaluated": fast.n_evaluated}  # fmt: skip
    if brute:
        t0, c0 = time.perf_counter(), time.process_time()
        full = fit_kernel(neutral, target, (0.6, 0.8), 1.0, texel_um)
        fig["brute_force_s"] = time.perf_counter() - t0
        fig["brute_force_cpu_s"] = time.process_time() - c0
        fig["brute_force_evaluated"] = full.n_evaluated
        fig["same_argmin"] = (full.alpha, full.sigma_um) == (fast.alpha, fast.sigma_um)
    fig["argmin"] = f"alpha={fast.alpha}, sigma={fast.sigma_um} um (truth 0.47, 30.5)"
    fig["histogram_samples"] = (size - 2 * fast.meta["margin"]) ** 2
    return fig


def bench_independent(sizes=(512, 1024), seeds=(2, 3, 4)):
    from facestats.acquire.synthetic.microstructure import SkinMicrostructure, procedural_microstructure
    from facestats.model.microstructure import convolve_displacement, fit_kernel

    texel = 10.0
    skin = SkinMicrostructure(roughness=0.3, furrow_angle=None, furrow_share=0.3, pore_share=0.3,
                              pore_density_mm2=3.0, pore_radius_um=30.0)  # fmt: skip
    alphas, sigmas = np.round(np.arange(-2, 1.0001, 0.02), 2), np.arange(5.0, 100.1, 2.5)
    out = {}
    for n in sizes:
        neutral = procedural_microstructure(n, texel, params=skin, seed=1).astype(np.float64)
        for seed in (1, *seeds):
            other = procedural_microstructure(n, texel, params=skin, seed=seed).astype(np.float64)
            g = np.diff(other, axis=1) / texel
            out[f"n{n}_seed{seed}_slope_std_u"] = float(g.std())
            out[f"n{n}_seed{seed}_kurtosis_u"] = float(np.mean(g**4) / np.mean(g**2) ** 2)
            if seed == 1:
                continue
            for alpha, sigma in ((0.5, 30.0), (-1.0, 20.0)):
                target = convolve_displacement(other, (1.0, 0.0), alpha, sigma, 0.0, 1.0, texel)
                fit = fit_kernel(neutral, target, (1.0, 0.0), 1.0, texel, alphas=alphas, sigmas_um=sigmas)
                key = f"n{n}_seed{seed}_truth({alpha:g},{sigma:g})"
                out[key] = f"({fit.alpha:g},{fit.sigma_um:g}) tv={fit.tv:.4f} tol={fit.ridge_tolerance:.4f}"
    return out


#: Kernels of the dense-surface check (Nagano et al. 2015 Fig. 11 spans α ∈ [−2, 1], σ up to about 60 µm).
DENSE_TRUTHS = ((0.5, 30.0), (-1.0, 20.0), (0.9, 60.0), (0.3, 45.0), (-0.5, 15.0), (-1.8, 25.0), (-1.5, 40.0),
                (0.7, 20.0))  # fmt: skip


def bench_independent_dense(sizes=(256, 384, 512), seeds=(2, 3, 4), truths=DENSE_TRUTHS):
    """Joint argmin of eq. 7 from independent realisations of a shot-noise surface (500 bumps/mm², 10 µm).

    Targets: realisation ``seed`` convolved along (0.6, 0.8) with each (α, σ); neutral: seed 1; fit by
    coarse-to-fine over the paper's grid.  Prints the largest |Δα| and |Δσ| (texels) per size and the
    number of fits outside ±0.1 in α or ±1 texel in σ.
    """
    from facestats.acquire.synthetic.microstructure import shot_noise_microstructure
    from facestats.model.microstructure import convolve_displacement, fit_kernel

    texel, axis = 10.0, (0.6, 0.8)
    out = {}
    for n in sizes:
        neutral = shot_noise_microstructure(n, texel, seed=1).astype(np.float64)
        errors = []
        for seed in seeds:
            other = shot_noise_microstructure(n, texel, seed=seed).astype(np.float64)
            for alpha, sigma in truths:
                target = convolve_displacement(other, axis, alpha, sigma, 0.0, 1.0, texel)
                fit = fit_kernel(neutral, target, axis, 1.0, texel, method="coarse-to-fine")
                errors.append((abs(fit.alpha - alpha), abs(fit.sigma_um - sigma) / texel))
        e = np.array(errors)
        out[f"n{n}_fits"] = len(e)
        out[f"n{n}_max_abs_dalpha"] = round(float(e[:, 0].max()), 3)
        out[f"n{n}_max_abs_dsigma_texel"] = round(float(e[:, 1].max()), 3)
        out[f"n{n}_outside_tolerance"] = int(np.sum((e[:, 0] > 0.1 + 1e-9) | (e[:, 1] > 1 + 1e-9)))
    return out


def bench_rotation(
    size=512, texel_um=6.0, angles=(0.0, 10.0, 22.5, 35.0, 45.0, 60.0, 80.0), ratios=(2.2, 0.65), omegas=(0.5, 0.9)
):
    """Orientation independence (not a speed figure): the same strain at several angles to the texel grid.

    Forehead kernels of stretch ratios ``ratios`` (r_s along s, r_t across).  For each angle and each ω of
    ``omegas`` (× π rad per texel): the share of a wave across s that pass 1 keeps (eq. 3: all of it) and the
    gain of both passes on that wave (eq. 6: K_t(ω), also returned); for each angle the rms slopes along s and t
    of procedural skin (``procedural_microstructure``) after both passes, relative to the neutral's.
    """
    from facestats.acquire.synthetic.microstructure import procedural_microstructure
    from facestats.model.microstructure import FOREHEAD, convolve_displacement, kernel_taps
    from facestats.model.microstructure.kernel import frequency_response

    (a_s, s_s), (a_t, s_t) = [(float(FOREHEAD.alpha(r)), float(FOREHEAD.sigma(r))) for r in ratios]
    m = max(8, size // 8)
    rows, cols = np.indices((size, size), dtype=np.float64)
    skin = procedural_microstructure(size, texel_um, seed=1).astype(np.float64)
    fig = {}

    def inner(x):
        return x[m:-m, m:-m]

    def rms_slopes(field, axis):
        gv, gu = np.gradient(field)
        return np.std(inner(axis[0] * gu + axis[1] * gv)), np.std(inner(-axis[1] * gu + axis[0] * gv))

    for w in omegas:
        fig[f"eq6_gain_{w:g}pi"] = float(frequency_response(kernel_taps(a_t, s_t, texel_um), w * np.pi))
    for deg in angles:
        th = np.radians(deg)
        axis = (np.cos(th), np.sin(th))
        for w in omegas:
            wave = np.cos(w * np.pi * (-axis[1] * cols + axis[0] * rows) + 0.3)
            for key, (alpha_t, sigma_t) in (("pass1_keeps", (0.0, 1.0)), ("gain", (a_t, s_t))):
                out = convolve_displacement(wave, axis, a_s, s_s, alpha_t, sigma_t, texel_um)
                fig[f"{key}_{w:g}pi_{deg:g}deg"] = float(np.sum(inner(out) * inner(wave)) / np.sum(inner(wave) ** 2))
        after = rms_slopes(convolve_displacement(skin, axis, a_s, s_s, a_t, s_t, texel_um), axis)
        before = rms_slopes(skin, axis)
        fig[f"slope_s_ratio_{deg:g}deg"] = float(after[0] / before[0])
        fig[f"slope_t_ratio_{deg:g}deg"] = float(after[1] / before[1])
    return fig


def bench_generate(size=16384, texel_um=18.0, window=(9046, 6077, 2048, 2048), whole=True):
    import facestats
    from facestats.acquire.synthetic.microstructure import subject_microstructure

    with facestats.open_store() as store:
        ds = store.subject("S001", exclude=["micro_normal"])
    fig = {}
    for name, win in [("window", window)] + ([("whole", None)] if whole else []):
        tracemalloc.start()
        t0, c0 = time.perf_counter(), time.process_time()
        h = subject_microstructure(ds, size, texel_um, window=win)
        fig[f"{name}_s"], fig[f"{name}_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        fig[f"{name}_texels"] = h.size
        fig[f"{name}_peak_mb"] = peak / 2**20
        fig[f"{name}_peak_beyond_output_mb"] = (peak - h.nbytes) / 2**20
        del h
    return fig


BENCHMARKS = [
    ("convolve", bench_convolve),
    ("rotation", bench_rotation),
    ("convolve_table", bench_convolve_table),
    ("strain", bench_strain),
    ("fit", bench_fit),
    ("independent", bench_independent),
    ("independent_dense", bench_independent_dense),
    ("generate", bench_generate),
]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "convolve": {"size": 160, "crop": 48, "repeat": 1},
    "convolve_table": {"size": 96, "crop": 48},
    "rotation": {"size": 96, "angles": (0.0, 30.0)},
    "strain": {"frames": 2, "texel_size": 64},
    "fit": {"size": 96, "brute": False},
    "independent": {"sizes": (96,), "seeds": (2,)},
    "independent_dense": {"sizes": (96,), "seeds": (2,), "truths": ((0.5, 30.0),)},
    "generate": {"size": 1024, "texel_um": 290.0, "window": (560, 380, 64, 64)},
}


if __name__ == "__main__":
    for name, fn in BENCHMARKS:
        print(name, fn())
