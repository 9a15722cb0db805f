"""A calibrated pinhole camera: projection, which patches it sees, and the radiance it records at them.

The camera model is the dome's (:class:`facestats.acquire.dome.Dome`) without
lens distortion: a point x (mm, world frame) has camera coordinates R (x − C)
(rows of R: x right, y down, z forward), and pixel coordinates
(u, v) = (K R (x − C))[:2] / z with intrinsics K; but pixel (0, 0) is the
top-left corner of the top-left pixel, whose centre is (0.5, 0.5) (the dome's
centre is (0, 0), as in OpenCV: :meth:`PinholeCamera.from_dome` moves the
principal point), and images are indexed [row, column] = [v, u].
:func:`look_at` is the one implementation, used by the dome as well
(:meth:`facestats.acquire.dome.Dome.project` projects with distortion itself).

For Suzuki, Mukaigawa & Yagi §3.3 only the patches the camera sees give rows:
a patch is *seen* if it faces the camera, projects inside the image, is not
occluded (shadow map of the patches' mesh from the camera centre,
:class:`facestats.acquire.visibility.ShadowMaps`) and the image holds a finite
value there.  Its radiance is the image sampled bilinearly at its projected
centre, and its exitance l_j = π L_o / F_t,o (eq. 15,
:func:`facestats.model.irradiance.exitance_from_radiance`).

Camera files are JSON: ``{"matrix": 3×3 K, "rotation": 3×3 world-to-camera R,
"position_mm": [x, y, z], "image_size": [width, height]}`` (or ``"look_at"``
with ``"target_mm"`` and ``"focal_px"`` instead of ``"rotation"`` and
``"matrix"``).  Radiance images: OpenEXR or PFM through
:func:`facestats.io.images.read_image` (linear, as stored), or ``.npz`` with an
array ``radiance`` (H, W[, C]).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from facestats.core.validate import as_finite, as_scalar, check_shape, described
from facestats.errors import FormatError, ValidationError
from facestats.io.layout import read_regular_file

__all__ = [
    "PinholeCamera",
    "look_at",
    "project_points",
    "sample_image",
]


def look_at(position, target, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """World-to-camera rotation (rows: camera x right, y down, z forward) looking from ``position`` at ``target``.

    Parameters
    ----------
    position, target : array_like, shape (..., 3)
        Camera centre and the point it looks at, mm (world frame); stacked for several cameras.
    up : array_like, shape (3,) or (..., 3)
        World direction that appears up in the image; where it is parallel to the view direction,
        (1, 0, 0) is used in its place.

    Returns
    -------
    ndarray of float64, shape (..., 3, 3)
        The rotation R, rows right, down, forward (unit vectors).

    Raises
    ------
    ValidationError
        A ``target`` equal to its ``position`` (or NaN).
    """
    p = np.asarray(position, float)
    fwd = np.asarray(target, float) - p
    length = np.linalg.norm(fwd, axis=-1, keepdims=True)
    if not np.all(length > 0):  # also NaN
        first = np.argwhere(~(length[..., 0] > 0))[0] if length.ndim > 1 else ()
        where = f" (camera {', '.join(str(int(i)) for i in first)})" if len(first) else ""
        raise ValidationError(
            f"a camera's target must differ from its position{where}, got position {p[tuple(first)].tolist()!r}"
        )
    fwd /= length
    up = np.broadcast_to(np.asarray(up, float), fwd.shape)
    right = np.cross(fwd, up)
    bad = np.linalg.norm(right, axis=-1) < 1e-6
    right = np.where(bad[..., None], np.cross(fwd, [1.0, 0.0, 0.0]), right)
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    down = np.cross(fwd, right)
    return np.stack([right, down, fwd], axis=-2)


def project_points(points, position, rotation, matrix):
    """Pixel coordinates (N, C, 2) and depths (N, C) of points (N, 3) in cameras (C) given as stacked arrays.

    Points behind a camera get depth ≤ 0 and non-finite pixels are possible there.

    Parameters
    ----------
    points : array_like, shape (N, 3)
        World points, mm.
    position : array_like, shape (C, 3)
        Camera centres, mm.
    rotation : array_like, shape (C, 3, 3)
        World-to-camera rotations (module docstring).
    matrix : array_like, shape (C, 3, 3)
        Intrinsics K.

    Returns
    -------
    pixels : ndarray of float64, shape (N, C, 2)
        (u, v) with pixel (0, 0) the top-left corner of the image (module docstring).
    depth : ndarray of float64, shape (N, C)
        Camera z of each point, mm.
    """
    d = np.asarray(points, np.float64)[:, None, :] - np.asarray(position, np.float64)[None, :, :]
    cam = np.einsum("cij,ncj->nci", np.asarray(rotation, np.float64), d)
    uvw = np.einsum("cij,ncj->nci", np.asarray(matrix, np.float64), cam)
    with np.errstate(divide="ignore", invalid="ignore"):
        pix = uvw[..., :2] / uvw[..., 2:3]
    return pix, cam[..., 2]


@dataclass
class PinholeCamera:
    """One calibrated camera (module docstring).

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        Intrinsics K, pixels.
    rotation : ndarray, shape (3, 3)
        World-to-camera rotation (rows: x right, y down, z forward).
    position : ndarray, shape (3,)
        Camera centre, mm.
    image_size : tuple of int
        (width, height) in pixels.
    """

    matrix: np.ndarray
    rotation: np.ndarray
    position: np.ndarray
    image_size: tuple

    def __post_init__(self):
        k = check_shape(as_finite(self.matrix, "matrix", dtype=np.float64), "matrix", (3, 3))
        r = check_shape(as_finite(self.rotation, "rotation", dtype=np.float64), "rotation", (3, 3))
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-6):
            raise ValidationError("rotation must be a rotation matrix (R Rᵀ = I), got a matrix that is not orthonormal")
        if np.linalg.det(r) < 0:
            raise ValidationError("rotation must be a proper rotation (det R = +1), got a reflection (det R = -1)")
        if k[0, 0] <= 0 or k[1, 1] <= 0 or not np.allclose(k[2], [0, 0, 1]) or k[1, 0] != 0:
            raise ValidationError(
                f"matrix must be pinhole intrinsics [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, "
                f"got {k.tolist()}"
            )
        c = check_shape(as_finite(self.position, "position", dtype=np.float64), "position", (3,))
        raw = np.asarray(self.image_size).reshape(-1)
        if raw.dtype.kind not in "iuf" or raw.size != 2 or np.any(raw != np.round(raw)) or np.any(raw <= 0):
            raise ValidationError(f"image_size must be (width, height) positive whole pixels, got {self.image_size!r}")
        size = tuple(int(x) for x in raw)
        self.matrix, self.rotation, self.position, self.image_size = k, r, c, size

    @classmethod
    def looking_at(cls, position, target, *, focal_px, image_size) -> "PinholeCamera":
        """A camera at ``position`` (mm) looking at ``target``, focal length ``focal_px``, principal point centred.

        Parameters
        ----------
        position : array_like, shape (3,)
            Camera centre, mm (world frame).
        target : array_like, shape (3,)
            The point it looks at, mm; the world's +y appears up (:func:`look_at`).
        focal_px : float
            Focal length in pixels (fx = fy), > 0.
        image_size : sequence of int
            (width, height) in pixels; the principal point is (width / 2, height / 2).

        Returns
        -------
        PinholeCamera

        Raises
        ------
        ValidationError
            ``focal_px`` not > 0, ``target`` equal to ``position``, or a camera the constructor refuses.
        """
        w, h = (int(x) for x in image_size)
        f = as_scalar(focal_px, "focal_px", 0, None, low_inclusive=False)
        k = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1.0]])
        return cls(k, look_at(position, target), np.asarray(position, float), (w, h))

    @classmethod
    def from_dome(cls, dome, index: int, *, ignore_distortion: bool = False) -> "PinholeCamera":
        """Camera ``index`` of a :class:`facestats.acquire.dome.Dome` calibration.

        R, the centre and the image size are copied unchanged; K too, but for its principal point, moved by
        (+½, +½): the dome puts pixel centres at integer coordinates (OpenCV, an image spans [−½, W − ½)), this
        class at integer + ½ (module docstring).  An undistorted camera projects every point to the dome's pixel
        + (½, ½), and :meth:`in_frame` agrees with the dome's.  This class has no lens distortion: a dome camera
        with distortion is refused unless ``ignore_distortion`` is true.

        Parameters
        ----------
        dome : Dome
            The calibration.
        index : int
            The camera, in [0, ``dome.n_cameras``).
        ignore_distortion : bool, optional
            Accept a camera with lens distortion and drop it (its projections are then off by the distortion,
            most near the image edges).  Default False.

        Returns
        -------
        PinholeCamera

        Raises
        ------
        ValidationError
            ``index`` out of range, or the camera has lens distortion and ``ignore_distortion`` is false.
        """
        i = int(index)
        if not 0 <= i < dome.n_cameras:
            raise ValidationError(f"index must name one of the dome's {dome.n_cameras} cameras, got {index!r}")
        dist = np.asarray(dome.camera_distortion[i], np.float64)
        if np.any(dist != 0) and not ignore_distortion:
            raise ValidationError(
                f"dome camera {i} has lens distortion {dist.tolist()}, which PinholeCamera cannot model; "
                "pass ignore_distortion=True to drop it"
            )
        k = np.array(dome.camera_matrix[i], np.float64)
        k[:2, 2] += 0.5  # pixel centres: integers (dome, OpenCV) -> integer + 0.5 (here)
        return cls(k, dome.camera_rotation[i], dome.camera_position[i], tuple(dome.image_size[i]))

    def project(self, points):
        """Pixel coordinates (N, 2) and depths along the optical axis (N,) of points (N, 3), mm.

        Parameters
        ----------
        points : array_like, shape (N, 3)
            World points, mm.

        Returns
        -------
        pixels : ndarray of float64, shape (N, 2)
            (u, v) with pixel (0, 0) the top-left corner of the image (module docstring).
        depth : ndarray of float64, shape (N,)
            Camera z, mm (≤ 0 behind the camera, where the pixels mean nothing).
        """
        pix, depth = project_points(points, self.position[None], self.rotation[None], self.matrix[None])
        return pix[:, 0], depth[:, 0]

    def in_frame(self, points) -> np.ndarray:
        """(N,) bool: in front of the camera and inside the image.

        Parameters
        ----------
        points : array_like, shape (N, 3)
            World points, mm.

        Returns
        -------
        ndarray of bool, shape (N,)
            Depth > 0 and the pixel in [0, width) × [0, height).
        """
        pix, depth = self.project(points)
        w, h = self.image_size
        with np.errstate(invalid="ignore"):
            return (depth > 0) & (pix[:, 0] >= 0) & (pix[:, 1] >= 0) & (pix[:, 0] < w) & (pix[:, 1] < h)

    def pixel_footprint(self, points) -> np.ndarray:
        """Side of a pixel at each point's depth, mm (depth / focal length).

        Parameters
        ----------
        points : array_like, shape (N, 3)
            World points, mm.

        Returns
        -------
        ndarray of float64, shape (N,)
            |depth| / sqrt(fx fy), mm.
        """
        _, depth = self.project(points)
        return np.abs(depth) / float(np.sqrt(self.matrix[0, 0] * self.matrix[1, 1]))

    def to_dict(self) -> dict:
        """The camera as a JSON-ready dict (K, R, position in mm, image size)."""
        return {
            "matrix": self.matrix.tolist(),
            "rotation": self.rotation.tolist(),
            "position_mm": self.position.tolist(),
            "image_size": list(self.image_size),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "PinholeCamera":
        """Inverse of :meth:`to_dict`; ``look_at`` form accepted (module docstring).

        Parameters
        ----------
        d : dict
            A decoded camera description: ``matrix``, ``rotation``, ``position_mm`` and ``image_size``, or
            ``position_mm``, ``target_mm``, ``focal_px`` and ``image_size`` (:meth:`looking_at`).

        Returns
        -------
        PinholeCamera

        Raises
        ------
        FormatError
            ``d`` is not a dict, or a key is missing.
        ValidationError
            A field out of its domain (the constructor's or :meth:`looking_at`'s checks).
        """
        if not isinstance(d, dict):
            raise FormatError(f"camera description must be a JSON object, got {type(d).__name__}")
        try:
            if "look_at" in d or "target_mm" in d:
                return cls.looking_at(
                    d["position_mm"], d["target_mm"], focal_px=d["focal_px"], image_size=d["image_size"]
                )
            return cls(
                np.asarray(d["matrix"], float), np.asarray(d["rotation"], float), d["position_mm"], d["image_size"]
            )
        except KeyError as exc:
            raise FormatError(f"camera description is missing the key {exc.args[0]!r}") from None

    def save(self, path):
        """Write :meth:`to_dict` to ``path`` as JSON.

        Parameters
        ----------
        path : str or path-like
            The file to write (replaced if it exists); :meth:`load` reads it.
        """
        with open(path, "w") as f:
            json.dump(self.to_dict(), f, indent=1)

    @classmethod
    def load(cls, path) -> "PinholeCamera":
        """The camera of a JSON file (:meth:`from_dict`); every error names the file.

        Parameters
        ----------
        path : str or path-like
            A camera file (module docstring).

        Returns
        -------
        PinholeCamera

        Raises
        ------
        FormatError
            The file cannot be read or is not JSON, or a field is missing or of the wrong type.
        ValidationError
            A field out of its domain.
        """
        try:
            doc = json.loads(read_regular_file(path))
        except (OSError, ValueError, RecursionError) as exc:  # ValueError: not JSON, or not UTF-8
            raise FormatError(f"cannot read the camera file {os.fspath(path)}: {exc}") from None
        return described(cls.from_dict, doc, f"camera file {os.fspath(path)}")


def sample_image(image, pixels) -> np.ndarray:
    """Bilinear samples (N, C) of an image (H, W, C) at pixel coordinates (N, 2), by scipy.ndimage.map_coordinates.

    Pixel centres lie at integer + 0.5; samples outside the image, or touching a
    NaN pixel, are NaN.

    Parameters
    ----------
    image : array_like, shape (H, W, C) or (H, W)
        The image, indexed [v, u]; (H, W) is one channel.
    pixels : array_like, shape (N, 2)
        (u, v) pixel coordinates; finite ones in [0, W] × [0, H] are sampled (clamped to the edge pixels).

    Returns
    -------
    ndarray of float64, shape (N, C)
        Samples; C = 1 for an (H, W) image.
    """
    from scipy.ndimage import map_coordinates

    img = np.asarray(image, np.float64)
    if img.ndim == 2:
        img = img[..., None]
    h, w = img.shape[:2]
    pix = np.asarray(pixels, np.float64)
    x, y = pix[:, 0] - 0.5, pix[:, 1] - 0.5
    ok = np.isfinite(x) & np.isfinite(y) & (x >= -0.5) & (y >= -0.5) & (x <= w - 0.5) & (y <= h - 0.5)
    coords = np.stack([np.where(ok, y, 0), np.where(ok, x, 0)])
    out = np.stack([map_coordinates(img[..., c], coords, order=1, mode="nearest") for c in range(img.shape[2])], -1)
    out[~ok] = np.nan
    return out
