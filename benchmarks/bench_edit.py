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


def _stationary_texture(seed, size):
    """A stationary albedo of known statistics: 1/f^0.8 Gaussian fields per channel, modulated by a shared
    log-normal field (heavy-tailed spots), about skin's colour; independent seeds are realisations of one texture."""
    rng = np.random.default_rng(seed)
    f = np.fft.fftfreq(size)
    k = np.hypot(*np.meshgrid(f, f, indexing="ij"))
    k[0, 0] = 1.0
    x = np.stack([np.fft.ifft2(np.fft.fft2(rng.standard_normal((size, size))) / k**0.8).real for _ in range(3)], -1)
    x /= x.std(axis=(0, 1))
    spots = np.exp(0.6 * x[..., :1])
    return np.clip(np.array([0.45, 0.3, 0.22]) * (1 + 0.15 * x) * spots / spots.mean(), 0, 1)


def bench_band_noise(
    size=512, levels=5, bins=256, sides=(16, 32, 64, 128, 256), draws=100, counts=(64, 256, 1024), faces=True
):
    """The sampling floor of the band-histogram distance against the coefficients a band holds (README,
    *Texture transfer needs coefficients*): not a speed figure.

    * ``iid_*``: ``draws`` samples of n values from a normal and a Laplace distribution against 256-bin
      histograms of two million values of the same distribution, mean distance (what
      ``MIN_COEFFICIENTS_PER_BIN`` rests on), beside ``distance_floor``'s expectation;
    * ``pyramid_*``: a second realisation of a stationary synthetic texture, inside squares of side ``sides``,
      against the first realisation's statistics (same texture, so every distance is sampling noise): each band's
      distance after the image-histogram match (``iterations=0``), averaged over the bands whose coefficients
      fall within a factor 1.5 of n, beside the formula's mean over the same bands;
    * ``faces_*`` (``faces=True``; builds the texture sample once): what a band's distance must resolve, the
      distances between different faces' bands where they hold thousands of coefficients (levels 1-4 of the
      512² texture sample, 7 levels, the face), for three pairs of its subjects, at the start of a transfer.
    """
    from facestats.edit.histogram import SOURCE_BINS, Histogram, distance_floor, histogram_distance, source_histogram
    from facestats.edit.statistics import TextureStatistics

    rng = np.random.default_rng(0)
    fig = {}
    for name in ("normal", "laplace"):
        draw = getattr(rng, name)
        target = Histogram.from_data(draw(size=2_000_000), bins)
        for n in counts:
            d = [histogram_distance(source_histogram(draw(size=n), SOURCE_BINS)[0], target) for _ in range(draws)]
            fig[f"iid_{name}_n{n}"] = float(np.mean(d))
            fig[f"iid_{name}_n{n}_formula"] = distance_floor(target, n)
    first, second = _stationary_texture(1, size), _stationary_texture(2, size)
    stats = TextureStatistics.from_image(first, levels=levels, bins=bins)
    measured = []  # (coefficients, distance, formula) per band and square
    for side in sides:
        mask = np.zeros((size, size), bool)
        mask[:side, :side] = True
        res = transfer_texture(second, stats, mask, iterations=0, noise=0.0, feather=0.0)
        n = np.asarray(res.coefficients[1][1:], float)
        measured += list(zip(n, res.band_distance[0].mean(0), res.band_floor.mean(0), strict=True))
    measured = np.array(measured)
    for n in counts:
        near = np.abs(np.log(measured[:, 0] / n)) < np.log(1.5)
        if near.any():
            fig[f"pyramid_n{n}"] = float(measured[near, 1].mean())
            fig[f"pyramid_n{n}_formula"] = float(measured[near, 2].mean())
            fig[f"pyramid_n{n}_bands"] = int(near.sum())
    if faces:
        import facestats
        from facestats.edit.grids import band_grids
        from facestats.pipeline.texture_sample import texture_sample

        grids = np.array(band_grids(7, 4)[1:])
        between = []
        with facestats.open_store(texture_sample()) as store:
            for a, b in (("S001", "S030"), ("S006", "S021"), ("S001", "S006")):
                face = store.subject(a)["region"].values > 0
                target = TextureStatistics.from_image(store.subject(b)["albedo"].values, face, levels=7, bins=bins)
                res = transfer_texture(store.subject(a)["albedo"].values, target, face, iterations=0, seed=1)
                start = res.band_distance[0].mean(0)
                between += [float(start[(grids == g)[: len(start)]].mean()) for g in range(1, 5)]
        fig["faces_levels_1_4_min"], fig["faces_levels_1_4_max"] = min(between), max(between)
    return fig


BENCHMARKS = [
    ("pyramid_2048", bench_pyramid),
    ("texture_transfer_2048", bench_texture_transfer),
    ("colour_edit_2048", bench_colour_edit),
    ("band_noise", bench_band_noise),
]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "pyramid_2048": {"size": 64, "levels": 3},
    "texture_transfer_2048": {"size": 64, "levels": 3, "iterations": 1},
    "colour_edit_2048": {"size": 64, "cameras": 2},
    "band_noise": {"size": 64, "levels": 2, "sides": (32, 64), "draws": 3, "counts": (64,), "faces": False},
}
