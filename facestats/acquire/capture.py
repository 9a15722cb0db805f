"""Captures: the raw data of one subject from the dome and the contact sensor.

A capture holds, for every lumitexel (Weyrich et al. 2006 §5), its geometry
(position, scanned normal, UV, area, region) and every (camera, light) sample:
the HDR radiance L (NaN where the sample is invalid: unlit, shadowed, occluded,
out of frame, back-facing, or clipped in every exposure), the beam-normal
irradiance E⊥ of each light at the lumitexel (the calibrated LED model of
:class:`facestats.acquire.dome.Dome`), and the calibration; plus the HDR
contact-sensor profiles R(r) of three sites with their noise.

Layout (arrays, any of numpy in memory or zarr on disk; dims in brackets)::

    position     [lumitexel, xyz]                 float32  mm
    scan_normal  [lumitexel, xyz]                 float32  unit
    uv           [lumitexel, uvc]                 float32  in [0, 1]
    area         [lumitexel]                      float32  mm²
    region       [lumitexel]                      uint8    1-10
    irradiance   [lumitexel, light, channel]      float32  E⊥, dome units
    radiance     [lumitexel, camera, light, channel] float16 dome units / sr, NaN = invalid
    region_map   [v, u]                           uint8    label image of the output maps
    sensor_profile, sensor_profile_std [site, fiber, channel] float64 mm⁻²
    fiber_distance [fiber]                        float64  mm

Attributes: ``dome`` and ``sensor`` (JSON calibration), subject metadata
(``subject_id``, ``person_id``, ``age``, ``gender``, ``skin_type``,
``condition``), ``map_size``, ``provenance`` (JSON).

On disk a capture is a zarr v3 group with these arrays (``dimension_names`` set,
so :func:`xarray.open_zarr` reads it too), chunked along ``lumitexel`` (2048
lumitexels per chunk by default, the fit's default block) so a subject at full
resolution streams chunk by chunk.  ``radiance`` and ``irradiance`` are
compressed with Blosc-LZ4 (radiance unshuffled, irradiance byte-shuffled):
measured on a 512² capture, radiance decodes in 7 µs per lumitexel against
24 µs with zarr's default zstd, for 32 % more bytes (``benchmarks/bench_fit.py``,
``codec``); the fit reads every chunk once, so decoding speed wins.  Other
arrays keep zarr's default (zstd).  Captures written with any codec read the same.

zarr leaves out a chunk that holds only its fill value, so a deleted radiance chunk would read as
2048 lumitexels of invalid samples and the fit would fill them in from their neighbours.  A
:class:`CaptureWriter` therefore writes every chunk, fill values or not, and marks the group with
:data:`ALL_CHUNKS_ATTR`; :func:`open_capture` refuses such a capture when any array has fewer chunks
on disk than its shape asks for (deleted, or not yet written).  Captures written before the mark
are read as before.  Real captures are brought
into this layout by whoever registers the images to the geometry; everything
downstream (the fit pipeline) reads only this layout.

The BRDF samples of eq. 8 are f_r = L / E with E = E⊥ (N·ωi):
:meth:`Lumitexels.brdf`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields

import numpy as np

from facestats.acquire.dome import Dome
from facestats.acquire.sensor import ContactSensor
from facestats.core.conventions import CHANNELS, SITES
from facestats.core.validate import check_integer
from facestats.errors import FormatError, ValidationError

__all__ = ["Capture", "Lumitexels", "open_capture", "CAPTURE_ARRAYS"]

#: Array name -> (dims, dtype).
CAPTURE_ARRAYS = {
    "position": (("lumitexel", "xyz"), "float32"),
    "scan_normal": (("lumitexel", "xyz"), "float32"),
    "uv": (("lumitexel", "uvc"), "float32"),
    "area": (("lumitexel",), "float32"),
    "region": (("lumitexel",), "uint8"),
    "irradiance": (("lumitexel", "light", "channel"), "float32"),
    "radiance": (("lumitexel", "camera", "light", "channel"), "float16"),
    "region_map": (("v", "u"), "uint8"),
    "sensor_profile": (("site", "fiber", "channel"), "float64"),
    "sensor_profile_std": (("site", "fiber", "channel"), "float64"),
    "fiber_distance": (("fiber",), "float64"),
}
PER_LUMITEXEL = tuple(k for k, (dims, _) in CAPTURE_ARRAYS.items() if dims[0] == "lumitexel")
_META = ("subject_id", "person_id", "age", "gender", "skin_type", "condition")


@dataclass
class Lumitexels:
    """A block of lumitexels with their samples, ready for the fit stages.

    Attributes
    ----------
    index : ndarray of int, shape (n,)
        Lumitexel indices in the capture.
    position, scan_normal, uv, area, region
        Per-lumitexel geometry (see the module docstring).
    wi : ndarray, shape (n, L, 3)
        Unit directions towards the LEDs.
    wo : ndarray, shape (n, C, 3)
        Unit directions towards the cameras.
    irradiance : ndarray, shape (n, L, 3)
        E⊥ per LED and channel.
    radiance : ndarray, shape (n, C, L, 3)
        HDR radiance, NaN where invalid, in the stored dtype (float16 for captures
        on disk: the fit converts only the valid samples).
    """

    index: np.ndarray
    position: np.ndarray
    scan_normal: np.ndarray
    uv: np.ndarray
    area: np.ndarray
    region: np.ndarray
    wi: np.ndarray
    wo: np.ndarray
    irradiance: np.ndarray
    radiance: np.ndarray

    @property
    def n(self) -> int:
        """Number of lumitexels in the block."""
        return int(self.index.shape[0])

    def __getitem__(self, sl: slice) -> "Lumitexels":
        """The lumitexels of a slice of this block (views, no copy)."""
        if not isinstance(sl, slice):
            raise ValidationError(f"Lumitexels can only be sliced by a slice, got {sl!r}")
        return Lumitexels(**{f.name: getattr(self, f.name)[sl] for f in fields(self)})

    @property
    def valid(self) -> np.ndarray:
        """(n, C, L) validity of each sample: finite, non-negative radiance and positive irradiance."""
        # local import: keeps facestats.model (21 modules) out of this module's import
        from facestats.model.fitting.samples import valid_samples

        return valid_samples(self.radiance, self.irradiance)

    def cos_incident(self, normal) -> np.ndarray:
        """N·ωi, shape (n, L).

        Parameters
        ----------
        normal : array_like, shape (n, 3)
            Unit normal of each lumitexel.

        Returns
        -------
        ndarray, shape (n, L)
            Cosine of each LED's direction, unclipped (negative below the horizon).
        """
        return np.einsum("nk,nlk->nl", normal, self.wi)

    def cos_outgoing(self, normal) -> np.ndarray:
        """N·ωo, shape (n, C).

        Parameters
        ----------
        normal : array_like, shape (n, 3)
            Unit normal of each lumitexel.

        Returns
        -------
        ndarray, shape (n, C)
            Cosine of each camera's direction, unclipped (negative below the horizon).
        """
        return np.einsum("nk,nck->nc", normal, self.wo)

    def brdf(self, normal=None) -> np.ndarray:
        """BRDF samples f_r = L / E, E = E⊥ max(N·ωi, 0) (Weyrich et al. 2006 eq. 8), shape (n, C, L, 3).

        NaN where the sample is invalid or the light is at or below the horizon of
        ``normal`` (default: the scanned normal).

        Parameters
        ----------
        normal : array_like, shape (n, 3), optional
            Unit normal of each lumitexel; default :attr:`scan_normal`.

        Returns
        -------
        ndarray of float32, shape (n, C, L, 3)
            f_r in sr⁻¹ (radiance in dome units / sr over irradiance in dome units).
        """
        nrm = self.scan_normal if normal is None else normal
        e = self.irradiance * np.maximum(self.cos_incident(nrm), 0)[..., None]
        with np.errstate(divide="ignore", invalid="ignore"):
            f = self.radiance.astype(np.float32) / e[:, None, :, :]
        return np.where(self.valid[..., None] & (e[:, None] > 0), f, np.nan).astype(np.float32)


@dataclass
class Capture:
    """One subject's capture (module docstring): arrays in memory or on disk, calibration and metadata.

    Attributes
    ----------
    arrays : dict
        Every array of :data:`CAPTURE_ARRAYS` by name (numpy arrays in memory or zarr arrays on disk, read when
        sliced); the per-lumitexel ones share their first length.
    attrs : dict
        ``dome`` and ``sensor`` (JSON strings or dicts), ``map_size``, the subject metadata (``subject_id``,
        ``person_id``, ``age``, ``gender``, ``skin_type``, ``condition``) and optionally ``provenance``.
    path : str or None
        Where the capture is on disk (None: in memory); used in messages.

    Raises
    ------
    FormatError
        A missing array or attribute, or per-lumitexel arrays of different lengths.
    """

    arrays: dict
    attrs: dict
    path: str | None = None
    _dome: Dome = field(default=None, init=False, repr=False)
    _sensor: ContactSensor = field(default=None, init=False, repr=False)

    def __post_init__(self):
        missing = [k for k in CAPTURE_ARRAYS if k not in self.arrays]
        if missing:
            raise FormatError(f"capture {self.path or ''} is missing arrays {missing}")
        n = self.arrays["position"].shape[0]
        for k in PER_LUMITEXEL:
            if self.arrays[k].shape[0] != n:
                raise FormatError(f"capture array {k!r} has {self.arrays[k].shape[0]} lumitexels, expected {n}")
        for key in ("dome", "sensor", "map_size") + _META:
            if key not in self.attrs:
                raise FormatError(f"capture {self.path or ''} is missing the attribute {key!r}")

    # -- metadata --------------------------------------------------------------
    @property
    def n_lumitexels(self) -> int:
        """Number of lumitexels."""
        return int(self.arrays["position"].shape[0])

    @property
    def map_size(self) -> int:
        """Side of the square UV maps the fit produces."""
        return int(self.attrs["map_size"])

    @property
    def dome(self) -> Dome:
        """The dome calibration (parsed once from the ``dome`` attribute)."""
        if self._dome is None:
            d = self.attrs["dome"]
            self._dome = Dome.from_dict(json.loads(d) if isinstance(d, str) else d)
        return self._dome

    @property
    def sensor(self) -> ContactSensor:
        """The contact sensor's description (parsed once from the ``sensor`` attribute)."""
        if self._sensor is None:
            s = self.attrs["sensor"]
            self._sensor = ContactSensor.from_attrs(json.loads(s) if isinstance(s, str) else s)
        return self._sensor

    @property
    def metadata(self) -> dict:
        """Subject metadata: ``subject_id``, ``person_id``, ``age``, ``gender``, ``skin_type``, ``condition``."""
        return {k: self.attrs[k] for k in _META}

    @property
    def provenance(self) -> dict:
        """How the capture was made (a dict; stored as JSON)."""
        p = self.attrs.get("provenance", "{}")
        return json.loads(p) if isinstance(p, str) else dict(p)

    def array(self, name, sl=slice(None)) -> np.ndarray:
        """An array (or a lumitexel slice of it) as numpy; a damaged chunk is a :class:`FormatError` naming the
        capture, the array and the lumitexels.

        Parameters
        ----------
        name : str
            An array of :data:`CAPTURE_ARRAYS`.
        sl : slice or index
            The part to read along the first axis (default all); any numpy/zarr index is passed on.

        Returns
        -------
        ndarray
            In the stored dtype.

        Raises
        ------
        FormatError
            A chunk cannot be read or decoded (naming the part read).
        """
        try:
            return np.asarray(self.arrays[name][sl])
        except (RuntimeError, ValueError, OSError) as exc:  # e.g. "error during blosc decompression: -1"
            raise FormatError(
                f"capture {self.path or '(in memory)'}: array {name!r}, {_part_read(name, sl, self.arrays[name])}, "
                f"cannot be read (a damaged or truncated chunk): {exc}"
            ) from exc

    # -- lumitexel blocks ------------------------------------------------------------
    def lumitexels(self, start: int = 0, stop: int | None = None, cameras=None) -> Lumitexels:
        """Lumitexels ``start:stop`` with their samples (directions from the calibration).

        Parameters
        ----------
        start : int
            First lumitexel, 0 ≤ ``start`` < ``stop``.
        stop : int, optional
            One past the last lumitexel (default, and at most, :attr:`n_lumitexels`).
        cameras : array_like of int, optional
            If given, keeps only those cameras' samples (the others become NaN, i.e. invalid).

        Returns
        -------
        Lumitexels
            Geometry as float64, ``wi`` and ``wo`` as float32 (:meth:`facestats.acquire.dome.Dome.directions32`),
            ``irradiance`` and ``radiance`` in the stored dtypes.

        Raises
        ------
        ValidationError
            An empty or out-of-range lumitexel range, or camera indices that are not integers in [0, C).
        FormatError
            A chunk cannot be read (:meth:`array`).
        """
        stop = self.n_lumitexels if stop is None else min(int(stop), self.n_lumitexels)
        if not (0 <= start < stop):
            raise ValidationError(
                f"lumitexel range must satisfy 0 <= start < stop <= {self.n_lumitexels}, got {start}:{stop}"
            )
        sl = slice(int(start), stop)
        pos = self.array("position", sl).astype(np.float64)
        dome = self.dome
        wi, wo = dome.directions32(pos)
        rad = self.array("radiance", sl)  # as stored (float16): the fit converts only the valid samples
        if cameras is not None:
            cams = np.asarray(cameras)
            if cams.dtype.kind not in "iu" or np.any((cams < 0) | (cams >= dome.n_cameras)):
                raise ValidationError(f"cameras must be indices in [0, {dome.n_cameras}), got {cameras!r}")
            keep = np.zeros(dome.n_cameras, bool)
            keep[np.asarray(cameras)] = True
            rad = np.where(keep[None, :, None, None], rad, np.nan)
        return Lumitexels(
            index=np.arange(sl.start, sl.stop),
            position=pos,
            scan_normal=self.array("scan_normal", sl).astype(np.float64),
            uv=self.array("uv", sl).astype(np.float64),
            area=self.array("area", sl).astype(np.float64),
            region=self.array("region", sl),
            wi=wi,
            wo=wo,
            irradiance=self.array("irradiance", sl),
            radiance=rad,
        )

    def blocks(self, size: int = 4096):
        """Yield ``(start, stop)`` lumitexel ranges aligned to ``size`` (≥ 1).

        Parameters
        ----------
        size : int
            Lumitexels per range (the last may be shorter), ≥ 1.

        Yields
        ------
        start, stop : int
            Covering 0 to :attr:`n_lumitexels` in order.

        Raises
        ------
        ValidationError
            ``size`` not an integer ≥ 1 (when iterated).
        """
        check_integer(size, "size", 1)
        for start in range(0, self.n_lumitexels, int(size)):
            yield start, min(start + int(size), self.n_lumitexels)

    # -- persistence -----------------------------------------------------------------
    def to_zarr(self, path, chunk: int = 2048):
        """Write the capture as a zarr v3 group (``chunk`` lumitexels per chunk); returns the path.

        Parameters
        ----------
        path : str or path-like
            The group to create (an existing one there is overwritten); :func:`open_capture` reads it.
        chunk : int
            Lumitexels per chunk and per block written, ≥ 1.

        Returns
        -------
        str
            ``path``.
        """
        writer = CaptureWriter(
            path,
            n_lumitexels=self.n_lumitexels,
            n_cameras=self.dome.n_cameras,
            n_lights=self.dome.n_leds,
            map_size=self.map_size,
            n_fibers=self.sensor.n_fibers,
            attrs=self.attrs,
            chunk=chunk,
        )
        for start, stop in self.blocks(chunk):
            writer.write_block(start, {k: self.array(k, slice(start, stop)) for k in PER_LUMITEXEL})
        writer.write_global({k: self.array(k) for k in CAPTURE_ARRAYS if k not in PER_LUMITEXEL})
        return str(path)


