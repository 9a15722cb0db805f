"""A folder of dome photographs to a fitted subject in a store: ingest (acquire stage), fit, write.

:func:`ingest_subject` chains :func:`facestats.acquire.ingest.ingest_photographs`
(photographs → capture on disk, resumable), :func:`facestats.pipeline.fit_subject`
(Weyrich et al. 2006 §5.1-5.4) and :meth:`Store.write_subject` (atomic).  The
subject reaches the store only after the whole capture is ingested and fitted:
an interrupted run leaves a partial capture in the work directory, never a
subject, and rerunning the same command resumes at the first unfinished camera.

A run that fails leaves no side effects: every argument and input (subject id,
options, the store and work paths, the mesh and its region image, the
calibration, the photo folder's manifest) is checked before anything is
created, and an error after that removes the store and the work folders the
run created (a store only while it is still empty).  Only an interruption
(Ctrl-C, a signal) keeps them, with the partial capture, for the next run to resume.
"""

from __future__ import annotations

import contextlib
import json
import os
import pathlib
import shutil
import stat
from dataclasses import dataclass, field

from facestats.acquire.dome import Dome
from facestats.acquire.ingest import (
    MIN_FOOTPRINT_PX,
    MOTION_TOLERANCE,
    footprint_note,
    ingest_photographs,
    open_ingested,
)
from facestats.acquire.photographs import open_folder
from facestats.core.outputs import check_output_dir
from facestats.core.validate import as_scalar, check_integer
from facestats.errors import FitError, FormatError, ValidationError
from facestats.io import open_store
from facestats.io.ids import check_subject_id
from facestats.io.layout import ROOT_META
from facestats.io.mesh import load_face_mesh
from facestats.io.root import new_store_guard
from facestats.pipeline.subject import fit_subject

__all__ = ["ingest_subject", "IngestReport", "default_work_path", "find_region_image"]


@dataclass
class IngestReport:
    """What :func:`ingest_subject` did.

    Attributes
    ----------
    subject_id : str
        The subject's id in the store.
    store : str
        The store directory.
    capture : str
        The capture's path (the work path; empty when skipped).
    n_lumitexels : int
        Lumitexels of the capture.
    samples_used : int
        Samples the fit used (the provenance's ``counts``).
    motion_flags : list of dict
        Frames flagged for head motion (``camera``, ``led``, ``score``; the capture's provenance).
    skipped : bool
        The store already held the subject: nothing was done.
    """

    subject_id: str
    store: str
    capture: str
    n_lumitexels: int = 0
    samples_used: int = 0
    motion_flags: list = field(default_factory=list)
    skipped: bool = False

    def to_text(self) -> str:
        """What the ingest did, as the lines ``facestats ingest`` prints."""
        if self.skipped:
            return f"{self.subject_id} is already in {self.store}: nothing to do"
        lines = [
            f"ingested {self.subject_id} into {self.store}",
            f"  capture: {self.capture} ({self.n_lumitexels} lumitexels, {self.samples_used} samples used)",
            f"  frames flagged for head motion: {len(self.motion_flags)}",
        ]
        lines += [f"    camera {f['camera']}, LED {f['led']}: score {f['score']}" for f in self.motion_flags[:10]]
        return "\n".join(lines)


def default_work_path(store, subject_id) -> pathlib.Path:
    """Where the capture of an ingest is kept by default: ``<store>.ingest/<subject_id>/capture.zarr``.

    Parameters
    ----------
    store : str or os.PathLike
        The store the ingest writes to.
    subject_id : str
        The subject's id.

    Returns
    -------
    pathlib.Path
        The capture's path beside the store (nothing is created).
    """
    s = pathlib.Path(store)
    return s.with_name(s.name + ".ingest") / str(subject_id) / "capture.zarr"


