"""The dome simulator writing photographs: a capture folder with known truth, as a lab's dome would write it.

:func:`write_capture_photographs` turns a subject's truth into the inputs of
:func:`facestats.acquire.ingest.ingest_photographs`:

* **Truth geometry**: the face's mesh is written as the lab's mesh (OBJ with UVs
  and a region image) and read back; its vertices and their mesh normals are the
  simulated face, so the ingest sees the surface it was given.
* **Radiance** of every lumitexel, camera and LED from the simulator's forward
  model (:class:`facestats.acquire.synthetic.simulate.DomeSimulator`, noise-free).
* **Images**: the face mesh is sampled densely (barycentric grids, ≤ ½ pixel
  apart), projected into each camera with its lens distortion and z-buffered
  (the visible surface of a pixel: samples within ``FRONT_MM`` of its nearest;
  of those the one closest to the pixel centre); each covered pixel shows the radiance of the
  lumitexel whose texel holds its surface point — the truth maps are constant
  per texel, and the shading is that of the lumitexel (so the image is the
  texel-resolution rendering of the truth, and a lumitexel's projection falls
  inside its own patch unless the view is grazing); the radiance is computed
  for every lit, front-facing (lumitexel, camera) pair and occlusion is left to
  the z-buffer; unlit lumitexels are dark, pixels off the face black.
* **Camera**: electrons = radiance × ``camera_scale`` × Δt, shot and read noise,
  the known non-linear response of :class:`facestats.acquire.response.ResponseCurve`
  (BT.709 curve, 12-bit codes by default), written as 16-bit PNG (or TIFF, or
  8-bit PNG/JPEG) with the exposure time in EXIF; the two exposures of the dome (§5).
* **Head motion** (optional): chosen frames see the head rotated between the two
  passes, so their long exposure is rendered with the moved head.
* **Calibration with small errors**: the dome JSON the lab would have —
  cameras' K, dist, R, t, LED positions and intensities — each perturbed by
  :class:`CalibrationErrors`, with the true response curve and camera scale.
* **Mesh** (OBJ with UVs) and its region image (PNG), the contact-sensor file
  and the manifest.

:func:`write_target_photographs` writes the photographs of a white diffuse
planar target (Weyrich §5: Fluorilon) at several poses under every LED, the
input of :func:`facestats.acquire.calibration.calibrate_leds`.
"""

from __future__ import annotations

import hashlib
import pathlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from facestats.acquire.calibration import target_hits
from facestats.acquire.dome import Dome, default_dome
from facestats.acquire.photographs import MANIFEST, write_manifest, write_sensor_file
from facestats.acquire.response import ResponseCurve
from facestats.acquire.synthetic.simulate import DomeSimulator
from facestats.core.progress import progress_bar
from facestats.core.validate import as_finite, check_choice
from facestats.errors import ValidationError
from facestats.face.geometry import FaceGeometry
from facestats.face.named import named_face

#: Depth band (mm) behind the nearest surface sample of a pixel that still counts as the visible surface.
FRONT_MM = 1.0

__all__ = [
    "CalibrationErrors",
    "PhotoCapture",
    "write_capture_photographs",
    "write_target_photographs",
    "TargetPose",
    "FrameRenderer",
    "encode_frame",
    "frame_name",
]


