"""Texture transfer (Weyrich et al. 2006 §8): facestats' steerable pyramid against pyrtools.

The baseline is the same Heeger-Bergen transfer (same histogram matching, same
statistics, same iterations) with the pyramid swapped for pyrtools'
``SteerablePyramidFreq`` (the reference Python implementation, float64, full
complex FFTs, tabulated masks), through the ``pyramid`` argument of
:func:`facestats.edit.transfer_texture`.  Both run on one 2048×2048 RGB
albedo with 7 levels, 4 orientations, 256 bins and 5 iterations, with the
target given as an albedo map (its statistics are computed inside the timed
call).  Requirement: ours ≤ 30 s and ≥ 5× faster.  The pyrtools run takes a few
minutes.

``colour_edit_2048`` times one store-level skin-colour transfer
(:func:`facestats.edit.transfer_colour_subject`) of the representative 2048²
subject with a 16-camera micro-normal map (``bench_export.representative_subject``)
and traces its peak memory.  The baseline is the size of the subject in memory:
an edit that held the whole source, as every edit did before the micro-normals
were left on disk (2026-12-07), peaked above it.
"""

from __future__ import annotations

import tempfile
import time

import numpy as np

from facestats.edit.pyramid import SteerablePyramid
from facestats.edit.texture import transfer_texture

SIZE = 2048
LEVELS = 7
ITERATIONS = 5


class PyrtoolsPyramid:
    """pyrtools' ``SteerablePyramidFreq`` behind the interface of :class:`SteerablePyramid`.

    pyrtools leaves level ``i`` bands ``4**i`` times larger (no rescaling after
    cropping the spectrum); they are rescaled to facestats' convention (image
    units) so the same target statistics apply.
    """

    def __init__(self, shape, levels, orientations, *, dtype=np.float64, workers=1):
        self.levels, self.orientations, self.dtype = levels, orientations, np.dtype(dtype)
        self._pyr = None

    def decompose(self, image):
        import pyrtools as pt

        self._pyr = pt.pyramids.SteerablePyramidFreq(
            np.asarray(image, np.float64), height=self.levels, order=self.orientations - 1
        )
        c = self._pyr.pyr_coeffs
        bands = [c["residual_highpass"]]
        bands += [c[(i, b)] / 4.0**i for i in range(self.levels) for b in range(self.orientations)]
        bands.append(c["residual_lowpass"] / 4.0**self.levels)
        return [np.ascontiguousarray(b, self.dtype) for b in bands]

    def reconstruct(self, bands):
        c = self._pyr.pyr_coeffs
        c["residual_highpass"] = np.asarray(bands[0], np.float64)
        k = 1
        for i in range(self.levels):
            for b in range(self.orientations):
                c[(i, b)] = np.asarray(bands[k], np.float64) * 4.0**i
                k += 1
        c["residual_lowpass"] = np.asarray(bands[k], np.float64) * 4.0**self.levels
        return np.ascontiguousarray(self._pyr.recon_pyr(), self.dtype)


def _albedos(size, seed=0):
    """A smooth source albedo and a freckled target albedo (linear RGB, float32)."""
    from scipy import ndimage

    rng = np.random.default_rng(seed)
    skin = np.array([0.55, 0.34, 0.25], np.float32)

    def noise(sigma):
        g = np.stack(
            [ndimage.gaussian_filter(rng.standard_normal((size, size), np.float32), sigma) for _ in range(3)], -1
        )
        return g / g.std()

    src = np.clip(skin * (1 + 0.03 * noise(3.0)), 0, 1).astype(np.float32)
    tgt = np.clip(skin * (1 + 0.05 * noise(0.7)), 0, 1).astype(np.float32)
    blobs = ndimage.gaussian_filter(rng.standard_normal((size, size), np.float32), 6.0)
    spots = blobs > np.quantile(blobs, 0.9)
    tgt[spots] *= np.array([0.6, 0.57, 0.54], np.float32)
    return src, tgt


def _run(src, tgt, pyramid, levels=LEVELS, iterations=ITERATIONS):
    t0 = time.perf_counter()
    res = transfer_texture(
        src,
        tgt,
        None,
        target_mask=None,
        levels=levels,
        orientations=4,
        bins=256,
        iterations=iterations,
        seed=0,
        noise=0.1,
        feather=4.0,
        workers=2,
        pyramid=pyramid,
    )
    return res, time.perf_counter() - t0