#: Group attribute of captures whose every chunk is on disk once written (module docstring).
ALL_CHUNKS_ATTR = "all_chunks_written"


def _part_read(name, sl, array) -> str:
    """What ``array[sl]`` reads, for a message: ``lumitexels 0:300`` (bounds resolved), or the index itself."""
    axis = CAPTURE_ARRAYS[name][0][0] if name in CAPTURE_ARRAYS else "row"
    label = "lumitexels" if axis == "lumitexel" else f"axis {axis!r}"
    if isinstance(sl, slice) and len(array.shape) > 0:
        try:
            start, stop, step = sl.indices(array.shape[0])
        except TypeError:  # bounds that are not integers
            pass
        else:
            return f"{label} {start}:{stop}" + (f":{step}" if step != 1 else "")
    return f"{label} index {sl!r:.60}"


def _lz4(shuffle):
    """A Blosc-LZ4 compressor (zarr v3 codec) with the given shuffle."""
    from zarr.codecs import BloscCodec

    return [BloscCodec(cname="lz4", clevel=5, shuffle=shuffle)]


#: Compressors of the arrays the fit decodes in every block (module docstring); others use zarr's default.
CAPTURE_CODECS = {"radiance": lambda: _lz4("noshuffle"), "irradiance": lambda: _lz4("shuffle")}