@dataclass(frozen=True)
class CalibrationErrors:
    """Standard deviations of the errors put into a simulated calibration file.

    Attributes
    ----------
    camera_rotation_deg : float
        Rotation about a random axis, degrees.
    camera_position_mm : float
        Camera centre, per axis, mm.
    focal : float
        Relative error of fx, fy.
    principal_point_px : float
        cx, cy, pixels at 1024² (scaled with the image).
    led_position_mm : float
        LED position, per axis, mm.
    led_intensity : float
        Relative error of each LED's RGB intensity (one factor per LED).
    """

    camera_rotation_deg: float = 0.01
    camera_position_mm: float = 0.1
    focal: float = 2e-4
    principal_point_px: float = 0.2
    led_position_mm: float = 0.5
    led_intensity: float = 0.003

    def apply(self, dome: Dome, rng: np.random.Generator) -> Dome:
        """``dome`` with these errors drawn from ``rng``.

        Parameters
        ----------
        dome : Dome
            The true rig.
        rng : numpy.random.Generator
            Draws the errors (normal, with the standard deviations of the attributes).

        Returns
        -------
        Dome
            A copy with perturbed camera rotations, positions, focal lengths and principal points, LED positions
            and LED intensities.
        """
        c = dome.n_cameras
        axis = rng.standard_normal((c, 3))
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        rot = np.stack([_rotation(a, np.radians(self.camera_rotation_deg) * rng.standard_normal()) for a in axis])
        k = dome.camera_matrix.copy()
        k[:, 0, 0] *= 1 + self.focal * rng.standard_normal(c)
        k[:, 1, 1] *= 1 + self.focal * rng.standard_normal(c)
        k[:, :2, 2] += self.principal_point_px * (dome.image_size / 1024.0) * rng.standard_normal((c, 2))
        n = dome.n_leds
        return replace(
            dome,
            camera_rotation=rot @ dome.camera_rotation,
            camera_position=dome.camera_position + self.camera_position_mm * rng.standard_normal((c, 3)),
            camera_matrix=k,
            led_position=dome.led_position + self.led_position_mm * rng.standard_normal((n, 3)),
            led_intensity=dome.led_intensity * (1 + self.led_intensity * rng.standard_normal((n, 1))),
        )


def _rotation(axis, angle):
    """Rodrigues rotation matrix about a unit ``axis`` by ``angle`` radians."""
    kx = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * (kx @ kx)


@dataclass(repr=False)
class PhotoCapture:
    """What :func:`write_capture_photographs` wrote: paths, and the truth it was made from.

    Attributes
    ----------
    folder : pathlib.Path
        The capture folder's manifest (``<folder>/manifest.json``; its ``parent`` is the folder).
    calibration : pathlib.Path
        The calibration file written (``dome.json``: the true dome with its calibration errors, if any).
    mesh : pathlib.Path
        The face mesh (``face.obj``).
    regions : pathlib.Path
        The mesh's region image (``face.regions.png``).
    true_dome : Dome
        The rig the photographs were rendered with (without calibration errors).
    moved_frames : list of (int, int)
        The (camera, LED) frames whose long exposure saw the moved head, sorted.
    geometry : FaceGeometry
        The simulated face: the mesh as written and read back.
    """

    folder: pathlib.Path
    calibration: pathlib.Path
    mesh: pathlib.Path
    regions: pathlib.Path
    true_dome: Dome
    moved_frames: list
    geometry: FaceGeometry

    def __repr__(self) -> str:
        """The folder, the files beside the manifest, and the rig and face as counts (their arrays are long)."""
        d, g = self.true_dome, self.geometry
        sizes = np.unique(np.asarray(d.image_size).reshape(-1, 2), axis=0)
        size = f"{sizes[0][0]}x{sizes[0][1]} px" if len(sizes) == 1 else f"{len(sizes)} image sizes"
        moved = ", ".join(map(str, self.moved_frames[:4])) + (", ..." if len(self.moved_frames) > 4 else "")
        files = ", ".join(f"{k}={str(getattr(self, k))!r}" for k in ("calibration", "mesh", "regions"))
        return (
            f"PhotoCapture(folder={str(self.folder.parent)!r}, {files}, "
            f"true_dome=<Dome: {d.n_leds} LEDs, {d.n_cameras} cameras, {size}>, "
            f"geometry=<FaceGeometry {g.name!r}: {g.n_points} lumitexels, {g.map_size}x{g.map_size} maps, "
            f"mesh of {len(g.mesh_vertices)} vertices and {len(g.mesh_faces)} faces>, "
            f"moved_frames=[{moved}] ({len(self.moved_frames)}))"
        )


