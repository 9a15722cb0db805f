"""Integrity of stored subjects: the manifest written with each generation, and the checked read of one.

Every subject group carries one bookkeeping attribute, :data:`STORE_ATTR`
(JSON: schema version, writer version, write time, generation and a
*manifest* of every variable's dims, shape, dtype and CRC-32 of its bytes).
:func:`open_generation` reads a generation back and checks it: the group
must exist, carry the manifest, have the recorded variables with the recorded
dims, shapes and dtypes, and (unless ``lazy=True``) bytes whose CRC-32 matches
(a deleted chunk file would otherwise read silently as fill values); finally
:func:`facestats.io.schema.validate_subject` runs.  Problems raise
:class:`~facestats.errors.SchemaError` naming the subject and the variable.

xarray is imported when a generation is opened, not with this module.
"""

from __future__ import annotations

import json
import zlib

import numpy as np

from facestats.core.version import __version__
from facestats.errors import SchemaError
from facestats.io.layout import ROOT_META, generation_rel
from facestats.io.schema import SCHEMA_VERSION, validate_subject

__all__ = ["STORE_ATTR", "digest", "manifest_entry", "store_attr_json", "open_generation"]

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
    a = np.ascontiguousarray(a)
    if a.dtype.byteorder == ">":
        a = a.astype(a.dtype.newbyteorder("<"))
    return a.dtype.str, zlib.crc32(a.reshape(-1).view(np.uint8))


def manifest_entry(var) -> dict:
    """The manifest entry of one variable: ``{"dims", "shape", "dtype", "crc32"}``."""
    dtype, crc = digest(var.values)
    return {"dims": list(var.dims), "shape": list(var.shape), "dtype": dtype, "crc32": crc}


def store_attr_json(generation: str, written: str, manifest: dict) -> str:
    """The value of :data:`STORE_ATTR` for a generation written now by this facestats."""
    return json.dumps(
        {
            "schema": SCHEMA_VERSION,
            "facestats_version": __version__,
            "written": written,
            "generation": generation,
            "manifest": manifest,
        }
    )


def open_generation(backend, sid: str, gen: str, *, label: str, lazy: bool = False, variables=None):
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
    check = list(manifest) if not lazy else list(variables or [])
    _verify_checksums(ds, manifest, check, sid)
    ds = _strings_to_str(ds, set(check) | set(ds.indexes))
    if not lazy:
        validate_subject(ds, name=sid)
    return ds


def _open_group(backend, sid: str, rel: str, label: str):
    """The Zarr group ``rel`` as a lazy Dataset."""
    import xarray as xr

    if not backend.exists(f"{rel}/{ROOT_META}"):
        raise SchemaError(f"subject {sid!r}: group {rel} is missing from store {label}")
    target, group = backend.zarr_target(rel)
    try:
        return xr.open_zarr(target, group=group, consolidated=False, zarr_format=3, chunks=None)
    except Exception as exc:
        raise SchemaError(f"subject {sid!r}: cannot open group {rel}: {type(exc).__name__}: {exc}") from None


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
    ds.attrs = attrs
    ds.encoding[STORE_ATTR] = {k: v for k, v in meta.items() if k != "manifest"}
    return manifest


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


def _verify_checksums(ds, manifest: dict, names, sid: str) -> None:
    """Load the variables ``names`` and compare their CRC-32 with the manifest."""
    for name in names:
        if name not in manifest:
            raise SchemaError(f"subject {sid!r}: no variable {name!r}")
        var = ds.variables[name]
        try:
            var.load()
        except Exception as exc:
            raise SchemaError(
                f"subject {sid!r}: variable {name!r} cannot be read (truncated or corrupt chunk): "
                f"{type(exc).__name__}: {exc}"
            ) from None
        if digest(var.values)[1] != manifest[name]["crc32"]:
            raise SchemaError(
                f"subject {sid!r}: variable {name!r} does not match its checksum "
                "(a chunk file is missing, truncated or altered)"
            )


def _strings_to_str(ds, names):
    """Turn string variables read back from Zarr (StringDType/object) into numpy ``str`` arrays."""
    for name in names:
        var = ds.variables[name]
        if var.dtype.kind in "OT":
            new = ds[name].copy(data=np.asarray(var.values).astype(object).astype(str))
            ds = ds.assign_coords({name: new}) if name in ds.coords else ds.assign({name: new})
    return ds
