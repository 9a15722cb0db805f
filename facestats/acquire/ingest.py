"""Photographs → lumitexels: a capture folder, a face mesh and a calibration into a capture on disk (Weyrich §5).

Weyrich et al. 2006 §5 register the dome's photographs to the scanned geometry
and gather, at every mesh vertex, a lumitexel of BRDF samples.
:func:`ingest_photographs` does that for a capture folder
(:mod:`facestats.acquire.photographs`):

1. **Geometry and visibility**: lumitexels from the mesh
   (:class:`facestats.face.geometry.FaceGeometry`), projected into every
   calibrated camera with lens distortion (:meth:`Dome.project`); valid samples
   from the shadow maps of every LED and camera, front-facing and in frame
   (:func:`facestats.acquire.visibility.sample_visibility`, the simulator's rule;
   the cameras' shadow maps at the cameras' own resolution, since a photograph
   shows occlusion edges at pixel scale);
   the irradiance E⊥ of every LED from its calibration (:meth:`Dome.incident`).
   A sample is kept only where the camera resolves the lumitexel: its surface
   patch (``area``) must span at least ``min_footprint_px`` pixels along its
   foreshortened axis (:func:`footprint_px`), otherwise the bilinear taps read
   the neighbouring surface — the registration problem of grazing views that
   makes Weyrich et al. exclude samples beyond 80° (§5.3).  Each of the four taps
   must also see the lumitexel's own surface (:func:`taps_on_surface`): a lumitexel
   at the mesh's edge or beside an occluding silhouette, though resolved, has taps
   on the background or on the occluder, which read it up to half as bright.  How many samples
   the rule dropped is recorded in the capture's provenance (``footprint``,
   :func:`footprint_note`): frames too coarse for the mesh leave too few samples
   to fit, and the fit's error then says why.
2. **HDR per (camera, LED)**: the frame's exposures are decoded once (checksums,
   bit depth and size checked), merged with the camera's response (Debevec &
   Malik 1997 eq. 6) at the four pixels around each lumitexel's projection and
   interpolated bilinearly; divided by ``camera_scale × camera_gain`` this is the
   radiance in dome units; samples with a saturated tap are invalid (NaN).
3. **Head motion**: the two exposures are two passes through the light sequence
   (§5); a head that moved between them makes them disagree.  Each frame's
   :func:`facestats.acquire.photographs.exposure_consistency` (the fraction of
   well-exposed pixels over the face whose two exposures disagree by more than
   a factor e^0.5; pixels within 4 of a clipped pixel are left out) above
   ``motion_tolerance`` flags the frame: its samples become
   invalid and the flag is recorded in the capture's provenance
   (``motion_flags``).  Motion within one pass, between consecutive LEDs, is not
   detected here; the stable minimum of the albedo fit (§5.2) discards such
   outliers.
4. **Streaming and resuming**: the capture (:mod:`facestats.acquire.capture`
   layout) is created on disk first, with ``radiance`` chunked per camera; one
   camera at a time is filled (memory: one camera's samples, N × L × 3 float32,
   plus the frames being decoded) and recorded in the group's ``ingest``
   attribute, so an interrupted ingest restarts at the first unfinished camera.
   Only when every camera is done is the capture marked complete; a partial
   capture cannot be opened for fitting (:func:`open_ingested`).
"""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np

from facestats.acquire.capture import PER_LUMITEXEL, CaptureWriter, open_capture
from facestats.acquire.dome import Dome
from facestats.acquire.photographs import (
    MANIFEST,
    CaptureFolder,
    bilinear_taps,
    check_exposures,
    check_response,
    exposure_consistency,
    merge_at,
    open_folder,
    prefetch,
)
from facestats.acquire.response import check_black_level, check_white_level
from facestats.acquire.visibility import dome_shadow_maps, sample_visibility
from facestats.core.progress import progress_bar
from facestats.core.validate import as_scalar, check_integer
from facestats.core.version import __version__
from facestats.errors import FormatError, ValidationError
from facestats.face.geometry import FaceGeometry

