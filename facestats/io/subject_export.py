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
import secrets
import shutil
import socket
import stat

from facestats.core.outputs import check_apart, check_output_dir, missing_folders
from facestats.core.processes import process_gone
from facestats.core.validate import check_choice
from facestats.errors import StoreError, ValidationError
from facestats.io.gltf import write_gltf
from facestats.io.ids import check_subject_id
from facestats.io.mesh import check_mesh_scale
from facestats.io.store import Store, open_store

__all__ = ["EXPORT_FORMATS", "EXPORT_OPTIONS", "UnknownSubjectError", "export_subject", "store_subject"]

EXPORT_FORMATS = ("exr", "mitsuba", "gltf")
#: The formats each option of :func:`export_subject` applies to.
EXPORT_OPTIONS = {
    "mesh": EXPORT_FORMATS,
    "mesh_scale": EXPORT_FORMATS,
    "mesh_format": ("exr", "mitsuba"),
    "probe": ("mitsuba",),
    "material": ("mitsuba",),
    "width": ("mitsuba",),
    "height": ("mitsuba",),
    "spp": ("mitsuba",),
    "fov": ("mitsuba",),
}
#: Options that name input files (refused inside ``out``, which an export may replace).
_INPUTS = ("mesh", "probe")


def store_subject(store, subject_id, *, lazy: bool = False):
    """``store.subject(id, lazy=lazy)`` after checking the id (:func:`facestats.io.ids.check_subject_id`) and its
    presence.

    Parameters
    ----------
    store : facestats.io.store.Store
        An open store.
    subject_id : str
        The subject's id.
    lazy : bool
        Passed to :meth:`facestats.io.store.Store.subject`.

    Returns
    -------
    xarray.Dataset
        The subject.

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
    return store.subject(sid, lazy=lazy)


class UnknownSubjectError(StoreError):
    """A subject id that the store does not hold."""


def _write(fmt, ds, tmp, options):
    if options.get("mesh") is not None and options.get("mesh_scale") is not None:  # a scan in another unit than mm
        from facestats.io.mesh import subject_mesh

        options = dict(options, mesh=subject_mesh(ds, options["mesh"], scale=options["mesh_scale"]))
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
            mesh=options.get("mesh"), mesh_format=options.get("mesh_format", "obj"), **view,
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
        :data:`EXPORT_OPTIONS`: ``mesh`` (scan path; every format), ``mesh_scale`` (factor from the scan's
        unit to mm, default 1), ``mesh_format`` (``obj``/``ply`` for
        ``exr``; only ``obj`` for ``mitsuba``), ``probe``, ``material``, ``width``, ``height``, ``spp``,
        ``fov`` (``mitsuba``).  An option of None is not given.

    Returns
    -------
    dict
        ``subject_id``, ``format``, ``out`` and ``files`` (sorted names).

    Raises
    ------
    ValidationError
        Before anything is written: an unknown option, an option that does not apply to ``format``, an input
        file (``mesh``, ``probe``) inside ``out`` (``overwrite`` would delete it), a non-empty ``out`` without
        ``overwrite``, a region-sample subject.
    UnknownSubjectError
        An id the store does not hold.
    """
    check_choice(format, "format", EXPORT_FORMATS)
    options = _check_options(format, options)
    if "mesh_scale" in options:
        options["mesh_scale"] = check_mesh_scale(options["mesh_scale"], options.get("mesh"))
    out = _check_out(out, overwrite)
    for name in _INPUTS:
        if isinstance(options.get(name), (str, os.PathLike)):
            check_apart(options[name], out, name, "out")
    if hasattr(subject, "data_vars"):
        ds = subject
    elif isinstance(store, Store):
        check_apart(out, store.path, replaced=True)
        ds = store_subject(store, subject)
    else:
        with open_store(store) as st:
            check_apart(out, st.path, replaced=True)
            ds = store_subject(st, subject)
    parent = os.path.dirname(out)
    _remove_stale_temporaries(parent, os.path.basename(out))
    created = missing_folders(parent)
    os.makedirs(parent, exist_ok=True)
    tmp = os.path.join(parent, f"{_temp_prefix(os.path.basename(out))}{os.getpid()}-{secrets.token_hex(4)}")
    try:
        os.mkdir(tmp, 0o755)
        _write(format, ds, tmp, options)
        files = sorted(os.listdir(tmp))
        _place(tmp, out, overwrite)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        for d in created:  # innermost first: the folders this export created for nothing
            try:
                os.rmdir(d)
            except OSError:
                pass
        raise
    return {"subject_id": str(ds.attrs.get("subject_id", "")), "format": format, "out": out, "files": files}