class CaptureWriter:
    """Create a capture group on disk and fill it block by block (bounded memory).

    ``camera_chunk`` (default: all cameras in one chunk) chunks ``radiance`` along
    ``camera`` too, so a writer that fills one camera at a time (the photograph
    ingest) writes whole chunks; :meth:`reopen` continues filling an existing group.
    """

    def __init__(
        self, path, *, n_lumitexels, n_cameras, n_lights, map_size, n_fibers, attrs, chunk=2048, camera_chunk=None
    ):
        import zarr

        check_integer(chunk, "chunk", 1)
        if camera_chunk is not None:
            check_integer(camera_chunk, "camera_chunk", 1)
        self.path = str(path)
        self.group = zarr.open_group(self.path, mode="w")
        sizes = {
            "lumitexel": n_lumitexels,
            "xyz": 3,
            "uvc": 2,
            "light": n_lights,
            "camera": n_cameras,
            "channel": 3,
            "v": map_size,
            "u": map_size,
            "site": len(SITES),
            "fiber": n_fibers,
        }
        for name, (dims, dtype) in CAPTURE_ARRAYS.items():
            shape = tuple(sizes[d] for d in dims)
            chunks = tuple(
                min(chunk, s) if d == "lumitexel" else min(camera_chunk or s, s) if d == "camera" else s
                for d, s in zip(dims, shape)
            )
            fill = np.nan if dtype.startswith("float") else 0
            codec = {"compressors": CAPTURE_CODECS[name]()} if name in CAPTURE_CODECS else {}
            self.group.create_array(
                name,
                shape=shape,
                chunks=chunks,
                dtype=dtype,
                dimension_names=dims,
                fill_value=fill,
                config={"write_empty_chunks": True},  # a missing chunk is then damage (module docstring)
                **codec,
            )
        self.group.attrs.update({k: (json.dumps(v) if isinstance(v, dict) else v) for k, v in attrs.items()})
        self.group.attrs[ALL_CHUNKS_ATTR] = True
        self.group.attrs["channel"] = list(CHANNELS)
        self.group.attrs["site"] = list(SITES)

    @classmethod
    def reopen(cls, path) -> "CaptureWriter":
        """A writer on an existing capture group (to continue an interrupted fill)."""
        import zarr

        self = cls.__new__(cls)
        self.path = str(path)
        try:
            self.group = zarr.open_group(self.path, mode="r+")
        except Exception as exc:  # zarr raises several types for a missing/invalid group
            raise FormatError(f"cannot reopen capture {path!s}: {exc}") from None
        return self

    def array(self, name):
        """The group's array ``name`` to write to, writing every chunk if the capture is marked so (zarr does not
        keep the setting in the array's metadata)."""
        arr = self.group[name]
        return arr.with_config({"write_empty_chunks": True}) if self.group.attrs.get(ALL_CHUNKS_ATTR) else arr

    def write_block(self, start, arrays: dict):
        """Write per-lumitexel arrays for the lumitexels from ``start`` on."""
        for name, arr in arrays.items():
            self.array(name)[start : start + arr.shape[0]] = arr

    def write_global(self, arrays: dict):
        """Write arrays that are not per lumitexel (region map, sensor data) whole."""
        for name, arr in arrays.items():
            self.array(name)[...] = arr


