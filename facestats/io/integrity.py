"""Integrity of stored subjects: the manifest written with each generation, and the checked read of one.

Every subject group carries one bookkeeping attribute, :data:`STORE_ATTR`
(JSON: schema version, writer version, write time, generation and a
*manifest* of every variable's dims, shape, dtype and CRC-32 of its bytes, and
for map variables the CRC-32 of each chunk of :data:`~facestats.io.layout.MAP_CHUNK_ROWS`
rows of ``v``).  :func:`open_generation` reads a generation back and checks
it: the group must exist, carry the manifest, have the recorded variables with
the recorded dims, shapes and dtypes, and bytes whose CRC-32 matches (a
deleted chunk file would otherwise read silently as fill values); finally
:func:`facestats.io.schema.validate_subject` runs.  With ``lazy=True`` the
bytes are checked when they are read: every variable left on disk is wrapped
so that each chunk is verified as it is loaded (a band of rows of a map reads
and verifies only its own chunks; generations written before chunk checksums
existed verify the whole variable on its first read).  So *every* read path
verifies.  Validation (``banded=True``) checks the maps of many bands that way too, one band in memory at a
time, with the checks and messages of a full read.

Two kinds of failure are kept apart, because repair acts on one only:

* :class:`~facestats.errors.SchemaError` — the data are damaged (checksum
  mismatch, undecodable or missing chunk, wrong metadata), naming the subject
  and the variable;
* :class:`~facestats.errors.StoreError` (not a SchemaError) — the data could
  not be read just now (an I/O error such as EIO or EACCES): they may well be
  intact, so nothing may be moved or dropped because of it.

xarray is imported when a generation is opened, not with this module.
"""

from __future__ import annotations

import functools
import json
import warnings
import zlib

import numpy as np

from facestats.core.crc32 import crc32_combine
from facestats.core.version import __version__
from facestats.errors import SchemaError, StoreError, ValidationError
from facestats.io.layout import ROOT_META, generation_rel, map_chunk_rows
from facestats.io.schema import SCHEMA_VERSION, MapChecks, face_texels, subject_kind, validate_subject
from facestats.io.summary import GATHERED_TEXELS, SUMMARY_MAPS

__all__ = [
    "STORE_ATTR",
    "digest",
    "manifest_entry",
    "store_attr_json",
    "open_generation",
    "banded_variables",
    "read_failure",
]

#: Group attribute holding the store's bookkeeping (removed from ``Dataset.attrs`` on read).
STORE_ATTR = "facestats_store"


def digest(values) -> tuple[str, int]:
    """(dtype tag, CRC-32) of an array's contents; strings are hashed by text.

    Parameters
    ----------
    values : array_like

    Returns
    -------
    tag : str
        ``"str"`` for text, else the little-endian numpy dtype string (``"<f4"``).
    crc : int
        CRC-32 of the bytes (little-endian) or of the texts joined by ``\\x1f``.
    """
    a = np.asarray(values)
    if a.dtype.kind in "UOST":
        text = "\x1f".join(str(x) for x in a.reshape(-1).tolist())
        return "str", zlib.crc32(text.encode("utf-8"))
    a = _little_endian(a)
    return a.dtype.str, zlib.crc32(a.reshape(-1).view(np.uint8))


def _little_endian(a: np.ndarray) -> np.ndarray:
    """``a`` C-contiguous and little-endian (a copy only where it is not)."""
    a = np.ascontiguousarray(a)
    return a.astype(a.dtype.newbyteorder("<")) if a.dtype.byteorder == ">" else a


def _band(values: np.ndarray, axis: int, lo: int, hi: int) -> np.ndarray:
    """Rows ``lo:hi`` of ``values`` along ``axis``."""
    index = [slice(None)] * values.ndim
    index[axis] = slice(lo, hi)
    return values[tuple(index)]


def _along(axis: int, step) -> tuple:
    """The index taking every ``step``-th element along ``axis``."""
    return (slice(None),) * axis + (slice(None, None, step),)