__all__ = [
    "ingest_photographs",
    "open_ingested",
    "ingest_state",
    "footprint_px",
    "taps_on_surface",
    "footprint_note",
    "MOTION_TOLERANCE",
    "MIN_FOOTPRINT_PX",
]

#: Default head-motion threshold: fraction of well-exposed face pixels whose two exposures disagree by more than a
#: factor e^0.5 (:func:`facestats.acquire.photographs.exposure_consistency`).  Still frames of simulated 12-bit PNG
#: and 8-bit JPEG captures score 0 (noise alone never reaches the factor); 1° head rotations between the passes
#: scored 0.2-1.5 % (2026-12-01), but since the synthetic albedo's sub-texel spots were fixed (cf69114) one of the
#: two moved frames of ``bench_photos.bench_ingest``'s 16² and 24² rigs stays below 0.1 % (docs/photographs.md).
#: Real still JPEG brackets score 0.0006-0.0016 % with the pixels around clipped highlights left out (0.48-0.49 %
#: with them; docs/photographs.md), a real bracket whose camera moved 0.27 px 2.1 %.
MOTION_TOLERANCE = 0.001
#: Default resolution limit: a lumitexel must span 2 pixels along its foreshortened axis, so that the four
#: bilinear taps around its projection (±1 pixel) stay on its own surface patch.
MIN_FOOTPRINT_PX = 2.0
_ATTR = "ingest"


def _fingerprint(
    folder: CaptureFolder,
    dome,
    geometry: FaceGeometry,
    subject_id=None,
    black_level=0,
    white_level=None,
    min_footprint_px=MIN_FOOTPRINT_PX,
    motion_tolerance=MOTION_TOLERANCE,
) -> dict:
    """What an ingest was made from: manifest, calibration and geometry digests, the black and white levels of the
    merge (DN; white None: the top code 2**bits − 1), the subject id it is for, and the two rules that decide
    which samples of a camera are kept (``min_footprint_px``, ``motion_tolerance``): a resumed ingest under
    other rules would keep some cameras' samples by one rule and the rest by the other."""
    geo = hashlib.sha256()
    for a in (geometry.position, geometry.normal, geometry.uv, geometry.mesh_vertices, geometry.mesh_faces):
        geo.update(np.ascontiguousarray(a).tobytes())
    calib = hashlib.sha256(json.dumps(dome.to_dict(), sort_keys=True).encode()).hexdigest()
    sid = subject_id or folder.subject()["subject_id"]
    return {
        "manifest": folder.fingerprint(),
        "calibration": calib,
        "geometry": geo.hexdigest(),
        "subject_id": sid,
        "black_level": int(black_level),
        "white_level": int(2**folder.bits - 1 if white_level is None else white_level),
        "min_footprint_px": float(min_footprint_px),
        "motion_tolerance": float(motion_tolerance),
    }


def _calibration(dome):
    """``(Dome, how messages name it)`` of a Dome or of its calibration file (:meth:`Dome.load`)."""
    if isinstance(dome, Dome):
        return dome, "the calibration"
    if isinstance(dome, (str, os.PathLike)):
        return Dome.load(dome), f"the calibration {os.fspath(dome)}"
    raise ValidationError(f"dome must be a Dome calibration or the path of its file, got {type(dome).__name__}")


def _check_inputs(folder: CaptureFolder, dome, geometry, calibration="the calibration"):
    """Raise unless the folder and the calibration describe the same rig, exposure times and bit depth.

    ``calibration`` names the calibration in messages (its file when known).
    """
    manifest = folder.path / MANIFEST
    if folder.kind != "face":
        raise FormatError(f"{manifest} field 'kind' must be 'face' to ingest a subject, got {folder.kind!r}")
    if folder.n_cameras != dome.n_cameras:
        raise FormatError(
            f"{manifest} field 'n_cameras' is {folder.n_cameras}, {calibration} has {dome.n_cameras} cameras "
            "(field 'cameras')"
        )
    if folder.n_leds != dome.n_leds:
        raise FormatError(
            f"{manifest} field 'n_leds' is {folder.n_leds}, {calibration} has {dome.n_leds} LEDs "
            "(field 'led_position_mm')"
        )
    if geometry.region_map is None:
        raise FormatError(f"geometry {geometry.name!r} has no face-region image (region_map): the maps need it")
    check_response(folder, dome, calibration)
    check_exposures(folder, dome, calibration)