# -- rendering --------------------------------------------------------------------------------------------
def _surface_samples(geometry, m):
    """Points (S, 3) and UVs (S, 2) on a barycentric grid of ``m`` steps in every mesh triangle."""
    i, j = np.meshgrid(np.arange(m + 1), np.arange(m + 1), indexing="ij")
    keep = i + j <= m
    b = np.stack([i[keep], j[keep], m - i[keep] - j[keep]], 1) / m  # (K, 3) barycentric weights
    f = geometry.mesh_faces
    uv = geometry.mesh_uv
    pts = np.einsum("kb,fbd->fkd", b, geometry.mesh_vertices[f]).reshape(-1, 3)
    uvs = np.einsum("kb,fbd->fkd", b, uv[f]).reshape(-1, 2)
    return pts, uvs


class FrameRenderer:
    """Per-camera pixel → lumitexel interpolation of one geometry in one (true) dome (module docstring).

    Parameters
    ----------
    geometry : FaceGeometry
        The face: its mesh (with ``mesh_uv``), lumitexels and map size.
    dome : Dome
        The rig whose cameras (with lens distortion) see the face.

    Raises
    ------
    ValidationError
        The geometry's mesh has no UVs.
    """

    def __init__(self, geometry: FaceGeometry, dome: Dome):
        self.geometry, self.dome = geometry, dome
        edge = np.linalg.norm(np.diff(geometry.mesh_vertices[geometry.mesh_faces][:, [0, 1, 2, 0]], axis=1), axis=2)
        dist = np.linalg.norm(dome.camera_position - geometry.mesh_vertices.mean(0), axis=1).min()
        px_per_mm = dome.camera_matrix[:, 0, 0].max() / dist
        self.steps = max(2, int(np.ceil(2.5 * edge.max() * px_per_mm)))
        if geometry.mesh_uv is None:
            raise ValidationError(f"geometry {geometry.name!r} needs UVs of its mesh vertices (mesh_uv) to be rendered")
        self.points, self.uvs = _surface_samples(geometry, self.steps)
        n = geometry.map_size
        self.grid = np.full((n, n), -1, np.int64)  # the lumitexel of each texel
        tex = geometry.texel_index()
        self.grid[tex[:, 0], tex[:, 1]] = np.arange(geometry.n_points)

    def pixels(self, camera, motion=None):
        """(flat pixel index (P,), lumitexel of each pixel (P,), −1 off the face) of the pixels the face covers.

        Parameters
        ----------
        camera : int
            0-based camera index.
        motion : ndarray, shape (3, 3), optional
            Rotation of the head about the centre of its mesh's bounding box (None: the head at rest).

        Returns
        -------
        flat : ndarray of int64, shape (P,)
            Flat indices v·W + u of the covered pixels, sorted.
        lumitexel : ndarray of int64, shape (P,)
            The lumitexel whose texel holds each pixel's visible surface point; −1 for a texel off the face.
        """
        pts = self.points
        if motion is not None:  # rigid head motion (rotation about the head centre)
            centre = 0.5 * (self.geometry.mesh_vertices.min(0) + self.geometry.mesh_vertices.max(0))
            pts = centre + (pts - centre) @ motion.T
        pix, z = self.dome.project(pts, [camera])
        w, h = self.dome.image_size[camera]
        with np.errstate(invalid="ignore"):
            u, v = np.rint(pix[:, 0, 0]), np.rint(pix[:, 0, 1])
            ok = (z[:, 0] > 0) & (u >= 0) & (v >= 0) & (u < w) & (v < h)
        keep = np.nonzero(ok)[0]
        flat = (v[ok] * w + u[ok]).astype(np.int64)
        zk = z[ok, 0]
        zmin = np.full(w * h, np.inf)
        np.minimum.at(zmin, flat, zk)
        front = zk <= zmin[flat] + FRONT_MM  # the visible surface in each pixel (z-buffer)
        keep, flat = keep[front], flat[front]
        d2 = np.sum((pix[keep, 0] - np.stack([u[keep], v[keep]], 1)) ** 2, axis=1)
        order = np.lexsort((d2, flat))  # within each pixel, the visible sample closest to the pixel centre
        flat, first = np.unique(flat[order], return_index=True)
        uv = self.uvs[keep[order[first]]]
        n = self.grid.shape[0]
        texel = np.clip((uv[:, ::-1] * n).astype(np.int64), 0, n - 1)  # (v, u) texel of the surface point
        return flat, self.grid[texel[:, 0], texel[:, 1]]

    @staticmethod
    def image(pixels, values, size):
        """Radiance image (H, W, 3) float32 from ``values`` (N, 3) per lumitexel (NaN: dark).

        Parameters
        ----------
        pixels : tuple of ndarray
            ``(flat, lumitexel)`` of :meth:`pixels`.
        values : ndarray, shape (N, 3)
            Radiance per lumitexel; NaN is written as 0 (dark).
        size : (int, int)
            The image's (width, height).

        Returns
        -------
        ndarray of float32, shape (H, W, 3)
            0 at pixels the face does not cover.
        """
        flat, node = pixels
        img = np.zeros((int(size[1]) * int(size[0]), 3), np.float32)
        on = node >= 0
        img[flat[on]] = np.nan_to_num(values[node[on]])
        return img.reshape(int(size[1]), int(size[0]), 3)