def manifest_entry(var, each_band=None) -> dict:
    """The manifest entry of one variable: ``{"dims", "shape", "dtype", "crc32"}``.

    Map variables (chunked along ``v``, :func:`facestats.io.layout.map_chunk_rows`)
    also get ``chunk_rows`` and ``chunk_crc32``: the CRC-32 of each band of
    ``chunk_rows`` rows of ``v``, the unit a lazy read verifies.

    A map variable is read band by band (``var[{"v": band}]``), so one left on disk (a lazily read or
    dask-backed variable, e.g. the micro-normals an edit copies from its source) is never whole in memory.
    Its ``crc32`` is that of all its bytes in C order: one running CRC per index of the dims before ``v``
    (the cameras of a micro-normal map), joined with :func:`facestats.core.crc32.crc32_combine`.

    Parameters
    ----------
    var : xarray.Variable
        The variable as it is about to be written (in memory or lazily read).
    each_band : callable, optional
        ``each_band(lo, band)``, called with every band of a map as read (rows ``lo:lo + len`` of ``v``, before its
        checksums are compared with anything): a reader that checks the values too does it on the same read.

    Returns
    -------
    dict
        ``dims`` (list of str), ``shape`` (list of int), ``dtype`` (:func:`digest`'s tag), ``crc32`` (int) and, for a
        non-string map variable, ``chunk_rows`` (int) and ``chunk_crc32`` (list of int, one per band).
    """
    rows = map_chunk_rows(var.dims, var.shape)
    if rows is None or var.dtype.kind in "UOST":
        dtype, crc = digest(np.asarray(var.values))
        return {"dims": list(var.dims), "shape": list(var.shape), "dtype": dtype, "crc32": crc}
    axis = list(var.dims).index("v")
    lead = int(np.prod(var.shape[:axis], dtype=np.int64))
    running, chunks = [0] * lead, []  # 0 = the CRC-32 of no bytes
    for lo in range(0, var.shape[axis], rows):
        band = _little_endian(np.asarray(var[{"v": slice(lo, lo + rows)}].values))
        if each_band is not None:
            each_band(lo, band)
        parts = band.reshape(lead, band.size // max(lead, 1)).view(np.uint8)
        crcs = [zlib.crc32(part) for part in parts]  # every byte once: the band's and the variable's CRC follow
        chunks.append(_joined(crcs, parts.shape[1]))
        running = [crc32_combine(r, c, parts.shape[1]) for r, c in zip(running, crcs)]
    crc = _joined(running, int(np.prod(var.shape[axis:], dtype=np.int64)) * var.dtype.itemsize)
    dtype = digest(np.empty(0, var.dtype))[0]
    return {
        "dims": list(var.dims),
        "shape": list(var.shape),
        "dtype": dtype,
        "crc32": crc,
        "chunk_rows": rows,
        "chunk_crc32": chunks,
    }


def _joined(crcs, length: int) -> int:
    """CRC-32 of the concatenation of parts of ``length`` bytes each whose CRC-32s are ``crcs`` (0 for none)."""
    out = 0
    for c in crcs:
        out = crc32_combine(out, c, length)
    return out


def store_attr_json(generation: str, written: str, manifest: dict) -> str:
    """The value of :data:`STORE_ATTR` for a generation written now by this facestats.

    Parameters
    ----------
    generation : str
        The generation's name.
    written : str
        When it was written (UTC, ISO 8601).
    manifest : dict
        ``{variable: manifest_entry(...)}``.

    Returns
    -------
    str
        JSON of ``{"schema", "facestats_version", "written", "generation", "manifest"}``.
    """
    return json.dumps(
        {
            "schema": SCHEMA_VERSION,
            "facestats_version": __version__,
            "written": written,
            "generation": generation,
            "manifest": manifest,
        }
    )


def open_generation(
    backend,
    sid: str,
    gen: str,
    *,
    label: str,
    lazy: bool = False,
    variables=None,
    check_chunks: bool = False,
    exclude=(),
    on_disk=(),
    banded: bool = False,
):
    """Open and check one generation of a subject.

    Parameters
    ----------
    backend : facestats.io.backends.DirectoryBackend or ZipBackend
        The store's files.
    sid, gen : str
        Subject id and generation.
    label : str
        The store's name in messages.
    lazy : bool
        Check metadata only (dims, shapes, dtypes) and leave variables on disk,
        except ``variables``, which are loaded and verified.
    variables : list of str, optional
        With ``lazy=True``: the variables to load and verify.
    check_chunks : bool
        Also check the per-chunk checksums of the variables loaded against their bytes (``validate``
        and repair: a damaged ``chunk_crc32`` would fail every later lazy read of its band; a full
        read needs no more than each variable's own checksum).
    exclude : sequence of str
        Optional variables to leave out of the Dataset, never read (their metadata are checked).
    on_disk : sequence of str
        With ``lazy=False``: variables to leave on disk as dask arrays of one band of ``chunk_rows`` rows
        per chunk, each band verified when it is computed; they are not validated (whoever writes them
        again validates them).  The others are loaded, verified and validated.  A variable whose
        manifest has no chunk checksums (written by facestats before they existed) is loaded too:
        every band of it would read and verify the whole variable.
    banded : bool
        With ``lazy=False``: check map variables of more than one band of rows without holding them
        (``validate`` and repair, :func:`banded_variables`): each is read once, band by band, for its checksums
        (:func:`manifest_entry`, the write's own computation), and each band as read is handed on: its face
        texels to the schema's map checks (:class:`facestats.io.schema.MapChecks`, passed to
        :func:`facestats.io.schema.validate_subject`) and, for the maps the index row reads
        (:data:`facestats.io.summary.SUMMARY_MAPS`), gathered for it (``ds.encoding[GATHERED_TEXELS]``, which
        :class:`facestats.io.summary.FaceTexels` takes).  The map is then left on disk, wrapped so that any later
        read verifies its bands.  The checks, their order and their messages are those of a full read; memory
        holds one band of such a map at a time (25 MB for the 16 micro-normal cameras of a 2048² subject) and the
        face texels of the index row's maps (72 MB at 2048²), where a full read holds the whole subject.

    Returns
    -------
    xarray.Dataset
        The subject; its bookkeeping (without the manifest) is in ``ds.encoding[STORE_ATTR]``.

    Raises
    ------
    SchemaError
        Missing group, missing or corrupt manifest, a variable that differs
        from it, or (``lazy=False``) a subject that breaks the schema.
    """
    rel = generation_rel(sid, gen)
    ds = _open_group(backend, sid, rel, label)
    manifest = _take_store_attr(ds, sid, rel)
    _check_variables(ds, manifest, sid, rel)
    _check_data_variables(ds, exclude, "exclude")
    _check_data_variables(ds, on_disk, "on_disk")
    left_out = [n for n in exclude if n in ds.data_vars]
    if left_out:
        ds = ds.drop_vars(left_out)
        manifest = {n: m for n, m in manifest.items() if n not in left_out}
    kept = [n for n in on_disk if n in ds.data_vars and manifest[n].get("chunk_crc32") and "v" in ds[n].dims]
    if lazy:  # small, in memory anyway: index coordinates and strings are verified now
        now = set(variables or []) | {n for n, v in ds.variables.items() if n in ds.indexes or v.dtype.kind in "OTUS"}
        check = [n for n in manifest if n in now] + [n for n in (variables or []) if n not in manifest]
    else:
        check = [n for n in manifest if n not in kept]
    streamed = set(banded_variables(ds, manifest)) & set(check) if banded and not lazy else set()
    feed = _BandFeed(ds) if streamed else None
    _verify_checksums(ds, manifest, check, sid, check_chunks, streamed, feed)
    ds = _strings_to_str(ds, set(check) | set(ds.indexes))
    gone = functools.partial(_gone, backend, rel)
    if lazy:
        return _verify_on_read(ds, manifest, set(check), sid, gone)
    ds = _verify_on_read(ds, manifest, set(check) - streamed, sid, gone)  # the streamed and kept variables
    validate_subject(ds.drop_vars(kept), name=sid, checked=feed.checks if feed else None)
    if kept:
        ds = ds.assign({n: ds[n].chunk({"v": manifest[n]["chunk_rows"]}) for n in kept})
    if feed and feed.gathered:
        gathered = {n: (ds.variables[n], t) for n, t in feed.gathered.items()}
        ds.encoding[GATHERED_TEXELS] = {"region": (ds.variables["region"], None), **gathered}
    return ds


def banded_variables(ds, manifest: dict) -> list:
    """The map variables of ``ds`` that ``open_generation(..., banded=True)`` checks band by band.

    Those of more than one band of rows of ``v`` whose manifest has the chunk checksums of the stored layout
    (:func:`facestats.io.layout.map_chunk_rows`), except ``region``: the face mask of every map check is
    loaded whole, once (a 2048² label map is 4 MB), where the schema and the index row would read it again
    and again.  A map of one band (the default store's 48² maps) is loaded as in a full read: streaming it
    would read the same bytes twice.

    Parameters
    ----------
    ds : xarray.Dataset
        The generation as opened (variables on disk).
    manifest : dict
        Its manifest (well formed).

    Returns
    -------
    list of str
    """
    out = []
    for name, var in ds.variables.items():
        m, rows = manifest.get(name, {}), map_chunk_rows(var.dims, var.shape)
        if name == "region" or rows is None or var.dtype.kind in "OTUS" or var.shape[var.dims.index("v")] <= rows:
            continue
        if m.get("chunk_rows") == rows and m.get("chunk_crc32"):
            out.append(name)
    return out


def _check_data_variables(ds, names, argument: str) -> None:
    """:class:`ValidationError` if ``names`` (``exclude``, ``on_disk``) include a coordinate of the subject."""
    coords = [n for n in names if n in ds.coords]
    if coords:
        raise ValidationError(f"{argument} may name data variables only, got the coordinate {coords[0]!r}")


def _gone(backend, rel: str) -> bool:
    """True if the generation ``rel`` is no longer in the store (a writer replaced the subject, or it was deleted)."""
    try:
        return not backend.exists(f"{rel}/zarr.json")
    except OSError:
        return False


def read_failure(exc: BaseException, sid: str, what: str) -> StoreError:
    """The error to raise when reading ``what`` of subject ``sid`` failed with ``exc``.

    An I/O error (other than a missing file or a wrong file type) says nothing
    about the data, so it becomes a plain :class:`StoreError` ("could not be
    read now"); anything else (undecodable bytes, missing chunk files, bad
    metadata) means damaged data and becomes a :class:`SchemaError`.

    Parameters
    ----------
    exc : BaseException
        The exception the read raised.
    sid : str
        The subject id, for the message.
    what : str
        What was being read (e.g. ``"variable 'albedo'"``), for the message.

    Returns
    -------
    StoreError
        A :class:`SchemaError` (a subclass) for damaged data; to be raised by the caller.
    """
    structural = (FileNotFoundError, IsADirectoryError, NotADirectoryError)
    if isinstance(exc, OSError) and not isinstance(exc, structural):
        return StoreError(
            f"subject {sid!r}: {what} could not be read just now ({type(exc).__name__}: {exc}); the data may be "
            "intact, so nothing was changed: check the disk and try again"
        )
    return SchemaError(
        f"subject {sid!r}: {what} cannot be read (truncated or corrupt chunk): {type(exc).__name__}: {exc}"
    )


def _open_group(backend, sid: str, rel: str, label: str):
    """The Zarr group ``rel`` as a lazy Dataset."""
    import xarray as xr

    if not backend.exists(f"{rel}/{ROOT_META}"):
        raise SchemaError(f"subject {sid!r}: group {rel} is missing from store {label}")
    try:
        strange = backend.strange_entry(rel)
    except OSError as exc:
        raise read_failure(exc, sid, f"group {rel}") from None
    if strange is not None:
        raise SchemaError(
            f"subject {sid!r}: {strange} is not a regular file or folder (a FIFO, device or symbolic link); "
            "it was not written by facestats"
        )
    target, group = backend.zarr_target(rel)
    try:
        with warnings.catch_warnings():  # a damaged group: the manifest check names what is missing
            warnings.filterwarnings("ignore", message=".*not recognized as a component of a Zarr hierarchy")
            return xr.open_zarr(target, group=group, consolidated=False, zarr_format=3, chunks=None)
    except Exception as exc:
        err = read_failure(exc, sid, f"group {rel}")
        if isinstance(err, SchemaError):
            err = SchemaError(f"subject {sid!r}: cannot open group {rel}: {type(exc).__name__}: {exc}")
        raise err from None


def _take_store_attr(ds, sid: str, rel: str) -> dict:
    """Move :data:`STORE_ATTR` from ``ds.attrs`` to ``ds.encoding`` (in place) and return its manifest."""
    attrs = dict(ds.attrs)
    raw = attrs.pop(STORE_ATTR, None)
    if raw is None:
        raise SchemaError(f"subject {sid!r}: group {rel} lacks the {STORE_ATTR!r} attribute (not written by facestats)")
    try:
        meta = json.loads(raw)
        manifest = meta["manifest"]
    except (ValueError, KeyError, TypeError):
        raise SchemaError(f"subject {sid!r}: the {STORE_ATTR!r} attribute of {rel} is corrupt") from None
    if meta.get("schema") != SCHEMA_VERSION:
        raise SchemaError(f"subject {sid!r}: schema version {meta.get('schema')!r}, expected {SCHEMA_VERSION}")
    if str(attrs.get("subject_id")) != sid:
        raise SchemaError(f"subject {sid!r}: group {rel} holds subject_id {attrs.get('subject_id')!r}")
    _check_manifest(manifest, sid, rel)
    ds.attrs = attrs
    ds.encoding[STORE_ATTR] = {k: v for k, v in meta.items() if k != "manifest"}
    return manifest


def _is_count(v, low: int = 0, high: int = 2**63 - 1) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and low <= v <= high


def _is_crc(v) -> bool:
    return _is_count(v, 0, 2**32 - 1)


def _show(v) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def manifest_entry_problem(m) -> str | None:
    """What is wrong with one manifest entry (naming the field and the value), or None if it is well formed.

    An entry is ``{"dims": [str], "shape": [int >= 0], "dtype": str, "crc32": int}`` (CRC-32 values are
    integers in [0, 2**32)); a map variable also has ``chunk_rows`` (an integer >= 1) and ``chunk_crc32``
    (one CRC-32 per band of ``chunk_rows`` rows of ``v``), and generations written before chunk
    checksums existed have neither.
    """
    if not isinstance(m, dict):
        return f"the entry must be an object, got {_show(m)}"
    missing = [k for k in ("dims", "shape", "dtype", "crc32") if k not in m]
    if missing:
        return f"field {missing[0]!r} is missing"
    dims, shape = m.get("dims"), m.get("shape")
    if not isinstance(dims, list) or not all(isinstance(d, str) for d in dims):
        return f"field 'dims' must be a list of dimension names, got {_show(dims)}"
    if not isinstance(shape, list) or len(shape) != len(dims) or not all(_is_count(n) for n in shape):
        return f"field 'shape' must be a list of {len(dims)} sizes (integers >= 0), got {_show(shape)}"
    if not isinstance(m.get("dtype"), str):
        return f"field 'dtype' must be a string, got {_show(m.get('dtype'))}"
    if not _is_crc(m.get("crc32")):
        return f"field 'crc32' must be a CRC-32 (an integer in [0, 2**32)), got {_show(m.get('crc32'))}"
    return _chunks_problem(m, dims, shape)


def _chunks_problem(m: dict, dims: list, shape: list) -> str | None:
    """What is wrong with the chunk checksums of a manifest entry with (valid) ``dims`` and ``shape``, or None."""
    rows, crcs = m.get("chunk_rows"), m.get("chunk_crc32")
    if rows is None and crcs is None:
        return None
    if "v" not in dims:
        return f"fields 'chunk_rows' and 'chunk_crc32' belong to map variables (with dimension v), dims are {dims}"
    if not _is_count(rows, 1):
        return f"field 'chunk_rows' must be an integer >= 1, got {_show(rows)}"
    n = -(-shape[dims.index("v")] // rows)
    if not isinstance(crcs, list) or len(crcs) != n:
        return f"field 'chunk_crc32' must be a list of {n} CRC-32 (one per {rows} rows of v), got {_show(crcs)}"
    bad = next((k for k, c in enumerate(crcs) if not _is_crc(c)), None)
    if bad is not None:
        return f"field 'chunk_crc32' must hold CRC-32 (integers in [0, 2**32)), got {_show(crcs[bad])} at [{bad}]"
    return None


def _check_manifest(manifest, sid: str, rel: str) -> None:
    """:class:`SchemaError` naming the file, the variable and the field unless ``manifest`` is well formed."""
    where = f"the manifest in the {STORE_ATTR!r} attribute of {rel}/{ROOT_META}"
    if not isinstance(manifest, dict):
        raise SchemaError(
            f"subject {sid!r}: {where} must be an object of variables, got {_show(manifest)} (damaged or not "
            "written by facestats)"
        )
    for name, m in manifest.items():
        problem = manifest_entry_problem(m)
        if problem:
            raise SchemaError(f"subject {sid!r}: {where}: variable {name!r}: {problem}")


def _check_variables(ds, manifest: dict, sid: str, rel: str) -> None:
    """The variables of ``ds`` are those of the manifest, with its dims, shapes and dtypes."""
    missing = [n for n in manifest if n not in ds.variables]
    if missing:
        raise SchemaError(f"subject {sid!r}: variable(s) {missing} missing from group {rel}")
    extra = [n for n in ds.variables if n not in manifest]
    if extra:
        raise SchemaError(f"subject {sid!r}: unexpected variable(s) {extra} in group {rel}")
    for name, m in manifest.items():
        _check_variable(ds.variables[name], name, m, sid)


def _check_variable(var, name: str, m: dict, sid: str) -> None:
    if list(var.dims) != m["dims"]:
        raise SchemaError(f"subject {sid!r}: variable {name!r} has dims {tuple(var.dims)}, expected {tuple(m['dims'])}")
    if list(var.shape) != m["shape"]:
        raise SchemaError(
            f"subject {sid!r}: variable {name!r} has shape {tuple(var.shape)}, "
            f"expected {tuple(m['shape'])} (truncated array?)"
        )
    dt = "str" if var.dtype.kind in "UOST" else var.dtype.str
    if dt != m["dtype"]:
        raise SchemaError(f"subject {sid!r}: variable {name!r} has dtype {dt}, expected {m['dtype']}")


def _verify_checksums(ds, manifest: dict, names, sid: str, chunks: bool = False, streamed=(), feed=None) -> None:
    """Load the variables ``names`` and compare their CRC-32 with the manifest (and, with ``chunks``, each chunk's).

    The variables ``streamed`` are not loaded but read band by band (:func:`_verify_bands`), each band handed to
    ``feed`` (a :class:`_BandFeed`) as read.  With ``feed``, the maps whose face texels it gathers for the index row
    are read last (:meth:`_BandFeed.gathers`: they are not held while the other large maps are read); the error
    raised is still the first in the order of ``names``, as a full read raises it: when a variable fails, those
    before it not yet checked are checked first.
    """
    names = list(names)
    order = (
        names
        if feed is None
        else [n for n in names if not feed.gathers(n, streamed)] + [n for n in names if feed.gathers(n, streamed)]
    )
    done = set()
    for name in order:
        try:
            _verify_one(ds, manifest, name, sid, chunks, streamed, feed)
        except StoreError:
            for earlier in names[: names.index(name)]:
                if earlier not in done:
                    _verify_one(ds, manifest, earlier, sid, chunks, streamed, None)
            raise
        done.add(name)


def _verify_one(ds, manifest: dict, name: str, sid: str, chunks: bool, streamed, feed) -> None:
    """:func:`_verify_checksums` of one variable."""
    if name not in manifest:
        raise SchemaError(f"subject {sid!r}: no variable {name!r}")
    var = ds.variables[name]
    if name in streamed:
        _verify_bands(var, manifest[name], sid, name, chunks, feed.consumer(name, var) if feed else None)
        return
    try:
        var.load()
    except Exception as exc:
        raise read_failure(exc, sid, f"variable {name!r}") from None
    if digest(var.values)[1] != manifest[name]["crc32"]:
        raise _checksum_error(sid, name)
    if chunks:
        _verify_chunk_checksums(var, manifest[name], sid, name)


def _checksum_error(sid: str, name: str) -> SchemaError:
    """The error of a variable whose bytes do not match its CRC-32."""
    return SchemaError(
        f"subject {sid!r}: variable {name!r} does not match its checksum "
        "(a chunk file is missing, truncated or altered)"
    )


def _verify_bands(var, m: dict, sid: str, name: str, chunks: bool, each_band=None) -> None:
    """The CRC-32 of a map variable left on disk (and, with ``chunks``, of each band), one band read at a time.

    The CRCs are computed as the write computed them (:func:`manifest_entry`), so the variable's checksum is
    compared first and the chunk checksums after, as for a loaded variable.  ``each_band(lo, band)`` gets every band
    as read (it raises nothing: :meth:`_BandFeed.consumer`).
    """
    try:
        found = manifest_entry(var, each_band)
    except Exception as exc:
        raise read_failure(exc, sid, f"variable {name!r}") from None
    if found["crc32"] != m["crc32"]:
        raise _checksum_error(sid, name)
    if chunks:
        _compare_chunk_checksums(found["chunk_crc32"], m, var.shape[list(var.dims).index("v")], sid, name)


def _verify_chunk_checksums(var, m: dict, sid: str, name: str) -> None:
    """The chunk checksums of a loaded (and whole-checksum verified) map variable agree with its bytes."""
    crcs = m.get("chunk_crc32")
    if not crcs or "v" not in var.dims:
        return
    rows, axis, values = int(m["chunk_rows"]), list(var.dims).index("v"), np.asarray(var.values)
    found = [digest(_band(values, axis, lo, lo + rows))[1] for lo in range(0, values.shape[axis], rows)]
    _compare_chunk_checksums(found, m, values.shape[axis], sid, name)


def _compare_chunk_checksums(found, m: dict, n: int, sid: str, name: str) -> None:
    """The CRC-32 ``found`` of the bands of ``chunk_rows`` rows of a variable with ``n`` rows of ``v`` are those of
    its manifest entry ``m``.

    The whole variable matched its CRC-32, so a chunk checksum that disagrees is a damaged manifest,
    on which every lazy read of that band would fail: damage, named here (the first such band).
    """
    rows = int(m["chunk_rows"])
    for j, (crc, expected) in enumerate(zip(found, m["chunk_crc32"])):
        if crc != expected:
            lo = j * rows
            raise SchemaError(
                f"subject {sid!r}: variable {name!r}: chunk_crc32[{j}] of its manifest (rows {lo}-"
                f"{min(lo + rows, n) - 1} of v) does not match the data, which match the "
                "variable's checksum: the manifest is damaged"
            )


class _BandFeed:
    """Where the checksum pass of ``open_generation(..., banded=True)`` hands the bands of the large maps it reads.

    The face texels of each band go to the schema's map checks (:attr:`checks`, a
    :class:`facestats.io.schema.MapChecks`) and, for the maps of :data:`facestats.io.summary.SUMMARY_MAPS`, are
    gathered for the index row (:attr:`gathered`, ``{name: (texels, *other dims)}``), so that neither reads the map
    again.  Nothing is fed unless the subject is a map subject whose ``region`` (dims ``v``, ``u``) can be loaded
    before the first large map (at construction); a variable whose feeding failed is left out of both (the schema
    and the index row read it themselves, with the messages of a full read).

    Parameters
    ----------
    ds : xarray.Dataset
        The generation as opened (variables on disk).
    """

    def __init__(self, ds):
        self.ds = ds
        self.checks: MapChecks | None = None
        self.gathered: dict = {}
        self._start()

    def gathers(self, name: str, streamed) -> bool:
        """True if the face texels of variable ``name`` (read band by band if in ``streamed``) are gathered."""
        return self.checks is not None and name in streamed and name in SUMMARY_MAPS and "u" in self.ds[name].dims

    def _start(self) -> None:
        """Load the face mask (``region``, verified later in its own turn), if the subject has one."""
        try:
            if subject_kind(self.ds) != "maps" or tuple(self.ds.variables["region"].dims) != ("v", "u"):
                return
            region = self.ds.variables["region"]
            region.load()
            self.checks = MapChecks(np.asarray(region.values) > 0)
        except Exception:  # the schema or the checksum pass names what is wrong, in their order
            self.checks = None

    def consumer(self, name: str, var):
        """``each_band(lo, band)`` feeding the bands of map variable ``name`` (None if nothing wants them)."""
        dims = tuple(var.dims)
        check = self.checks is not None and MapChecks.wants(name, dims)
        gather = self.gathers(name, {name})
        if not (check or gather):
            return None
        face, axis, n = self.checks.face, dims.index("v"), int(np.count_nonzero(self.checks.face))
        state = {"ok": True, "at": 0}

        def each_band(lo: int, band) -> None:
            if not state["ok"]:
                return
            try:
                texels = face_texels(band, dims, face[lo : lo + band.shape[axis]])
                if check:
                    self.checks.add(name, texels)
                if gather:
                    if name not in self.gathered:
                        self.gathered[name] = np.empty((n, *texels.shape[1:]), texels.dtype)
                    self.gathered[name][state["at"] : state["at"] + len(texels)] = texels
                    state["at"] += len(texels)
            except Exception:  # not read here after all: the schema and the index row read it (full-read messages)
                state["ok"] = False
                self.checks.found.pop(name, None)
                self.gathered.pop(name, None)

        return each_band


def _strings_to_str(ds, names):
    """Turn string variables read back from Zarr (StringDType/object) into numpy ``str`` arrays."""
    coords, data = {}, {}
    for name in names:
        var = ds.variables[name]
        if var.dtype.kind in "OT":
            new = var.copy(data=np.asarray(var.values).astype(object).astype(str))  # a Variable: no old coords
            (coords if name in ds.coords else data)[name] = new
    ds = ds.assign_coords(coords) if coords else ds  # one call each: every call rebuilds the indexes
    return ds.assign(data) if data else ds


def _verify_on_read(ds, manifest: dict, verified: set, sid: str, gone=lambda: False):
    """``ds`` with every variable not in ``verified`` wrapped so that its chunks are verified as they are read.

    ``gone()`` tells whether the generation has left the store since (then a failed read is no damage).
    """
    import xarray as xr
    from xarray.core import indexing

    coords, data = {}, {}
    for name, var in ds.variables.items():
        if name in verified:
            continue
        lazy = indexing.LazilyIndexedArray(_verified_chunks_class()(var, manifest[name], sid, name, gone))
        new = xr.Variable(var.dims, lazy, var.attrs, var.encoding)
        (coords if name in ds.coords else data)[name] = new
    out = ds.assign_coords(coords) if coords else ds
    return out.assign(data) if data else out


@functools.cache
def _verified_chunks_class():
    """:class:`_VerifiedChunks` as an :class:`xarray.backends.BackendArray` (built on first use: xarray loads late)."""
    from xarray.backends import BackendArray

    return type("VerifiedChunks", (_VerifiedChunks, BackendArray), {})


class _VerifiedChunks:
    """A variable left on disk whose chunks are CRC-checked against the manifest each time they are read.

    Indexing (basic: integers and slices per dim) loads the whole chunks of
    ``v`` the request touches through the unverified lazy variable, checks
    each against its ``chunk_crc32`` entry, then cuts the request out of them.
    Without chunk checksums (older generations, variables without ``v``) the
    variable is one chunk checked against its ``crc32``.  Raises
    :class:`SchemaError` (damaged) or :class:`StoreError` (I/O, or a
    generation that ``gone()`` says has left the store since it was opened:
    replaced by a writer or deleted, the data were not damaged) naming the
    subject, the variable and the rows.
    """

    def __init__(self, raw, entry: dict, sid: str, name: str, gone=lambda: False):
        self.raw, self.sid, self.name, self.gone = raw, sid, name, gone
        self.shape, self.dtype = tuple(raw.shape), raw.dtype
        dims = list(raw.dims)
        rows, crcs = entry.get("chunk_rows"), entry.get("chunk_crc32")
        n = self.shape[dims.index("v")] if "v" in dims else 0
        if rows and crcs and "v" in dims and len(crcs) == -(-n // int(rows)):
            self.axis, self.rows, self.crcs = dims.index("v"), int(rows), [int(c) for c in crcs]
        else:
            self.axis, self.rows, self.crcs = None, None, [int(entry["crc32"])]

    def __getitem__(self, key):
        from xarray.core import indexing

        return indexing.explicit_indexing_adapter(key, self.shape, indexing.IndexingSupport.BASIC, self._basic)

    def _basic(self, key: tuple):
        if self.axis is None:
            return self._load(None)[key]
        k, n = key[self.axis], self.shape[self.axis]
        idx = np.arange(n)[k] if isinstance(k, slice) else np.array([int(k) % n])
        if idx.size == 0:
            return np.empty(self.shape, self.dtype)[key] if np.prod(self.shape) == 0 else self._empty(key)
        lo = int(idx.min()) // self.rows * self.rows
        hi = min((int(idx.max()) // self.rows + 1) * self.rows, n)
        band = self._load((lo, hi))
        if isinstance(k, slice) and (k.step or 1) > 0:  # a view: np.take copied a whole variable read at once
            band = _band(band, self.axis, int(idx[0]) - lo, int(idx[-1]) - lo + 1)[_along(self.axis, k.step)]
        else:
            band = np.take(band, idx - lo, axis=self.axis)
        rest = list(key)
        rest[self.axis] = slice(None) if isinstance(k, slice) else 0
        return band[tuple(rest)]

    def _empty(self, key: tuple):
        """The (empty) result of a request selecting no row of ``v``."""
        shape = list(self.shape)
        shape[self.axis] = 0
        return np.empty(shape, self.dtype)[key]

    def _load(self, rows):
        """Rows ``lo:hi`` of ``v`` (all of the variable for None), every chunk in them verified."""
        what = f"variable {self.name!r}" + ("" if rows is None else f" (rows {rows[0]}-{rows[1] - 1} of v)")
        try:
            part = self.raw if rows is None else self.raw.isel(v=slice(*rows))
            values = np.asarray(part.values)
        except Exception as exc:
            raise self._replaced(what) or read_failure(exc, self.sid, what) from None
        if rows is None:
            bad = [0] if digest(values)[1] != self.crcs[0] else []
        else:
            first = rows[0] // self.rows
            bad = [
                j
                for j, lo in enumerate(range(0, values.shape[self.axis], self.rows), start=first)
                if digest(_band(values, self.axis, lo, lo + self.rows))[1] != self.crcs[j]
            ]
        if bad:
            where = "" if rows is None else f", chunk(s) {bad} of {self.rows} rows of v"
            replaced = self._replaced(what)
            if replaced:
                raise replaced
            raise SchemaError(
                f"subject {self.sid!r}: variable {self.name!r} does not match its checksum{where} "
                "(a chunk file is missing, truncated or altered)"
            )
        return values

    def _replaced(self, what: str) -> StoreError | None:
        """The :class:`StoreError` of a read that failed because the generation left the store, else None."""
        if not self.gone():
            return None
        return StoreError(
            f"subject {self.sid!r}: {what} cannot be read: the subject was replaced or deleted in the store after "
            "this lazy read opened it (its data were not damaged); read the subject again"
        )