def ingest_state(path) -> dict | None:
    """The ``ingest`` attribute of a capture being (or made by) an ingest, or None if there is none.

    Parameters
    ----------
    path : str or path-like
        A capture's zarr group.

    Returns
    -------
    dict or None
        The attribute (decoded when stored as a JSON string); None when the attribute is absent or no zarr group
        can be opened at ``path``.
    """
    import zarr

    try:
        g = zarr.open_group(str(path), mode="r")
    except Exception:  # zarr raises several types for a missing/invalid group
        return None
    st = g.attrs.get(_ATTR)
    return json.loads(st) if isinstance(st, str) else st


def _capture_subject_id(path):
    """The ``subject_id`` attribute of the capture group at ``path`` (None if it has none)."""
    import zarr

    return zarr.open_group(str(path), mode="r").attrs.get("subject_id")


def _start(path, folder, geometry, dome, fingerprint, chunk, subject_id):
    """Create the capture group with its per-lumitexel geometry and irradiance, or reopen a matching one."""
    state = ingest_state(path)
    if state is not None:
        stored = dict(state.get("fingerprint") or {})
        if "subject_id" not in stored:  # an ingest begun before the id was part of the key: the capture's own id
            stored["subject_id"] = _capture_subject_id(path)
        stored.setdefault("black_level", 0)  # an ingest begun before the black level was part of the key
        stored.setdefault("white_level", 2**folder.bits - 1)  # one begun before the white level was: the top code
        for rule in ("min_footprint_px", "motion_tolerance"):  # one begun before the rules were: unknown, this run's
            stored.setdefault(rule, fingerprint[rule])
        if stored != fingerprint:
            changed = [k for k in fingerprint if stored.get(k) != fingerprint[k]]
            raise FormatError(
                f"{path} holds an ingest of other inputs ({', '.join(changed)} differ); remove it or choose another "
                "work directory"
            )
        return CaptureWriter.reopen(path), state
    if os.path.isdir(path) and os.listdir(path) and not _setup_of(path, fingerprint):
        # never write over a folder that is not this ingest's capture
        raise FormatError(
            f"work folder {path} is not empty and holds no ingest: choose an empty or new folder "
            "(the capture is written there)"
        )
    sensor, _, _ = folder.sensor()
    meta = dict(folder.subject(), **({"subject_id": subject_id} if subject_id else {}))
    if subject_id and meta.get("person_id") in (None, folder.subject()["subject_id"]):
        meta["person_id"] = subject_id
    state = {"fingerprint": fingerprint, "cameras_done": [], "complete": False, "motion_flags": [], "footprint": []}
    attrs = dict(
        meta,
        dome=json.dumps(dome.to_dict()),
        sensor=json.dumps(sensor.to_attrs()),
        map_size=int(geometry.map_size),
        provenance=json.dumps(
            {
                "source": "photographs",
                "software": f"facestats {__version__}",
                "folder": str(folder.path),
                "manifest_sha256": fingerprint["manifest"],
                "geometry": geometry.name,
            }
        ),
    )
    writer = CaptureWriter(
        path,
        n_lumitexels=geometry.n_points,
        n_cameras=dome.n_cameras,
        n_lights=dome.n_leds,
        map_size=geometry.map_size,
        n_fibers=sensor.n_fibers,
        attrs=attrs,
        chunk=chunk,
        camera_chunk=1,
    )
    for a in range(0, geometry.n_points, chunk):  # per-lumitexel arrays block by block (bounded memory)
        sl = slice(a, min(a + chunk, geometry.n_points))
        _, e_perp = dome.incident(geometry.position[sl])
        arrays = {
            "position": geometry.position[sl].astype(np.float32),
            "scan_normal": geometry.normal[sl].astype(np.float32),
            "uv": geometry.uv[sl].astype(np.float32),
            "area": geometry.area[sl].astype(np.float32),
            "region": geometry.region[sl],
            "irradiance": e_perp.astype(np.float32),
        }
        writer.write_block(a, {k: arrays[k] for k in PER_LUMITEXEL if k != "radiance"})
    # The state last: a capture that has it holds every per-lumitexel array, so a rerun may resume it.
    writer.group.attrs[_ATTR] = json.dumps(state)
    return writer, state