def encode_frame(codes, exposure_s, extension=".png", *, model="simulated dome camera") -> bytes:
    """The file bytes of one frame: RGB codes (H, W, 3), 8/16-bit PNG or 8-bit JPEG (quality 95; both with EXIF
    exposure time) or TIFF.

    PNG goes through :func:`facestats.io.png.encode_png` (rows unfiltered; Huffman-only deflate from 65,536
    samples on, libdeflate level 1 below: about ten times as fast as OpenCV's writer on a 1024² noisy
    12-bit frame, and smaller); JPEG and TIFF through OpenCV.

    Parameters
    ----------
    codes : ndarray of uint8 or uint16, shape (H, W, 3)
        RGB codes (uint8 for JPEG).
    exposure_s : float
        Exposure time in seconds, written as EXIF ``ExposureTime`` (PNG and JPEG).
    extension : {".png", ".jpg", ".jpeg", ".tif"}
        The file type, in any case (``".JPEG"`` is JPEG).
    model : str
        EXIF ``Model`` (``Make`` is ``facestats``).

    Returns
    -------
    bytes

    Raises
    ------
    ValidationError
        OpenCV cannot encode the codes in that format.
    """
    # local import: keeps facestats.io (23 modules) out of this module's import
    from facestats.io.exif import embed_exif, exif_payload
    from facestats.io.png import encode_png

    payload = exif_payload(exposure_s, make="facestats", model=model)
    kind = str(extension).lower()
    if kind == ".png":
        return encode_png(codes, chunks=[(b"eXIf", payload)])
    import cv2

    jpeg = kind in (".jpg", ".jpeg")
    params = [cv2.IMWRITE_JPEG_QUALITY, 95] if jpeg else []
    ok, buf = cv2.imencode(kind, np.ascontiguousarray(codes[..., ::-1]), params)
    if not ok:
        raise ValidationError(f"could not encode a {codes.shape} {codes.dtype} frame as {extension}")
    data = buf.tobytes()
    return embed_exif(data, payload) if jpeg else data


def _encode(path, codes, exposure_s):
    """Write one frame (:func:`encode_frame`) at ``path``; return its SHA-256."""
    data = encode_frame(codes, exposure_s, path.suffix)
    path.write_bytes(data)
    return hashlib.sha256(data).hexdigest()


def frame_name(camera, led, exposure, ext, pose=None):
    """Relative path of a frame in the simulator's capture folders: ``cam00/led000_e0.png`` (targets: ``pose0/…``).

    Parameters
    ----------
    camera, led, exposure : int
        0-based indices.
    ext : str
        File extension with its dot.
    pose : int, optional
        Target pose (LED calibration captures); None for a face capture.

    Returns
    -------
    str
        A POSIX relative path.
    """
    head = f"cam{camera:02d}" if pose is None else f"pose{pose}/cam{camera:02d}"
    return f"{head}/led{led:03d}_e{exposure}{ext}"


