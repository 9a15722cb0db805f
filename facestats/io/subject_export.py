"""One subject out to a renderer: the EXR texture set, a Mitsuba 3 scene or a glTF 2.0 asset, written atomically.

:func:`export_subject` is what ``facestats export-subject`` and the web app's
download call.  The output directory appears whole or not at all: everything
is written into a temporary sibling directory that is renamed into place at
the end, so a failed export (bad argument, missing optional dependency, full
disk) leaves nothing behind, and an existing directory is replaced only with
``overwrite=True`` (and only once the new export is complete).
"""

from __future__ import annotations

import os
import shutil
import tempfile

from facestats.core.validate import check_choice
from facestats.errors import StoreError, ValidationError
from facestats.io.gltf import write_gltf
from facestats.io.ids import check_subject_id
from facestats.io.store import Store, open_store

__all__ = ["EXPORT_FORMATS", "UnknownSubjectError", "export_subject", "store_subject"]

EXPORT_FORMATS = ("exr", "mitsuba", "gltf")


def _dataset(subject, store):
    """The subject Dataset: given, or read (fully verified) from ``store`` (a Store, a path or None = default)."""
    if hasattr(subject, "data_vars"):
        return subject

    if isinstance(store, Store):
        return store_subject(store, subject)
    with open_store(store) as st:
        return store_subject(st, subject)


def store_subject(store, subject_id):
    """``store.subject(id)`` after checking the id (:func:`facestats.io.ids.check_subject_id`) and its presence.

    Raises
    ------
    ValidationError
        A malformed id (never used in a path).
    UnknownSubjectError
        An id the store does not hold (the message the CLI prints and the web app returns with 404).
    """

    sid = check_subject_id(subject_id)
    if sid not in store:
        raise UnknownSubjectError(f"subject {sid!r} is not in store {store.label} ({len(store)} subjects)")
    return store.subject(sid)


class UnknownSubjectError(StoreError):
    """A subject id that the store does not hold."""


def _write(fmt, ds, tmp, options):
    if fmt == "exr":
        # local import: keeps facestats.acquire (5 modules) out of this module's import
        from facestats.io.exr_set import write_exr_set

        write_exr_set(ds, tmp, mesh=options.get("mesh"), mesh_format=options.get("mesh_format", "obj"))
    elif fmt == "mitsuba":
        # local import: keeps 8 modules out of this module's import
        from facestats.io.mitsuba import write_mitsuba_scene

        view = {k: options[k] for k in ("width", "height", "spp", "fov") if options.get(k) is not None}
        write_mitsuba_scene(
            ds, tmp, probe=options.get("probe"), material=options.get("material", "surface"),
            mesh=options.get("mesh"), **view,
        )  # fmt: skip
    else:
        write_gltf(ds, tmp, mesh=options.get("mesh"))


def export_subject(subject, out, format="exr", *, store=None, overwrite=False, **options):
    """Export one map subject for a renderer into the directory ``out``.

    Parameters
    ----------
    subject : str or xarray.Dataset
        A subject id (read from ``store``) or a subject Dataset.
    out : str or os.PathLike
        Output directory; must not exist (or be empty) unless ``overwrite``.
    format : {"exr", "mitsuba", "gltf"}
        ``exr``: :func:`facestats.io.exr_set.write_exr_set`; ``mitsuba``:
        :func:`facestats.io.mitsuba.write_mitsuba_scene` (the EXR set plus the
        scene); ``gltf``: :func:`facestats.io.gltf.write_gltf`.
    store : Store, str, os.PathLike or None
        Where to read an id from (None: the embedded default).
    overwrite : bool
        Replace an existing non-empty ``out``.
    **options
        ``mesh`` (scan path), ``mesh_format`` (``obj``/``ply``, EXR set),
        ``probe``, ``material``, ``width``, ``height``, ``spp``, ``fov`` (Mitsuba).

    Returns
    -------
    dict
        ``subject_id``, ``format``, ``out`` and ``files`` (sorted names).
    """
    check_choice(format, "format", EXPORT_FORMATS)
    out = os.path.abspath(os.fspath(out))
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValidationError(f"out must be a directory, got the file {out!r}")
    if os.path.isdir(out) and os.listdir(out) and not overwrite:
        raise ValidationError(f"out directory {out!r} is not empty (pass overwrite=True / --overwrite to replace it)")
    ds = _dataset(subject, store)
    parent = os.path.dirname(out)
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=f".{os.path.basename(out)}-", dir=parent)
    try:
        os.chmod(tmp, 0o755)  # mkdtemp makes it private; the export is an ordinary directory
        _write(format, ds, tmp, options)
        files = sorted(os.listdir(tmp))
        if os.path.isdir(out):
            old = tmp + ".old"
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return {"subject_id": str(ds.attrs.get("subject_id", "")), "format": format, "out": out, "files": files}