def bench_texture_transfer(size=SIZE, levels=LEVELS, iterations=ITERATIONS):
    src, tgt = _albedos(size)
    ours, t_ours = _run(src, tgt, SteerablePyramid, levels, iterations)
    figures = {
        "ratio": "n/a",
        "facestats_s": t_ours,
        "distance_start": float(ours.distance[0]),
        "distance_end": float(ours.distance[-1]),
    }
    try:
        import pyrtools  # noqa: F401
    except ImportError:
        figures["pyrtools_s"] = "pyrtools not installed"
        return figures
    ref, t_ref = _run(src, tgt, PyrtoolsPyramid, levels, iterations)
    figures.update(
        {
            "ratio": t_ref / t_ours,
            "pyrtools_s": t_ref,
            "distance_end_pyrtools": float(ref.distance[-1]),
            "max_abs_diff": float(np.abs(ours.albedo - ref.albedo).max()),
            "mean_abs_diff": float(np.abs(ours.albedo - ref.albedo).mean()),
        }
    )
    return figures


def bench_pyramid(size=SIZE, levels=LEVELS):
    """One 2048² channel: decompose + reconstruct, facestats float32/float64 against pyrtools."""
    img = np.random.default_rng(1).uniform(0.1, 0.6, (size, size))
    figures = {}
    for name, dtype in (("float32", np.float32), ("float64", np.float64)):
        pyr = SteerablePyramid(img.shape, levels, 4, dtype=dtype)
        pyr.reconstruct(pyr.decompose(img))  # warm the mask cache
        t0 = time.perf_counter()
        rec = pyr.reconstruct(pyr.decompose(img))
        figures[f"facestats_{name}_s"] = time.perf_counter() - t0
        figures[f"facestats_{name}_recon_rel_err"] = float(np.abs(rec - img).max() / np.abs(img).max())
    try:
        import pyrtools  # noqa: F401
    except ImportError:
        return figures
    p = PyrtoolsPyramid(img.shape, levels, 4)
    t0 = time.perf_counter()
    rec = p.reconstruct(p.decompose(img))
    t_ref = time.perf_counter() - t0
    figures = {
        "ratio_float32": t_ref / figures["facestats_float32_s"],
        **figures,
        "pyrtools_s": t_ref,
        "pyrtools_recon_rel_err": float(np.abs(rec - img).max() / np.abs(img).max()),
    }
    return figures


def bench_colour_edit(size=SIZE, cameras=16):
    """Seconds and traced peak MB of a colour edit of a size² subject with ``cameras`` micro-normal cameras."""
    import tracemalloc

    from bench_export import representative_subject

    import facestats
    from facestats.edit import transfer_colour_subject

    source = representative_subject(size, cameras=cameras)
    subject_mb = sum(v.nbytes for v in source.variables.values()) / 2**20
    micro_mb = source["micro_normal"].nbytes / 2**20
    target = representative_subject(max(16, size // 8), cameras=1, seed=1)
    target.attrs["subject_id"] = "T001"
    with tempfile.TemporaryDirectory() as d, facestats.open_store(f"{d}/s.zarr", mode="a") as store:
        store.write_subjects([source, target])
        del source, target
        tracemalloc.start()
        t = time.perf_counter()
        edit = transfer_colour_subject(store, "S001", "T001")
        wall = time.perf_counter() - t
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        same = bool(np.array_equal(store.subject(edit.subject_id)["micro_normal"].values, edit.source["micro_normal"]))
    return {
        "peak_over_subject": peak / 2**20 / subject_mb,
        "edit_s": wall,
        "peak_MB": peak / 2**20,
        "subject_MB": subject_mb,
        "micro_normal_MB": micro_mb,
        "micro_normals_copied_exactly": same,
    }


BENCHMARKS = [
    ("pyramid_2048", bench_pyramid),
    ("texture_transfer_2048", bench_texture_transfer),
    ("colour_edit_2048", bench_colour_edit),
]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "pyramid_2048": {"size": 64, "levels": 3},
    "texture_transfer_2048": {"size": 64, "levels": 3, "iterations": 1},
    "colour_edit_2048": {"size": 64, "cameras": 2},
}