class _FrameWriter:
    """Encode frames on a thread pool with a bounded number in flight; collect their manifest entries."""

    def __init__(self, folder, workers):
        self.folder, self.workers = folder, max(1, int(workers))
        self.pool = ThreadPoolExecutor(self.workers)
        self.pending, self.entries = [], []

    def submit(self, rel, codes, exposure_s, **entry):
        (self.folder / rel).parent.mkdir(parents=True, exist_ok=True)
        future = self.pool.submit(_encode, self.folder / rel, codes, exposure_s)
        self.pending.append((future, dict(entry, exposure_s=float(exposure_s), file=rel)))
        while len(self.pending) > 2 * self.workers:  # bounded memory: wait for the oldest frame
            self._collect(0)

    def _collect(self, k):
        future, entry = self.pending.pop(k)
        entry["sha256"] = future.result()
        self.entries.append(entry)

    def close(self):
        while self.pending:
            self._collect(0)
        self.pool.shutdown()
        return self.entries


def _true_response(camera: ResponseCurve) -> np.ndarray:
    """The camera's g (ln electrons) per channel, as a calibration file holds it (levels, 3)."""
    return np.repeat(camera.log_exposure()[:, None], 3, axis=1)


# -- the face capture ---------------------------------------------------------------------------------------------
def write_capture_photographs(
    truth,
    folder,
    *,
    geometry: FaceGeometry | None = None,
    dome: Dome | None = None,
    camera: ResponseCurve | None = None,
    extension: str = ".png",
    errors: CalibrationErrors | None = CalibrationErrors(),
    moved_frames=(),
    motion_deg: float = 1.0,
    seed: int = 0,
    noise: bool = True,
    workers: int = 2,
    progress: bool = False,
) -> PhotoCapture:
    """Write a subject's whole dome capture as photographs (module docstring) into ``folder``.

    Parameters
    ----------
    truth : SubjectTruth
        The subject (:mod:`facestats.acquire.synthetic.population`).
    folder : str or path-like
        Output folder (created).
    geometry : FaceGeometry, optional
        The face, with the truth's map size; default the face the truth was drawn on
        (``truth.geometry``, :func:`facestats.face.named.named_face`).  The
        simulated truth is its mesh as written and read back (``PhotoCapture.geometry``):
        every labelled mesh vertex becomes a lumitexel, so a procedural face whose mesh
        grid equals its lumitexel grid keeps its lumitexels; the ICT face has about
        4,800-5,200 face vertices (857 lumitexels at 48²), which costs time.
    dome : Dome, optional
        The true rig; default :func:`default_dome` (1024² cameras; use :meth:`Dome.resized`).
    camera : ResponseCurve, optional
        The cameras' non-linear response; default 12-bit BT.709 with the dome's full well and read noise.
    extension : {".png", ".tif", ".jpg"}
        PNG (8- or 16-bit, with EXIF), TIFF, or 8-bit JPEG (with EXIF; quality 95) frames.
    errors : CalibrationErrors or None
        Errors of the written calibration (None: the true calibration).
    moved_frames : sequence of (camera, led)
        Frames whose long exposure sees the head rotated by ``motion_deg`` (between the two passes).
    motion_deg : float
        The rotation of the head in ``moved_frames``, degrees.
    seed : int
        Seeds the noise, the calibration errors and the motion axes.
    noise : bool
        Shot and read noise in the frames (False: only quantisation).
    workers : int
        Threads encoding the frames.
    progress : bool
        Progress bar over cameras.

    Returns
    -------
    PhotoCapture
        The folder's manifest, calibration, mesh and regions, the true dome, the moved frames and the geometry.
    """
    # local import: keeps facestats.io (23 modules) out of this module's import
    from facestats.io.mesh import load_face_mesh, save_face_mesh

    check_choice(extension, "extension", (".png", ".tif", ".jpg"))
    as_finite(motion_deg, "motion_deg", 0, None, unit="deg")
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    geometry = named_face(truth.geometry, truth.region_map.shape[0]) if geometry is None else geometry
    dome = default_dome() if dome is None else dome
    camera = camera or ResponseCurve(
        8 if extension == ".jpg" else 12, dome.response.full_well, dome.response.read_noise
    )
    if extension == ".jpg" and camera.bits != 8:
        raise ValidationError(f"camera must have 8-bit codes for JPEG frames, got bits={camera.bits}")
    rng = np.random.default_rng(seed)
    mesh = save_face_mesh(geometry, folder / "face.obj")
    regions = folder / "face.regions.png"
    _write_regions(regions, geometry.region_map)
    geometry = load_face_mesh(mesh, regions)  # the truth is the mesh the lab has: its vertices and normals
    clean = DomeSimulator(geometry, dome, noise=False, scan_normal_noise_deg=0.0, camera_visibility=False).simulate(
        truth
    )
    noisy_sensor = DomeSimulator(geometry, dome).simulate(truth)  # the contact sensor's HDR noise
    radiance = clean.array("radiance")
    renderer = FrameRenderer(geometry, dome)
    moved = {(int(c), int(l)) for c, l in moved_frames}
    writer = _FrameWriter(folder, workers)
    cams = range(dome.n_cameras)
    cams = progress_bar(cams, desc=f"photographs {truth.subject_id}", unit="camera", enabled=progress)
    for cam in cams:  # loop over cameras, then LEDs; each frame is whole-image array work
        pixels = renderer.pixels(cam)
        for led in range(dome.n_leds):
            vals = radiance[:, cam, led].astype(np.float32)  # NaN (unlit, or unseen by this camera): dark
            img = renderer.image(pixels, vals, dome.image_size[cam])
            for e, t in enumerate(dome.exposure_times):
                if e == len(dome.exposure_times) - 1 and (cam, led) in moved:
                    axis = rng.standard_normal(3)
                    rot = _rotation(axis / np.linalg.norm(axis), np.radians(motion_deg))
                    img = renderer.image(renderer.pixels(cam, rot), vals, dome.image_size[cam])
                codes = camera.encode(img * np.float32(dome.camera_scale * t), rng if noise else None)
                writer.submit(frame_name(cam, led, e, extension), codes, t, camera=cam, led=led, exposure=e)
    entries = writer.close()
    calib = dome if errors is None else errors.apply(dome, rng)
    calib = replace(calib, camera_log_response=_true_response(camera))
    calibration = folder / "dome.json"
    calib.save(calibration)
    write_sensor_file(
        folder / "sensor.json",
        noisy_sensor.sensor,
        noisy_sensor.array("sensor_profile"),
        noisy_sensor.array("sensor_profile_std"),
    )
    write_manifest(
        folder,
        entries,
        kind="face",
        bits=camera.bits,
        n_cameras=dome.n_cameras,
        n_leds=dome.n_leds,
        subject=dict(truth.metadata()),
        sensor="sensor.json",
    )
    return PhotoCapture(folder / MANIFEST, calibration, pathlib.Path(mesh), regions, dome, sorted(moved), geometry)