def open_capture(path) -> Capture:
    """Open a capture written by :meth:`Capture.to_zarr` (arrays stay on disk until sliced).

    Parameters
    ----------
    path : str or path-like
        The capture's zarr group.

    Returns
    -------
    Capture
        Its arrays are zarr arrays, read when sliced; ``path`` is kept as a string.

    Raises
    ------
    FormatError
        The group cannot be opened, lacks an array of :data:`CAPTURE_ARRAYS` or a required attribute, has arrays
        of different lumitexel counts, or (when written with every chunk) has a chunk missing on disk.
    """
    import zarr

    try:
        g = zarr.open_group(str(path), mode="r")
    except Exception as exc:  # zarr raises several types for a missing/invalid group
        raise FormatError(f"cannot open capture {path!s}: {exc}") from None
    arrays = {}
    for name in CAPTURE_ARRAYS:
        if name not in g:
            raise FormatError(f"capture {path!s} is missing the array {name!r}")
        arrays[name] = g[name]
        if g.attrs.get(ALL_CHUNKS_ATTR):
            on_disk = arrays[name].nchunks_initialized  # lists the array's keys in the store once
            if on_disk < arrays[name].nchunks:
                raise FormatError(
                    f"capture {path!s}: array {name!r} has {on_disk} of its {arrays[name].nchunks} chunks on disk "
                    "(a chunk was deleted, or the capture was not completely written)"
                )
    return Capture(arrays=arrays, attrs=dict(g.attrs), path=str(path))