def _check_options(format, options) -> dict:
    """The options given (not None), each known (:data:`EXPORT_OPTIONS`) and applying to ``format``."""
    given = {k: v for k, v in options.items() if v is not None}
    unknown = [k for k in given if k not in EXPORT_OPTIONS]
    if unknown:
        raise ValidationError(f"export options must be among {list(EXPORT_OPTIONS)}, got {unknown}")
    foreign = [k for k in given if format not in EXPORT_OPTIONS[k]]
    if foreign:
        described = (
            f"{k}={given[k]!r} (--{k.replace('_', '-')} applies to {' and '.join(EXPORT_OPTIONS[k])} only)"
            for k in foreign
        )
        raise ValidationError(f"options given that do not apply to format {format!r}: {', '.join(described)}")
    return given


def _check_out(out, overwrite):
    """``out`` as an absolute path: a directory or creatable path, not a link, empty unless ``overwrite``."""
    path = os.path.abspath(check_output_dir(out, "out"))
    if os.path.islink(path):
        raise ValidationError(f"out must not be a symbolic link (it would be replaced by a directory), got {path!r}")
    if os.path.isdir(path) and os.listdir(path) and not overwrite:
        raise ValidationError(f"out directory {path!r} is not empty (pass overwrite=True / --overwrite to replace it)")
    return path


def _temp_prefix(name):
    """``.NAME.export-HOST-``: the start of this machine's temporary folders for an export to ``NAME``.

    NAME is cut to its first 100 bytes (at a character boundary), so that the temporary's name
    (``.NAME.export-HOST-PID-XXXXXXXX.old`` at most) stays within the 255 bytes a file name may hold when
    ``out``'s own name does.
    """
    host = "".join(c if c.isalnum() else "_" for c in socket.gethostname())[:40] or "host"
    short = os.fsencode(name)[:100].decode(errors="ignore") if len(os.fsencode(name)) > 100 else name
    return f".{short}.export-{host}-"


def _remove_stale_temporaries(parent, name):
    """Remove this machine's ``.NAME.export-HOST-PID-*`` folders whose process is gone (an export killed mid-way).

    Another machine's temporaries (a shared folder) and ``*.old`` folders (a previous export being replaced)
    are never touched.
    """
    if not os.path.isdir(parent):
        return
    prefix = _temp_prefix(name)
    for entry in os.listdir(parent):
        if not entry.startswith(prefix) or entry.endswith(".old"):
            continue
        pid = entry[len(prefix) :].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and process_gone(int(pid)):
            shutil.rmtree(os.path.join(parent, entry), ignore_errors=True)


def _place(tmp, out, overwrite):
    """Rename the finished export ``tmp`` to ``out``, checking ``out`` again (it may have appeared meanwhile).

    A folder that ``out`` replaces (empty, or any with ``overwrite``) passes its permission bits on, so that a
    private folder the user prepared (0700) does not become world-readable.
    """
    if os.path.islink(out) or (os.path.lexists(out) and not os.path.isdir(out)):
        raise ValidationError(f"out {out!r} was replaced by a file or link during the export; nothing was written")
    if os.path.isdir(out):
        os.chmod(tmp, stat.S_IMODE(os.stat(out).st_mode))
    if os.path.isdir(out) and os.listdir(out):
        if not overwrite:
            raise ValidationError(f"out directory {out!r} was filled during the export; nothing was written")
        old = tmp + ".old"
        os.replace(out, old)
        try:
            os.replace(tmp, out)
        except BaseException:
            os.replace(old, out)  # the previous export comes back
            raise
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, out)  # onto an empty folder, or a new name