def _setup_of(path, fingerprint) -> bool:
    """True when ``path`` holds a capture group this ingest began but left before its per-lumitexel arrays were
    written (no ``ingest`` state yet; the same manifest): it is made again from the start.

    An ingest interrupted there used to record its state first, so every rerun resumed a capture without
    those arrays and failed on a missing chunk (a red team).
    """
    import zarr

    try:
        attrs = zarr.open_group(str(path), mode="r").attrs
        prov = json.loads(attrs.get("provenance") or "{}")
    except Exception:  # not a zarr group, or not ours: zarr and json raise several types
        return False
    return (
        _ATTR not in attrs
        and isinstance(prov, dict)
        and prov.get("source") == "photographs"
        and prov.get("manifest_sha256") == fingerprint["manifest"]
    )


def footprint_px(dome, geometry, camera: int) -> np.ndarray:
    """Shortest axis (pixels) of each lumitexel's surface patch as camera ``camera`` sees it, shape (N,).

    A lumitexel represents ``area`` mm² of surface; seen at depth z under the
    angle θo its patch spans √area · f/z pixels across and √area · cos θo · f/z
    along the foreshortened axis (f the camera's mean focal length in pixels).

    Parameters
    ----------
    dome : Dome
        The calibration.
    geometry : FaceGeometry
        Lumitexel positions, normals and areas (mm²).
    camera : int
        0-based camera index.

    Returns
    -------
    ndarray of float64, shape (N,)
        √area · cos θo · f/z in pixels; 0 for lumitexels behind the camera or facing away from it.
    """
    _, z = dome.project(geometry.position, [camera])
    wo = dome.view_directions(geometry.position)[:, camera]
    cos_o = np.maximum(np.einsum("nk,nk->n", geometry.normal, wo), 0)
    f = 0.5 * (dome.camera_matrix[camera, 0, 0] + dome.camera_matrix[camera, 1, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(z[:, 0] > 0, np.sqrt(geometry.area) * cos_o * f / z[:, 0], 0.0)


def taps_on_surface(dome, shadows, camera: int, position, normal, pixel) -> np.ndarray:
    """Whether every bilinear tap around each lumitexel's projection sees the lumitexel's own surface, shape (N,).

    A tap pixel's ray (:meth:`Dome.pixel_rays`, distortion undone) is intersected with the lumitexel's tangent
    plane; the camera's depth buffer (:meth:`ShadowMaps.on_surface`) must hold a surface at that point and none
    in front of it.  A lumitexel at the mesh's edge has taps beyond the silhouette (the background), one beside an
    occluding silhouette taps on the occluder; either reads it too dark or too bright.  Taps of zero weight do not
    count.  The LED calibration keeps its target points on the target in the same way (its target is a bounded
    plane: :func:`facestats.acquire.calibration.target_observations`).

    Parameters
    ----------
    dome : Dome
        The calibration.
    shadows : ShadowMaps
        The LEDs' then the cameras' depth buffers (:func:`~facestats.acquire.visibility.dome_shadow_maps` with
        ``camera_pixels``: the cameras' at their own resolution).
    camera : int
        0-based camera index.
    position, normal : ndarray, shape (N, 3)
        The lumitexels' positions (mm) and unit normals.
    pixel : ndarray, shape (N, 2)
        Their projections in the camera (:meth:`Dome.view`).

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    size = dome.image_size[camera]
    index, weight = bilinear_taps(pixel, size)
    width = int(size[0])
    centres = np.stack([index % width, index // width], -1).reshape(-1, 2).astype(np.float64)
    rays = dome.pixel_rays(camera, centres).reshape(-1, 4, 3)
    eye = dome.camera_position[camera]
    facing = np.einsum("nk,ntk->nt", normal, rays)  # < 0: the ray meets the plane's front
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("nk,nk->n", position - eye, normal)[:, None] / facing
    hit = (facing < 0) & (t > 0)
    points = eye + np.where(hit, t, 0)[..., None] * rays
    on = shadows.on_surface(points.reshape(-1, 3), np.repeat(normal, 4, axis=0), dome.n_leds + camera)
    return np.all((hit & on.reshape(-1, 4)) | (weight <= 0), axis=1)


def _footprint_counts(vis, camera: int, footprint, resolved, on_surface) -> dict:
    """Of the samples camera ``camera`` sees lit (front-facing, in frame, unshadowed), how many the footprint rule
    drops, how many more the taps' surface test (:func:`taps_on_surface`) drops, and the median footprint
    (pixels) of the lumitexels it sees."""
    seen = vis.seen[:, camera]
    per = vis.lit[seen].sum(axis=1)  # lit samples of each lumitexel the camera sees
    return {
        "camera": int(camera),
        "visible": int(per.sum()),
        "dropped": int(per[~resolved[seen]].sum()),
        "off_surface": int(per[(resolved & ~on_surface)[seen]].sum()),
        "median_px": round(float(np.median(footprint[seen])), 4) if seen.any() else None,
    }


def _footprint_summary(counts, min_footprint_px: float, n_cameras: int) -> dict | None:
    """The provenance's ``footprint`` record from every camera's :func:`_footprint_counts` (None when an ingest
    resumed from a version that did not count leaves some cameras without counts)."""
    if len(counts) != n_cameras:
        return None
    medians = [c["median_px"] for c in counts if c["median_px"] is not None]
    return {
        "min_footprint_px": float(min_footprint_px),
        "visible_samples": int(sum(c["visible"] for c in counts)),
        "dropped_samples": int(sum(c["dropped"] for c in counts)),
        "off_surface_samples": int(sum(c.get("off_surface", 0) for c in counts)),
        "median_px": round(float(np.median(medians)), 4) if medians else None,
    }


def footprint_note(provenance) -> str:
    """How many samples an ingest's footprint rule dropped, as a sentence for error messages ("" if none or unknown).

    Parameters
    ----------
    provenance : dict
        The capture's provenance (:attr:`Capture.provenance` of :func:`open_ingested`), whose ``footprint``
        record :func:`ingest_photographs` writes.

    Returns
    -------
    str
        E.g. ``"the ingest dropped 40,110 of the 40,110 lit samples its cameras see (100.0 %) as unresolved: their
        lumitexels span fewer than --min-footprint 2 pixels (median footprint 0.6 pixels; pass a lower
        --min-footprint or photographs of higher resolution)"``; "" when it dropped none, or for a capture
        ingested before the record existed.
    """
    fp = (provenance or {}).get("footprint") or {}
    visible, dropped = int(fp.get("visible_samples", 0)), int(fp.get("dropped_samples", 0))
    if dropped <= 0 or visible <= 0:
        return ""
    median = fp.get("median_px")
    median = "" if median is None else f"median footprint {median:.3g} pixels; "
    return (
        f"the ingest dropped {dropped:,} of the {visible:,} lit samples its cameras see ({100 * dropped / visible:.1f} "
        f"%) as unresolved: their lumitexels span fewer than --min-footprint {fp['min_footprint_px']:g} pixels "
        f"({median}pass a lower --min-footprint or photographs of higher resolution)"
    )


def _camera_samples(folder, dome, vis, camera, motion_tolerance, workers, resolved, black_level=0, white_level=None):
    """Radiance (N, L, 3) float32 of one camera (NaN where invalid) and its motion scores (L,)."""
    n, n_led = vis.seen.shape[0], dome.n_leds
    out = np.full((n, n_led, 3), np.nan, np.float32)
    sel = np.nonzero(vis.seen[:, camera] & resolved)[0]
    scores = np.full(n_led, np.nan)
    if sel.size == 0:
        return out, scores, []
    size = dome.image_size[camera]
    index, weight = bilinear_taps(vis.pixel[sel, camera], size)
    lo = np.clip(np.floor(vis.pixel[sel, camera].min(0)).astype(int), 0, size - 1)
    hi = np.clip(np.ceil(vis.pixel[sel, camera].max(0)).astype(int) + 1, 1, size)
    box = (lo[0], lo[1], hi[0], hi[1])  # the face in this camera
    g = dome.camera_log_response[camera]
    scale = (dome.camera_scale * dome.camera_gain[camera]).astype(np.float32)

    def read(led):
        return led, folder.read_stack(camera, led, size=size)

    flags = []
    for led, (stack, times) in prefetch(read, range(n_led), workers):  # loop over LEDs, vectorised over lumitexels
        rad = merge_at(stack, times, g, index, weight, black_level=black_level, white_level=white_level) / scale
        lit = vis.lit[sel, led]
        out[sel[lit], led] = rad[lit]
        scores[led], n_used = exposure_consistency(
            stack, times, g, box, black_level=black_level, white_level=white_level
        )
        if n_used >= 100 and scores[led] > motion_tolerance:
            out[:, led] = np.nan
            flags.append({"camera": int(camera), "led": int(led), "score": round(float(scores[led]), 4)})
    return out, scores, flags


def ingest_photographs(
    folder,
    geometry: FaceGeometry,
    dome,
    path,
    *,
    subject_id: str | None = None,
    chunk: int = 2048,
    workers: int = 2,
    motion_tolerance: float = MOTION_TOLERANCE,
    min_footprint_px: float = MIN_FOOTPRINT_PX,
    black_level: int | None = None,
    white_level: int | None = None,
    progress: bool = False,
) -> str:
    """Turn a capture folder into a capture on disk (module docstring); rerunning resumes an interrupted ingest.

    Parameters
    ----------
    folder : str, path-like or CaptureFolder
        The photographs (:mod:`facestats.acquire.photographs`).
    geometry : FaceGeometry
        The face mesh's lumitexels (:func:`facestats.io.mesh.load_face_mesh`), mm, world frame.
    dome : Dome, str or path-like
        The calibration: cameras (K, dist, R, t), LEDs, ``camera_log_response``,
        ``camera_scale`` and ``camera_gain``; or its JSON file (:meth:`Dome.load`),
        which the errors about it then name.
    path : str or path-like
        Where the capture (a zarr group) is written.
    subject_id : str, optional
        Overrides the manifest's ``subject.subject_id``.
    chunk : int
        Lumitexels per zarr chunk (≥ 1).
    workers : int
        Threads decoding frames (≥ 1; decoding and hashing release the GIL).
    motion_tolerance : float
        Head-motion threshold (ln units, > 0; module docstring).
    min_footprint_px : float
        Samples whose lumitexel patch spans fewer pixels along its shortest axis
        (:func:`footprint_px`) are invalid (≥ 0; module docstring).
    black_level : int, optional
        The cameras' pedestal in DN, the one their response was recovered with
        (:func:`facestats.acquire.response.recover_response`): codes at and below it get no weight
        in the merge.  Default: the calibration's ``camera_black_level`` (0 for cameras without one).
    white_level : int, optional
        The code in DN at and above which the cameras clip, the one their response was recovered with:
        Z_max of the hat weights of Debevec & Malik 1997 eq. 4, codes at and above it get no weight in
        the merge (a sample with a tap at or above it in every exposure is invalid) and in the head-motion
        test.  Default: the calibration's ``camera_white_level`` (None there: the top code 2**bits − 1).
        An ingest resumed with another white level is refused, as for another black level.
    progress : bool
        Show a progress bar over cameras.

    Returns
    -------
    str
        ``path``; open it with :func:`open_ingested`.

    Raises
    ------
    FormatError
        The folder and the calibration disagree (camera or LED count, bit depth, a frame's
        exposure time beyond 1 % of the calibration's, :func:`~facestats.acquire.photographs.check_exposures`),
        or a frame is missing, corrupt or of the wrong size or depth; the message
        names the manifest or frame, the field and both values, and the
        calibration file when ``dome`` is one.
    """

    if not isinstance(geometry, FaceGeometry):
        raise ValidationError(f"geometry must be a FaceGeometry, got {type(geometry).__name__}")
    dome, calibration = _calibration(dome)
    chunk = check_integer(chunk, "chunk", 1)
    workers = check_integer(workers, "workers", 1)
    motion_tolerance = as_scalar(motion_tolerance, "motion_tolerance", 0, None, low_inclusive=False)
    min_footprint_px = as_scalar(min_footprint_px, "min_footprint_px", 0, None)
    folder = folder if isinstance(folder, CaptureFolder) else open_folder(folder)
    _check_inputs(folder, dome, geometry, calibration)
    black_level = check_black_level(dome.camera_black_level if black_level is None else black_level, 2**folder.bits)
    white_level = check_white_level(
        dome.camera_white_level if white_level is None else white_level, 2**folder.bits, black_level
    )
    fingerprint = _fingerprint(
        folder, dome, geometry, subject_id, black_level, white_level, min_footprint_px, motion_tolerance
    )
    writer, state = _start(path, folder, geometry, dome, fingerprint, chunk, subject_id)
    if state["complete"]:
        return str(path)
    shadows = dome_shadow_maps(geometry, dome, camera_pixels=True)
    vis = sample_visibility(dome, shadows, geometry.position, geometry.normal)
    todo = [c for c in range(dome.n_cameras) if c not in state["cameras_done"]]
    it = progress_bar(
        todo, desc=f"ingest {folder.path.name}", unit="camera", initial=dome.n_cameras - len(todo), enabled=progress
    )
    state.setdefault("footprint", [])  # absent from an ingest begun before the counts were kept
    for cam in it:  # loop over cameras: one camera's samples in memory at a time
        footprint = footprint_px(dome, geometry, cam)
        resolved = footprint >= min_footprint_px
        on_surface = np.zeros(geometry.n_points, bool)
        test = np.nonzero(vis.seen[:, cam] & resolved)[0]
        on_surface[test] = taps_on_surface(
            dome, shadows, cam, geometry.position[test], geometry.normal[test], vis.pixel[test, cam]
        )
        rad, _, flags = _camera_samples(
            folder, dome, vis, cam, motion_tolerance, workers, resolved & on_surface, black_level, white_level
        )
        writer.array("radiance")[:, cam] = rad.astype(np.float16)
        state["cameras_done"].append(int(cam))
        state["motion_flags"].extend(flags)
        state["footprint"].append(_footprint_counts(vis, cam, footprint, resolved, on_surface))
        writer.group.attrs[_ATTR] = json.dumps(state)  # the camera is on disk: record it
    sensor, prof, std = folder.sensor()
    writer.write_global(
        {
            "region_map": geometry.region_map,
            "sensor_profile": prof,
            "sensor_profile_std": std,
            "fiber_distance": sensor.fiber_distance,
        }
    )
    prov = json.loads(writer.group.attrs["provenance"])
    prov["motion_flags"] = state["motion_flags"]
    summary = _footprint_summary(state["footprint"], min_footprint_px, dome.n_cameras)
    if summary is not None:
        prov["footprint"] = summary
    writer.group.attrs["provenance"] = json.dumps(prov)
    state["complete"] = True
    writer.group.attrs[_ATTR] = json.dumps(state)
    return str(path)


def open_ingested(path):
    """Open a capture made by :func:`ingest_photographs`; a partial ingest is refused.

    Parameters
    ----------
    path : str or path-like
        The capture's zarr group.

    Returns
    -------
    Capture
        As :func:`facestats.acquire.capture.open_capture` gives it.

    Raises
    ------
    FormatError
        The capture is not complete (the message says how many cameras are done), or
        :func:`~facestats.acquire.capture.open_capture` refuses it.
    """
    state = ingest_state(path)
    if state is not None and not state.get("complete"):
        done = len(state.get("cameras_done", []))
        raise FormatError(
            f"capture {path} is a partial ingest ({done} camera(s) done); rerun the ingest to complete it"
        )
    return open_capture(path)