def _write_regions(path, region_map):
    import cv2

    if not cv2.imwrite(str(path), np.asarray(region_map, np.uint8)):
        raise ValidationError(f"could not write the region image {path}")


# -- the LED calibration target ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class TargetPose:
    """A planar diffuse target: centre (mm), unit normal, in-plane axis ``u_axis`` and size (mm).

    Attributes
    ----------
    centre : tuple of float
        The target's centre, mm (world coordinates).
    normal : tuple of float
        Unit normal of its front side (the side lit and photographed).
    u_axis : tuple of float
        Unit in-plane axis along its width.
    size_mm : tuple of float
        (width along ``u_axis``, height along normal × ``u_axis``), mm.
    """

    centre: tuple
    normal: tuple
    u_axis: tuple = (1.0, 0.0, 0.0)
    size_mm: tuple = (300.0, 300.0)

    def to_dict(self) -> dict:
        """The pose as a JSON-ready dict (centre and size in mm, normal, u axis)."""
        return {
            "centre_mm": list(map(float, self.centre)),
            "normal": list(map(float, self.normal)),
            "u_axis": list(map(float, self.u_axis)),
            "size_mm": list(map(float, self.size_mm)),
        }


def write_target_photographs(
    folder,
    dome: Dome,
    poses,
    *,
    albedo=(0.99, 0.99, 0.99),
    camera: ResponseCurve | None = None,
    cameras=None,
    seed: int = 0,
    workers: int = 2,
) -> pathlib.Path:
    """Photographs of a Lambertian target (albedo ρ) at ``poses`` under every LED, and their manifest.

    Radiance on the target is L = ρ/π · E⊥ · max(n·ωi, 0) (:meth:`Dome.incident`);
    each pixel's ray (:meth:`Dome.pixel_rays`) is intersected with the plane.
    Only ``cameras`` (default all) photograph; the manifest lists them in its ``cameras`` field.
    The manifest's ``target`` field records ρ and the poses.

    Parameters
    ----------
    folder : str or path-like
        The capture folder (created).
    dome : Dome
        The rig: LEDs, cameras, exposure times and ``camera_scale``.
    poses : sequence of TargetPose
        The target's poses, one frame set each (``pose<p>/…`` files).
    albedo : sequence of float
        ρ per channel.
    camera : ResponseCurve, optional
        The cameras' encoding (default a 12-bit curve with the dome's full well and read noise).
    cameras : iterable of int, optional
        The cameras that photograph (default all).
    seed : int
        Seed of the noise.
    workers : int
        Threads encoding and writing frames.

    Returns
    -------
    pathlib.Path
        The path of ``manifest.json``.
    """
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    camera = camera or ResponseCurve(12, dome.response.full_well, dome.response.read_noise)
    rng = np.random.default_rng(seed)
    rho = np.asarray(albedo, np.float64)
    use = set(range(dome.n_cameras) if cameras is None else (int(c) for c in cameras))
    writer = _FrameWriter(folder, workers)
    for p, pose in enumerate(poses):  # loop over poses and cameras; whole images per LED
        for cam in sorted(use):
            pts, idx = _target_points(dome, cam, pose)
            wi, e_perp = dome.incident(pts)
            cos = np.maximum(wi @ np.asarray(pose.normal, np.float64), 0)
            w, h = dome.image_size[cam]
            for led in range(dome.n_leds):
                img = np.zeros((h * w, 3), np.float32)
                img[idx] = rho / np.pi * e_perp[:, led] * cos[:, led, None]
                for e, t in enumerate(dome.exposure_times):
                    codes = camera.encode(img.reshape(h, w, 3) * np.float32(dome.camera_scale * t), rng)
                    rel = frame_name(cam, led, e, ".png", pose=p)
                    writer.submit(rel, codes, t, camera=cam, led=led, exposure=e, pose=p)
    entries = writer.close()
    target = {"albedo": rho.tolist(), "poses": [pose.to_dict() for pose in poses]}
    return write_manifest(
        folder,
        entries,
        kind="target",
        bits=camera.bits,
        n_cameras=dome.n_cameras,
        n_leds=dome.n_leds,
        cameras=sorted(use),
        target=target,
    )


def _target_points(dome, camera, pose):
    """World points (P, 3) of the pixels of ``camera`` that see the target, and their flat pixel indices."""
    w, h = dome.image_size[camera]
    v, u = np.mgrid[0:h, 0:w]
    geometry = (pose.centre, pose.normal, pose.u_axis, pose.size_mm)
    pts, inside = target_hits(dome, camera, np.stack([u.ravel(), v.ravel()], 1), geometry)
    inside &= (dome.camera_position[camera] - np.asarray(pose.centre, np.float64)) @ np.asarray(pose.normal) > 0
    idx = np.nonzero(inside)[0]
    return pts[idx], idx
