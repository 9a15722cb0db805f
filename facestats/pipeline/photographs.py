"""A folder of dome photographs to a fitted subject in a store: ingest (acquire stage), fit, write.

:func:`ingest_subject` chains :func:`facestats.acquire.ingest.ingest_photographs`
(photographs → capture on disk, resumable), :func:`facestats.pipeline.fit_subject`
(Weyrich et al. 2006 §5.1-5.4) and :meth:`Store.write_subject` (atomic).  The
subject reaches the store only after the whole capture is ingested and fitted:
an interrupted run leaves a partial capture in the work directory, never a
subject, and rerunning the same command resumes at the first unfinished camera.
"""

from __future__ import annotations

import json
import pathlib
from dataclasses import dataclass, field

from facestats.acquire.ingest import MIN_FOOTPRINT_PX, MOTION_TOLERANCE, ingest_photographs, open_ingested
from facestats.errors import FormatError
from facestats.io import open_store
from facestats.io.ids import check_subject_id
from facestats.io.mesh import load_face_mesh
from facestats.pipeline.subject import fit_subject

__all__ = ["ingest_subject", "IngestReport", "default_work_path", "find_region_image"]


@dataclass
class IngestReport:
    """What :func:`ingest_subject` did."""

    subject_id: str
    store: str
    capture: str
    n_lumitexels: int = 0
    samples_used: int = 0
    motion_flags: list = field(default_factory=list)
    skipped: bool = False

    def to_text(self) -> str:
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
    """Where the capture of an ingest is kept by default: ``<store>.ingest/<subject_id>/capture.zarr``."""
    s = pathlib.Path(store)
    return s.with_name(s.name + ".ingest") / str(subject_id) / "capture.zarr"


def find_region_image(mesh) -> pathlib.Path:
    """The face-region image next to a mesh: ``<stem>.regions.png`` or ``<stem>.regions.npy``."""
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
        Directory store, created if missing.
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
    """

    sid = check_subject_id(subject_id)
    with open_store(store, "a") as st:
        if sid in st:
            return IngestReport(sid, str(store), "", skipped=True)
    geometry = load_face_mesh(mesh, regions if regions is not None else find_region_image(mesh))
    work = pathlib.Path(work) if work is not None else default_work_path(store, sid)
    work.parent.mkdir(parents=True, exist_ok=True)
    ingest_photographs(
        photo_dir,
        geometry,
        calibration,  # the file, so that errors name it
        work,
        subject_id=sid,
        workers=workers,
        motion_tolerance=MOTION_TOLERANCE if motion_tolerance is None else motion_tolerance,
        min_footprint_px=MIN_FOOTPRINT_PX if min_footprint_px is None else min_footprint_px,
        progress=progress,
    )
    capture = open_ingested(work)
    ds = fit_subject(capture, sigma_tr_avg, settings, progress=progress)
    with open_store(store, "a") as st:
        st.write_subject(ds)
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
