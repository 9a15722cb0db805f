"""Lumitexel samples as flat arrays: the data structure every fit stage works on.

A lumitexel gathers up to (cameras × lights) BRDF samples but only a fraction is
valid (about 900 of 2,400 in the default dome, §5).  Rather than dense
(lumitexel, camera, light) grids that are mostly empty, the stages keep only the
valid samples, sorted by lumitexel then camera, as flat arrays: the lumitexel,
camera and light of each sample and its radiance and irradiance (channel-major,
so every channel is contiguous).  Directions stay on the per-lumitexel grids
they come from (towards each light, towards each camera); the stages need only
cosines (N·ωi, N·ωo, ωi·ωo), which are computed on the small grids and gathered
per sample, so no per-sample 3-vector is ever built.

Because the samples of a lumitexel form one contiguous run (and, within it, the
samples of each camera), every per-lumitexel or per-(lumitexel, camera)
reduction is a segmented reduction over runs (``np.add.reduceat``; the first
smallest value of each run and its position come from ``np.minimum.reduceat``
over :func:`order_keys`), per-lumitexel values reach the samples by ``np.repeat``
over the run lengths, and grid values by ``np.take`` on precomputed flat
indices.  Sums over the lights of every (lumitexel, camera) can also run as
batched matrix products on the (lumitexel, camera, light) grid
(:meth:`Samples.on_grid`).  These primitives cost about as much as one
elementwise operation; ``np.bincount`` with weights, 2-D fancy indexing and
``np.where`` on scattered masks cost several times more (measured while
profiling the full-resolution fit of ``benchmarks/bench_fit.py``), so the fit
stages avoid them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facestats.errors import ValidationError
from facestats.model.fitting.engine import resolve_engine

__all__ = ["Samples", "run_starts", "segment_sum", "masked", "order_keys", "valid_samples"]


def run_starts(counts):
    """Start offsets (int64) of consecutive runs of ``counts`` samples: one per run, none for no runs.

    Parameters
    ----------
    counts : array_like of int, shape (k,)
        Length of each run (≥ 0).

    Returns
    -------
    ndarray of int64, shape (k,)
        Offset of each run: 0, counts[0], counts[0] + counts[1], ….
    """
    c = np.asarray(counts, np.int64)
    return np.cumsum(c) - c


def segment_sum(values, starts, counts):
    """Sums of ``values`` over consecutive runs (``starts``, ``counts``; runs may be empty).

    ``values`` is (S,) or (K, S) (summed along the last axis); the result has one
    entry per run, 0 for empty runs, in the dtype of ``values`` (float32 sums are
    pairwise, accurate to about 1e-7 relative).

    Parameters
    ----------
    values : array_like, shape (S,) or (K, S)
        Per-sample values.
    starts, counts : ndarray of int, shape (k,)
        Offset and length of each run (:func:`run_starts`).

    Returns
    -------
    ndarray, shape (k,) or (K, k)
        The sums, float in the dtype of ``values`` or int64 for integer or bool ``values``.
    """
    v = np.asarray(values)
    nonempty = counts > 0
    out = np.zeros(v.shape[:-1] + (counts.shape[0],), v.dtype if v.dtype.kind == "f" else np.int64)
    if v.shape[-1] and nonempty.any():
        sums = np.add.reduceat(v, starts[nonempty], axis=-1, dtype=out.dtype)
        if nonempty.all():
            return sums
        out[..., nonempty] = sums
    return out


def masked(values, mask):
    """``values`` where ``mask``, 0 elsewhere (also where a masked-out value is NaN or infinite).

    A product with the mask, which streams (``np.where`` is several times slower);
    masked-out products that are not finite are then zeroed in place.

    Parameters
    ----------
    values : array_like
        The values.
    mask : array_like of bool
        Broadcast against ``values``.

    Returns
    -------
    ndarray
        ``values`` × ``mask``, broadcast shape; NaN or inf values where ``mask`` holds stay as they are.
    """
    v = np.asarray(values)
    m = np.asarray(mask, bool)
    with np.errstate(invalid="ignore"):
        out = v * m
    bad = ~np.isfinite(out)
    if bad.any():  # NaN from inf × 0 (or a NaN) where masked out: zero those only
        np.putmask(out, bad & ~m, 0)
    return out


def order_keys(values):
    """int64 keys that order samples by (float32 value, position): ``np.minimum.reduceat`` over
    them gives each run's first smallest value and, in the low 32 bits, its position.

    The upper word holds the value's bits read as int32, which order the
    non-negative floats; flipping the magnitude bits of the negative ones
    (``bits ^ ((bits >> 31) & 0x7FFFFFFF)``) extends the order to them (−0 just
    below +0).  The lower word holds the position (fewer than 2³¹ values, none NaN).

    Parameters
    ----------
    values : array_like, shape (S,)
        Values, read as float32.

    Returns
    -------
    ndarray of int64, shape (S,)
        One key per value.

    Raises
    ------
    ValidationError
        ``values`` not 1-D, or with 2³¹ entries or more.
    """
    v = np.ascontiguousarray(values, np.float32)
    if v.ndim != 1 or v.size >= 2**31:
        raise ValidationError(f"values must be 1-D with fewer than 2**31 entries, got shape {v.shape}")
    key = np.empty(v.size, np.int64)
    words = key.view(np.int32).reshape(-1, 2)
    low, high = (0, 1) if np.little_endian else (1, 0)
    words[:, low] = np.arange(v.size, dtype=np.int32)
    bits = v.view(np.int32)
    np.bitwise_xor(bits, (bits >> 31) & np.int32(0x7FFFFFFF), out=words[:, high])
    return key


def valid_samples(radiance, irradiance):
    """(n, C, L) validity of dome samples: all channels' radiance ≥ 0 and not NaN, all E⊥ > 0.

    ``radiance`` is (n, C, L, 3), ``irradiance`` (n, L, 3).  float16 radiance (the
    capture format) is tested on its bit patterns, without conversion: a
    half-precision value is ≥ 0 and not NaN exactly when its pattern is at most
    0x7C00 (+∞) or equals 0x8000 (−0).

    Parameters
    ----------
    radiance : array_like, shape (n, C, L, 3)
        Radiance per lumitexel, camera, light and channel (any float dtype; float16 as captured).
    irradiance : array_like, shape (n, L, 3)
        Beam-normal irradiance E⊥ per lumitexel, light and channel.

    Returns
    -------
    ndarray of bool, shape (n, C, L)
        True where the sample is valid (+∞ radiance counts as valid).
    """
    r = np.asarray(radiance)
    if r.dtype == np.float16:
        u = r.view(np.uint16)
        high = np.maximum(np.maximum(u[..., 0], u[..., 1]), u[..., 2])
        ok = high <= 0x7C00
        if np.any(u == 0x8000):  # a −0 channel (valid, but its pattern is above 0x7C00): exact test
            exact = (u <= 0x7C00) | (u == 0x8000)
            ok = exact[..., 0] & exact[..., 1] & exact[..., 2]
    else:
        ok = np.minimum(np.minimum(r[..., 0], r[..., 1]), r[..., 2]) >= 0  # NaN compares False
    e = np.asarray(irradiance)
    return ok & ((e[..., 0] > 0) & (e[..., 1] > 0) & (e[..., 2] > 0))[:, None, :]


def _check_dome(wi, wo, irradiance, radiance, keep_cameras=None):
    """(n, C, L) of a dome grid whose arrays have the documented shapes, else ValidationError naming the first
    array that does not (shapes only: nothing is converted or copied)."""
    r = np.shape(radiance)
    if len(r) != 4 or r[3] != 3:
        raise ValidationError(f"radiance must have shape (n, C, L, 3), got {r}")
    n, n_cam, n_led = r[:3]
    wanted = [("wi", wi, (n, n_led, 3), "(n, L, 3)"), ("wo", wo, (n, n_cam, 3), "(n, C, 3)")]
    wanted.append(("irradiance", irradiance, (n, n_led, 3), "(n, L, 3)"))
    if keep_cameras is not None:
        wanted.append(("keep_cameras", keep_cameras, (n_cam,), "(C,)"))
    for name, value, shape, text in wanted:
        if np.shape(value) != shape:
            raise ValidationError(
                f"{name} must have shape {text} = {shape} to match radiance {r}, got {np.shape(value)}"
            )
    return n, n_cam, n_led


def _dot3(a, b):
    """Dot products of 3-vectors on the last axis, broadcast, as three products and two sums.

    Elementwise IEEE arithmetic gives the same bits on every CPU, where a BLAS product (``matmul``)
    sums in an order that depends on the kernel the CPU selects: the fit's results would then
    differ between machines in the last bits, and iterative fits amplify that.
    """
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


@dataclass
class Samples:
    """Valid samples of ``n_texels`` lumitexels, sorted by lumitexel, then camera.

    Derived arrays (run lengths and starts, grid indices, ωi·ωo, …) are cached privately, not a constructor
    argument: a new instance (also one from :func:`dataclasses.replace`) starts with an empty cache.

    Attributes
    ----------
    n_texels : int
    texel : ndarray of int32, shape (S,)
        Lumitexel of each sample (non-decreasing).
    camera_index, light_index : ndarray of intp, shape (S,)
        Flat index of each sample's outgoing and incident direction in
        ``wo_grid.reshape(-1, 3)`` and ``wi_grid.reshape(-1, 3)`` (non-decreasing
        camera within a lumitexel); :attr:`camera` and :attr:`light` give the
        per-lumitexel indices.
    wi_grid : ndarray of float32, shape (n, L, 3)
        Unit directions from each lumitexel towards each light.
    wo_grid : ndarray of float32, shape (n, C, 3)
        Unit directions from each lumitexel towards each camera.
    radiance : ndarray of float32, shape (3, S)
        Radiance per channel (RGB).
    irradiance : ndarray of float32, shape (3, S)
        Beam-normal irradiance E⊥ per channel.
    paired : bool
        True when ``camera`` and ``light`` index the same per-sample direction
        pairs (:meth:`from_arrays`) rather than a dome's camera and light grids.
    engine : {"numba", "numpy"} or None
        Implementation of the per-sample primitives and of the stages that take these
        samples (:mod:`facestats.model.fitting.engine`); None: the configured default.
    """

    n_texels: int
    texel: np.ndarray
    camera_index: np.ndarray
    light_index: np.ndarray
    wi_grid: np.ndarray
    wo_grid: np.ndarray
    radiance: np.ndarray
    irradiance: np.ndarray
    paired: bool = False
    engine: str | None = None
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def from_grid(cls, wi, wo, irradiance, radiance, valid):
        """Flatten a dome grid to its valid samples.

        Parameters
        ----------
        wi : array_like, shape (n, L, 3)
            Unit directions from each lumitexel towards each light (stored as float32).
        wo : array_like, shape (n, C, 3)
            Unit directions from each lumitexel towards each camera (stored as float32).
        irradiance : array_like, shape (n, L, 3)
            Beam-normal irradiance E⊥ per lumitexel, light and channel.
        radiance : array_like, shape (n, C, L, 3)
            Radiance per lumitexel, camera, light and channel, any float dtype (float16 as captured).
        valid : array_like of bool, shape (n, C, L)
            Samples to keep (e.g. :func:`valid_samples`).

        Returns
        -------
        Samples
            The kept samples, radiance and irradiance as float32, ``engine`` None.

        Raises
        ------
        ValidationError
            An array whose shape is not the one above (``radiance`` sets n, C and L).
        """
        n, n_cam, n_led = _check_dome(wi, wo, irradiance, radiance)
        v = np.asarray(valid, bool)
        if v.shape != (n, n_cam, n_led):
            raise ValidationError(
                f"valid must have shape (n, C, L) = {(n, n_cam, n_led)} to match radiance {np.shape(radiance)}, "
                f"got {v.shape}"
            )
        # Sample positions in the row-major (lumitexel, camera, light) grid, and the run length of
        # every (lumitexel, camera): indices follow from repeats, with no division.
        index_dtype = np.intp  # the index type np.take wants (no conversion per gather)
        flat = np.flatnonzero(v)
        per_tc = np.count_nonzero(v.reshape(n * n_cam, n_led), axis=1)
        tc = np.repeat(np.arange(n * n_cam, dtype=index_dtype), per_tc)
        per_texel = per_tc.reshape(n, n_cam).sum(1)
        texel = np.repeat(np.arange(n, dtype=np.int32), per_texel)
        rad = np.asarray(radiance).reshape(-1, 3).take(flat, axis=0).T.astype(np.float32, order="C")
        irr_grid = np.ascontiguousarray(np.moveaxis(np.asarray(irradiance, np.float32), -1, 0)).reshape(3, -1)
        light_index = flat - (tc - texel) * n_led  # flat = (t C + c) L + l, tc = t C + c: t L + l
        out = cls(
            n_texels=n,
            texel=texel,
            camera_index=tc,
            light_index=light_index,
            wi_grid=np.asarray(wi, np.float32),
            wo_grid=np.asarray(wo, np.float32),
            radiance=rad,
            irradiance=np.stack([irr_grid[c].take(light_index) for c in range(3)]),
        )
        out._cache.update(counts=per_texel, grid_index=flat, camera_runs=per_tc)
        return out

    @classmethod
    def from_dome(cls, wi, wo, irradiance, radiance, *, keep_cameras=None, engine=None):
        """The valid samples of a dome grid (:func:`valid_samples`, minus cameras left out), and the invalid count.

        With the numba engine and float16 radiance (the capture format) one compiled pass
        (:func:`facestats.model.fitting.kernels.samples.flatten_grid`) does both.

        Parameters
        ----------
        wi : array_like, shape (n, L, 3)
            Unit directions towards the lights, as :meth:`from_grid`.
        wo : array_like, shape (n, C, 3)
            Unit directions towards the cameras, as :meth:`from_grid`.
        irradiance : array_like, shape (n, L, 3)
            Beam-normal irradiance E⊥, as :meth:`from_grid`.
        radiance : array_like, shape (n, C, L, 3)
            Radiance, as :meth:`from_grid`.
        keep_cameras : array_like of bool, shape (C,), optional
            Cameras whose samples may be used (default all).
        engine : {"numba", "numpy"} or None
            Engine of the result (:func:`facestats.model.fitting.engine.resolve_engine`); None: the configured
            default.

        Returns
        -------
        samples : Samples
        n_invalid : ndarray of int64, shape (n,)
            Grid entries per lumitexel that are not used: invalid or of a camera left out.

        Raises
        ------
        ValidationError
            An unknown or unusable ``engine``, or an array whose shape is not the one above (``radiance`` sets n,
            C and L).
        """
        engine = resolve_engine(engine)
        n, n_cam, n_led = _check_dome(wi, wo, irradiance, radiance, keep_cameras)
        keep = np.ones(n_cam, bool) if keep_cameras is None else np.asarray(keep_cameras, bool)
        if engine == "numba" and np.asarray(radiance).dtype == np.float16:
            # local import: the kernels import numba
            from facestats.model.fitting.kernels.samples import flatten_grid

            rad = np.ascontiguousarray(radiance).view(np.uint16)
            irr = np.ascontiguousarray(irradiance, np.float32)
            texel, cam_i, light_i, grid_i, rad_s, irr_s, per_tc = flatten_grid(rad, irr, keep)
            out = cls(
                n_texels=n,
                texel=texel,
                camera_index=cam_i,
                light_index=light_i,
                wi_grid=np.asarray(wi, np.float32),
                wo_grid=np.asarray(wo, np.float32),
                radiance=rad_s,
                irradiance=irr_s,
                engine=engine,
            )
            per_texel = per_tc.reshape(n, n_cam).sum(1)
            out._cache.update(counts=per_texel, grid_index=grid_i, camera_runs=per_tc)
            return out, n_cam * n_led - per_texel
        valid = valid_samples(radiance, irradiance) & keep[None, :, None]
        out = cls.from_grid(wi, wo, irradiance, radiance, valid)
        out.engine = engine
        return out, (~valid).reshape(n, n_cam * n_led).sum(1)

    @classmethod
    def from_arrays(cls, wi, wo, valid, radiance=None, irradiance=None, engine=None):
        """From per-texel sample arrays ``wi``, ``wo`` (T, S, 3) and ``valid`` (T, S).

        The samples are ``paired``: sample ``s`` of texel ``t`` has its own (ωi, ωo) pair.  Nothing is checked.

        Parameters
        ----------
        wi, wo : array_like, shape (T, S, 3)
            Unit directions towards the light and the camera per texel and sample (stored as float32).
        valid : array_like of bool, shape (T, S)
            Samples to keep.
        radiance : array_like, shape (T, S, 3), optional
            Radiance per sample and channel; default 0.
        irradiance : array_like, shape (T, S, 3), optional
            Beam-normal irradiance E⊥ per sample and channel; default 1.
        engine : {"numba", "numpy"} or None
            Engine of the result (not resolved here); None: the configured default.

        Returns
        -------
        Samples
        """
        v = np.asarray(valid, bool)
        t, s = np.nonzero(v)
        n_s = t.size
        rad = np.zeros((3, n_s), np.float32) if radiance is None else np.asarray(radiance, np.float32)[t, s].T
        irr = np.ones((3, n_s), np.float32) if irradiance is None else np.asarray(irradiance, np.float32)[t, s].T
        flat = (t * v.shape[1] + s).astype(np.intp)
        return cls(
            n_texels=v.shape[0],
            texel=t.astype(np.int32),
            camera_index=flat,
            light_index=flat,
            wi_grid=np.asarray(wi, np.float32),
            wo_grid=np.asarray(wo, np.float32),
            radiance=np.ascontiguousarray(rad),
            irradiance=np.ascontiguousarray(irr),
            paired=True,
            engine=engine,
        )

    # -- runs and indices ---------------------------------------------------------------
    @property
    def n(self) -> int:
        """Number of samples."""
        return int(self.texel.shape[0])

    @property
    def counts(self) -> np.ndarray:
        """Samples per lumitexel, shape (n_texels,)."""
        if "counts" not in self._cache:
            # Sorted texel ids: run boundaries by binary search.
            edges = np.searchsorted(self.texel, np.arange(self.n_texels + 1))
            self._cache["counts"] = np.diff(edges)
        return self._cache["counts"]

    @property
    def starts(self) -> np.ndarray:
        """Offset of each lumitexel's run of samples, shape (n_texels,)."""
        if "starts" not in self._cache:
            self._cache["starts"] = run_starts(self.counts)
        return self._cache["starts"]

    @property
    def camera(self) -> np.ndarray:
        """Index of each sample's camera (its row of ``wo_grid[texel]``), shape (S,)."""
        return self.camera_index - self.texel.astype(np.intp) * self.wo_grid.shape[1]

    @property
    def light(self) -> np.ndarray:
        """Index of each sample's light (its row of ``wi_grid[texel]``), shape (S,)."""
        return self.light_index - self.texel.astype(np.intp) * self.wi_grid.shape[1]

    def camera_runs(self):
        """Runs of the (lumitexel, camera) groups: ``(key, starts, counts)``, empty groups left out.

        ``key`` = lumitexel × C + camera of each run (C = ``wo_grid.shape[1]``).
        """
        if "camera_run_triple" not in self._cache:
            if "camera_runs" in self._cache:  # from a dome grid: one run length per (lumitexel, camera)
                per_tc = self._cache["camera_runs"]
                key = np.flatnonzero(per_tc)
                cnt = per_tc[key]
            else:
                k = self.camera_index
                if k.size and np.any(k[1:] < k[:-1]):
                    raise ValidationError("samples must be grouped by (lumitexel, camera) for per-camera runs")
                bound = np.flatnonzero(np.concatenate([[True], k[1:] != k[:-1]])) if k.size else np.zeros(0, np.int64)
                key = k[bound]
                cnt = np.diff(np.concatenate([bound, [k.size]]))
            start = run_starts(cnt)
            self._cache["camera_run_triple"] = (key.astype(np.int64), start, cnt)
        return self._cache["camera_run_triple"]

    # -- per-lumitexel reductions and expansions ----------------------------------------
    def count(self, mask=None) -> np.ndarray:
        """Samples per lumitexel (optionally only where ``mask``).

        Parameters
        ----------
        mask : array_like of bool, shape (S,), optional
            Samples to count; default all.

        Returns
        -------
        ndarray of int, shape (n_texels,)
        """
        if mask is None:
            return self.counts
        return segment_sum(np.asarray(mask, bool).view(np.int8), self.starts, self.counts)

    def sum(self, values, mask=None) -> np.ndarray:
        """Per-lumitexel sum of per-sample ``values`` (S,) or (K, S) (optionally only where ``mask``), float64.

        Masked-out values may be non-finite (they are excluded, not multiplied by 0).

        Parameters
        ----------
        values : array_like, shape (S,) or (K, S)
            Per-sample values.
        mask : array_like of bool, shape (S,), optional
            Samples to include; default all.

        Returns
        -------
        ndarray of float64, shape (n_texels,) or (K, n_texels)
        """
        v = np.asarray(values) if mask is None else masked(values, mask)
        return segment_sum(v, self.starts, self.counts).astype(np.float64)

    def expand(self, per_texel) -> np.ndarray:
        """Per-lumitexel values (n_texels, ...) repeated for each sample of the lumitexel, shape (S, ...).

        Parameters
        ----------
        per_texel : array_like, shape (n_texels, ...)
            One value (or row) per lumitexel.
        """
        return np.repeat(np.asarray(per_texel), self.counts, axis=0)

    def on_grid(self, values) -> np.ndarray:
        """Per-sample ``values`` (S,) placed on the (lumitexel, camera, light) grid (n, C, L), 0 elsewhere.

        Only for samples on a dome grid (not ``paired``).

        Parameters
        ----------
        values : array_like, shape (S,)
            Per-sample values.

        Returns
        -------
        ndarray, shape (n_texels, C, L)
            In the dtype of ``values``.

        Raises
        ------
        ValidationError
            The samples are ``paired``.
        """
        if self.paired:
            raise ValidationError("on_grid needs samples on a dome grid (Samples.from_grid), not paired samples")
        v = np.asarray(values)
        out = np.zeros(self.n_texels * self.wo_grid.shape[1] * self.wi_grid.shape[1], v.dtype)
        out[self._grid_index()] = v
        return out.reshape(self.n_texels, self.wo_grid.shape[1], self.wi_grid.shape[1])

    def _grid_index(self):
        """Flat index of each sample into the (lumitexel, camera, light) grid (cached)."""
        if "grid_index" not in self._cache:
            self._cache["grid_index"] = self.camera_index * self.wi_grid.shape[1] + self.light
        return self._cache["grid_index"]

    def at_lights(self, grid) -> np.ndarray:
        """Per-sample values of a (lumitexel, light) grid (n, L).

        Parameters
        ----------
        grid : array_like, shape (n_texels, L)
            One value per lumitexel and light (for ``paired`` samples: per texel and sample, (T, S)).

        Returns
        -------
        ndarray, shape (S,)
        """
        return np.asarray(grid).reshape(-1).take(self.light_index)

    def at_cameras(self, grid) -> np.ndarray:
        """Per-sample values of a (lumitexel, camera) grid (n, C).

        Parameters
        ----------
        grid : array_like, shape (n_texels, C)
            One value per lumitexel and camera (for ``paired`` samples: per texel and sample, (T, S)).

        Returns
        -------
        ndarray, shape (S,)
        """
        return np.asarray(grid).reshape(-1).take(self.camera_index)

    # -- geometry ------------------------------------------------------------------------
    @property
    def wi(self) -> np.ndarray:
        """Per-sample unit directions towards the light, (S, 3) (built on demand)."""
        return self.wi_grid.reshape(-1, 3).take(self.light_index, axis=0)

    @property
    def wo(self) -> np.ndarray:
        """Per-sample unit directions towards the camera, (S, 3) (built on demand)."""
        return self.wo_grid.reshape(-1, 3).take(self.camera_index, axis=0)

    def cos_grids(self, normal, dtype=np.float32):
        """(N·ωi on the light grid (n, L), N·ωo on the camera grid (n, C)) for normals (n, 3).

        Parameters
        ----------
        normal : array_like, shape (n_texels, 3)
            Unit normal per lumitexel (not checked).
        dtype : numpy.dtype
            Float dtype of the computation and results.

        Returns
        -------
        cos_i : ndarray, shape (n_texels, L)
        cos_o : ndarray, shape (n_texels, C)
        """
        nrm = np.asarray(normal, dtype)
        return _dot3(self.wi_grid.astype(dtype, copy=False), nrm[:, None]), _dot3(
            self.wo_grid.astype(dtype, copy=False), nrm[:, None]
        )

    def cos(self, normal, dtype=np.float32):
        """(N·ωi, N·ωo) per sample for per-lumitexel normals (n, 3).

        Parameters
        ----------
        normal : array_like, shape (n_texels, 3)
            Unit normal per lumitexel (not checked).
        dtype : numpy.dtype
            Float dtype of the results; float32 runs as a compiled kernel with the numba engine on a dome grid.

        Returns
        -------
        cos_i, cos_o : ndarray, shape (S,)
        """
        if self._compiled() and np.dtype(dtype) == np.float32:
            ci, co, io = self._kernel_cosines(normal)
            self._cache.setdefault("io", io)
            return ci, co
        ci, co = self.cos_grids(normal, dtype)
        return self.at_lights(ci), self.at_cameras(co)

    @property
    def resolved_engine(self) -> str:
        """The engine these samples run with (:attr:`engine`, or the configured default)."""
        return resolve_engine(self.engine)

    def _compiled(self) -> bool:
        """True when the per-sample primitives run as compiled kernels (numba engine, dome grid)."""
        return not self.paired and self.resolved_engine == "numba"

    def _kernel_cosines(self, normal=None):
        """(N·ωi, N·ωo, ωi·ωo) per sample from one compiled pass (the first two empty without ``normal``)."""
        # local import: the kernels import numba
        from facestats.model.fitting.kernels.samples import sample_cosines

        nrm = np.zeros((0, 3), np.float32) if normal is None else np.ascontiguousarray(normal, np.float32)
        return sample_cosines(
            self.texel,
            self.light_index,
            self.camera_index,
            np.ascontiguousarray(self.wi_grid).reshape(-1, 3),
            np.ascontiguousarray(self.wo_grid).reshape(-1, 3),
            nrm,
            normal is not None,
        )

    def cos_io(self) -> np.ndarray:
        """ωi·ωo per sample (float32, cached)."""
        if "io" not in self._cache:
            if self._compiled():
                io = self._kernel_cosines()[2]
            elif self.paired:
                io = np.einsum("sk,sk->s", self.wi, self.wo)
            else:
                grid = _dot3(self.wo_grid[:, :, None], self.wi_grid[:, None])  # (n, C, L)
                io = grid.reshape(-1).take(self._grid_index())
            self._cache["io"] = io.astype(np.float32, copy=False)
        return self._cache["io"]

    def cos_half(self, cos_i, cos_o) -> np.ndarray:
        """Per-sample N·H, H = (ωi + ωo)/‖ωi + ωo‖, from N·ωi and N·ωo: (cos θi + cos θo) / √(2 + 2 ωi·ωo).

        Parameters
        ----------
        cos_i, cos_o : array_like, shape (S,)
            N·ωi and N·ωo per sample (:meth:`cos`).

        Returns
        -------
        ndarray, shape (S,)
            N·H; the denominator is kept at least 1e-6 (√1e-12) where ωi and ωo are opposite.
        """
        io = self.cos_io()
        cos_i, cos_o = np.asarray(cos_i), np.asarray(cos_o)
        if self._compiled() and cos_i.shape == cos_o.shape == io.shape and cos_i.dtype == cos_o.dtype == np.float32:
            # local import: the kernels import numba
            from facestats.model.fitting.kernels.samples import half_cosines

            return half_cosines(np.ascontiguousarray(cos_i), np.ascontiguousarray(cos_o), io)
        return (cos_i + cos_o) / np.sqrt(np.maximum(2 + 2 * io, 1e-12))

    def grey(self) -> np.ndarray:
        """Σ_ch L / Σ_ch E⊥ per sample: the grey f_r cos θi (cached)."""
        if "grey" not in self._cache:
            r, e = self.radiance, self.irradiance
            with np.errstate(invalid="ignore", divide="ignore"):
                self._cache["grey"] = (r[0] + r[1] + r[2]) / (e[0] + e[1] + e[2])
        return self._cache["grey"]

    # -- order statistics ----------------------------------------------------------------
    def ranks(self, mask=None):
        """Position of each kept sample within its lumitexel: ``(texel, rank, counts)``.

        ``texel`` and ``rank`` (S',) index the padded (lumitexel, rank) layout of the
        samples kept by ``mask`` (all by default); ``counts`` (n_texels,) is the
        number kept per lumitexel.  Relies on the samples being sorted by lumitexel.

        Parameters
        ----------
        mask : array_like of bool, shape (S,), optional
            Samples to keep; default all.

        Returns
        -------
        texel : ndarray of int32, shape (S',)
        rank : ndarray of int, shape (S',)
        counts : ndarray of int, shape (n_texels,)
        """
        if mask is None:
            t, counts, start = self.texel, self.counts, self.starts
        else:
            m = np.asarray(mask, bool)
            t = self.texel[m]
            counts = self.count(m)
            start = run_starts(counts)
        return t, np.arange(t.size) - np.repeat(start, counts), counts

    def padded(self, values, fill, mask=None):
        """Per-lumitexel padded view (n_texels, S_max) of ``values`` (S,) (only ``mask`` samples kept).

        Parameters
        ----------
        values : array_like, shape (S,)
            Per-sample values.
        fill : scalar
            Value of the slots past each lumitexel's kept samples.
        mask : array_like of bool, shape (S,), optional
            Samples to keep; default all.

        Returns
        -------
        padded : ndarray, shape (n_texels, S_max)
            A new array in the dtype of ``values``; S_max is the largest count kept, at least 1.
        counts : ndarray of int, shape (n_texels,)
            Samples kept per lumitexel.
        """
        vals = np.asarray(values)
        if mask is None:
            counts, start = self.counts, self.starts
        else:
            m = np.asarray(mask, bool)
            vals = vals[m]
            counts = self.count(m)
            start = run_starts(counts)
        width = max(int(counts.max(initial=0)), 1)
        out = np.full((self.n_texels, width), fill, dtype=vals.dtype)
        # Slot of each sample: its rank plus its row offset (non-decreasing, so the scatter streams).
        slot = np.arange(vals.shape[0], dtype=np.int64) + np.repeat(
            np.arange(self.n_texels, dtype=np.int64) * width - start, counts
        )
        out.reshape(-1)[slot] = vals
        return out, counts