def find_region_image(mesh) -> pathlib.Path:
    """The face-region image next to a mesh: ``<stem>.regions.png``, ``<stem>.regions.npy`` or ``<stem>.regions.tif``.

    Parameters
    ----------
    mesh : str or os.PathLike
        The face mesh's file.

    Returns
    -------
    pathlib.Path
        The first of the three that is a file, in that order.

    Raises
    ------
    FormatError
        None of them is there.
    """
    m = pathlib.Path(mesh)
    candidates = [m.with_name(f"{m.stem}.regions{ext}") for ext in (".png", ".npy", ".tif")]
    for c in candidates:
        if c.is_file():
            return c
    raise FormatError(
        f"mesh {m} has no face-region image (looked for {', '.join(c.name for c in candidates)}); "
        "pass the label image of the face regions explicitly"
    )


def ingest_subject(
    photo_dir,
    mesh,
    calibration,
    store,
    subject_id: str,
    *,
    regions=None,
    work=None,
    sigma_tr_avg=None,
    settings=None,
    workers: int = 2,
    motion_tolerance: float | None = None,
    min_footprint_px: float | None = None,
    progress: bool = False,
) -> IngestReport:
    """Photographs → capture → fit → store (module docstring).

    Parameters
    ----------
    photo_dir : path
        A capture folder (:mod:`facestats.acquire.photographs`).
    mesh : path
        The face mesh (OBJ/PLY with UVs, mm, world frame; :func:`facestats.io.mesh.load_face_mesh`).
    calibration : path
        The dome calibration JSON (:meth:`facestats.acquire.dome.Dome.load`).
    store : path
        Directory store, created if missing (after the inputs are checked).
    subject_id : str
        The subject's id in the store (overrides the manifest's).
    regions : path, optional
        Face-region label image; default :func:`find_region_image` of ``mesh``.
    work : path, optional
        Where the capture is written (default :func:`default_work_path`).
    sigma_tr_avg, settings
        As :func:`facestats.pipeline.fit_subject`.
    workers : int
        Threads decoding frames.
    motion_tolerance : float, optional
        Head-motion threshold (default :data:`facestats.acquire.ingest.MOTION_TOLERANCE`).
    min_footprint_px : float, optional
        Resolution limit of a sample (default :data:`facestats.acquire.ingest.MIN_FOOTPRINT_PX`).
    progress : bool
        Progress bars.

    Returns
    -------
    IngestReport

    Raises
    ------
    ValidationError
        An argument out of its domain or an unusable store or work path, before anything is created.
    FormatError
        The mesh, its region image, the calibration or the photo folder cannot be read (before anything
        is created), or a frame is corrupt (the store and work folders this call created are removed).
    FitError, ValidationError
        The capture leaves too few samples to fit (:func:`facestats.pipeline.fit_subject`); the message adds how
        many the footprint rule dropped (:func:`facestats.acquire.ingest.footprint_note`), and the folders this call
        created are removed.
    """

    sid = check_subject_id(subject_id)
    workers = check_integer(workers, "workers", 1)
    if motion_tolerance is None:
        motion_tolerance = MOTION_TOLERANCE
    motion_tolerance = as_scalar(motion_tolerance, "motion_tolerance", 0, None, low_inclusive=False)
    if min_footprint_px is None:
        min_footprint_px = MIN_FOOTPRINT_PX
    min_footprint_px = as_scalar(min_footprint_px, "min_footprint_px", 0, None)
    store = check_output_dir(store, "store")
    work = check_output_dir(work if work is not None else default_work_path(store, sid), "work")
    if (store / ROOT_META).is_file():  # an existing store (read only here): nothing to do if it has the subject
        with open_store(store) as st:
            if sid in st:
                return IngestReport(sid, str(store), "", skipped=True)
    _input_file(mesh, "mesh")
    if regions is None:
        regions = find_region_image(mesh)
    if isinstance(regions, (str, os.PathLike)):
        _input_file(regions, "regions")
    Dome.load(calibration)  # read again by ingest_photographs, whose messages then name the file
    folder = open_folder(photo_dir)
    geometry = load_face_mesh(mesh, regions)
    interrupted = None
    with new_store_guard(store), _removed_on_error(work, keep=store):  # nothing was created before this line
        try:
            with open_store(store, "a"):  # create it now: a foreign directory fails before the long ingest
                pass
            work.parent.mkdir(parents=True, exist_ok=True)
            ingest_photographs(
                folder,
                geometry,
                calibration,  # the file, so that errors name it
                work,
                subject_id=sid,
                workers=workers,
                motion_tolerance=motion_tolerance,
                min_footprint_px=min_footprint_px,
                progress=progress,
            )
            capture = open_ingested(work)
            ds = _fit(capture, sigma_tr_avg, settings, progress)
            with open_store(store, "a") as st:
                st.write_subject(ds)
        except KeyboardInterrupt as exc:  # an interruption keeps the store and the partial capture to resume
            interrupted = exc
    if interrupted is not None:
        raise interrupted
    prov = capture.provenance
    counts = json.loads(ds.attrs["provenance"])["counts"]
    return IngestReport(
        sid,
        str(store),
        str(work),
        n_lumitexels=capture.n_lumitexels,
        samples_used=int(counts["samples_used"]),
        motion_flags=list(prov.get("motion_flags", [])),
    )


def _fit(capture, sigma_tr_avg, settings, progress):
    """:func:`fit_subject` of an ingested capture; a fit that cannot be made for want of samples also says how many
    the ingest dropped as unresolved (:func:`facestats.acquire.ingest.footprint_note`): frames too coarse for the
    mesh's lumitexels leave none, and the fit alone cannot tell that cause from a dark or badly aimed rig."""
    try:
        return fit_subject(capture, sigma_tr_avg, settings, progress=progress)
    except (FitError, ValidationError) as exc:
        note = footprint_note(capture.provenance)
        if not note:
            raise
        raise type(exc)(f"{exc}; {note}") from exc


def _input_file(path, what: str) -> pathlib.Path:
    """``path`` if it is a regular file, else an error naming ``what`` and the path (a FIFO is never opened).

    Parameters
    ----------
    path : str or os.PathLike
        An input file.
    what : str
        The argument's name in messages (``"mesh"``, ``"regions"``).

    Returns
    -------
    pathlib.Path

    Raises
    ------
    ValidationError
        ``path`` is not a path.
    FormatError
        It does not exist, cannot be read, or is a directory, FIFO or device.
    """
    if not isinstance(path, (str, os.PathLike)) or not os.fspath(path):
        raise ValidationError(f"{what} must be the path of a file, got {path!r}")
    p = pathlib.Path(os.fspath(path))
    try:
        mode = os.stat(p).st_mode
    except OSError as exc:
        raise FormatError(f"{what} {p} cannot be read: {exc.strerror}") from None
    if not stat.S_ISREG(mode):
        raise FormatError(f"{what} {p} is not a regular file (it is a directory, FIFO, socket or device)")
    return p


@contextlib.contextmanager
def _removed_on_error(path, keep):
    """Remove ``path`` and the missing folders above it that the block created, if the block fails with an error.

    Folders that existed before the block are never removed, nor one that holds ``keep`` (the store, whose
    creation :func:`facestats.io.root.new_store_guard` undoes); when ``path`` itself existed (an empty ``--work``
    folder), what the block wrote into it goes and the folder stays.  An interruption (:class:`KeyboardInterrupt`)
    keeps them: a partial capture is resumed by the next run.  A failed ingest leaves nothing behind, even
    after some cameras were finished: its input needs fixing, and the next run starts afresh.
    """
    p, keep = pathlib.Path(os.fspath(path)).absolute(), pathlib.Path(os.fspath(keep)).absolute()
    created = None  # the outermost missing folder of path's chain that does not hold keep
    while not os.path.lexists(p) and p != p.parent:
        if not keep.is_relative_to(p):
            created = p
        p = p.parent
    own = pathlib.Path(os.fspath(path)).absolute()
    existing = own.is_dir() and not own.is_symlink()
    before = set(os.listdir(own)) if existing else set()
    try:
        yield
    except Exception:
        if created is not None and os.path.isdir(created) and not os.path.islink(created):
            shutil.rmtree(created, ignore_errors=True)
        elif existing and own.is_dir():  # the user's folder stays; what this run wrote in it goes
            for name in set(os.listdir(own)) - before:
                entry = own / name
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry, ignore_errors=True)
                else:
                    entry.unlink(missing_ok=True)
        raise
