"""What a camera records of known patches: which patches it sees, and their exitance (Suzuki et al. eq. 15).

For Suzuki, Mukaigawa & Yagi §3.3 only the patches the camera sees give rows:
a patch is *seen* if it faces the camera, projects inside the image, is not
occluded (shadow map of the patches' mesh from the camera centre,
:class:`facestats.acquire.visibility.ShadowMaps`) and the image holds a finite
value there.  Its radiance L_o is the image sampled bilinearly at its projected
centre (:func:`facestats.acquire.camera.sample_image`) and its exitance
l_j = π L_o / F_t,o (eq. 15, :func:`facestats.model.irradiance.exitance_from_radiance`).

Radiance images are linear: OpenEXR or PFM through
:func:`facestats.io.images.read_image` (as stored, never normalised), or
``.npz`` holding an array ``radiance`` (H, W[, C]); NaN marks pixels where
nothing was recorded (in OpenEXR, which holds finite values only, an alpha
channel of 0 marks them: RGBA files are read with A as coverage).
"""

from __future__ import annotations

import os

import numpy as np

from facestats.acquire.camera import PinholeCamera, sample_image
from facestats.acquire.visibility import ShadowMaps
from facestats.errors import FormatError, ValidationError
from facestats.model.irradiance import exitance_from_radiance

__all__ = ["camera_sees", "patch_radiance", "read_radiance_image", "write_radiance_image"]


def read_radiance_image(path) -> np.ndarray:
    """A linear radiance image (H, W, C) float64 from OpenEXR, PFM or ``.npz`` (array ``radiance``).

    Parameters
    ----------
    path : str or path-like
        An ``.exr``, ``.pfm`` or ``.npz`` file.

    Returns
    -------
    ndarray of float64, shape (H, W, C)
        Values as stored; an (H, W) image gets C = 1, and an RGBA OpenEXR becomes RGB with NaN where alpha is ≤ 0
        (the coverage :func:`write_radiance_image` writes).

    Raises
    ------
    ValidationError
        ``path`` is not an existing file, or not ``.exr``, ``.pfm`` or ``.npz``.
    FormatError
        An ``.npz`` without ``radiance`` or unreadable, or an image not of shape (H, W[, C]).
    """
    p = os.fspath(path)
    if not os.path.isfile(p):
        raise ValidationError(f"image must name an existing file, got {p!r}")
    if p.lower().endswith(".npz"):
        try:
            with np.load(p) as z:
                if "radiance" not in z.files:
                    raise FormatError(f"{p} must hold an array named 'radiance', got {z.files}")
                img = np.asarray(z["radiance"], np.float64)
        except (OSError, ValueError) as exc:
            raise FormatError(f"cannot read the radiance image {p}: {exc}") from None
    else:
        # local import: keeps facestats.io (24 modules) out of this module's import
        from facestats.io.images import read_image

        if not p.lower().endswith((".exr", ".pfm")):
            raise ValidationError(f"image must be a linear HDR image (.exr, .pfm or .npz), got {p!r}")
        img = np.asarray(read_image(p), np.float64)
        if p.lower().endswith(".exr") and img.ndim == 3 and img.shape[2] == 4:  # coverage in alpha
            img = np.where(img[..., 3:] > 0, img[..., :3], np.nan)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3:
        raise FormatError(f"radiance image {p} must have shape (H, W[, C]), got {img.shape}")
    return img


def write_radiance_image(path, image) -> str:
    """Write a linear radiance image: ``.npz`` (array ``radiance``) or OpenEXR/PFM (float32) by extension.

    An OpenEXR image with non-finite pixels gets an alpha channel of coverage (0 there, those pixels 0).

    Parameters
    ----------
    path : str or path-like
        Ending in ``.exr``, ``.pfm`` or ``.npz``.
    image : array_like, shape (H, W[, C])
        Linear radiance (``.npz`` keeps its dtype).

    Returns
    -------
    str
        ``path`` as a string.

    Raises
    ------
    ValidationError
        Another extension.
    """
    p = os.fspath(path)
    img = np.asarray(image)
    if p.lower().endswith(".npz"):
        np.savez_compressed(p, radiance=img)
        return p
    # local import: keeps facestats.io (24 modules) out of this module's import
    from facestats.io.images import write_image

    if not p.lower().endswith((".exr", ".pfm")):
        raise ValidationError(f"path must end in .exr, .pfm or .npz, got {p!r}")
    img = img.astype(np.float32)
    if p.lower().endswith(".exr") and not np.all(np.isfinite(img)):  # OpenEXR: pixels nothing reached → alpha 0
        covered = np.all(np.isfinite(img if img.ndim == 3 else img[..., None]), axis=-1, keepdims=True)
        img = np.concatenate([np.where(covered, img if img.ndim == 3 else img[..., None], 0), covered], axis=-1)
        img = img.astype(np.float32)
    write_image(p, img)
    return p


def camera_sees(camera: PinholeCamera, patches, *, shadow_resolution=512) -> np.ndarray:
    """(m,) bool: patches facing the camera, in frame and (with a mesh) not occluded (shadow map).

    Parameters
    ----------
    camera : PinholeCamera
    patches : facestats.acquire.patches.Patches
        Their centres and normals are tested; their mesh, if any, occludes.
    shadow_resolution : int
        Side of the camera's shadow map in pixels.

    Returns
    -------
    ndarray of bool, shape (m,)
    """
    to_cam = camera.position - patches.centre
    seen = (np.einsum("mk,mk->m", patches.normal, to_cam) > 0) & camera.in_frame(patches.centre)
    if patches.has_mesh:
        maps = ShadowMaps(
            patches.mesh_vertices, patches.mesh_faces, camera.position[None], resolution=shadow_resolution
        )
        seen &= maps.visible(patches.centre, patches.normal)[:, 0]
    return seen


def patch_radiance(image, camera: PinholeCamera, patches, *, eta=1.3, shadow_resolution=512):
    """Exitance l_j (Suzuki eq. 15) of the patches a camera sees in a radiance image (module docstring).

    Parameters
    ----------
    image : ndarray, shape (H, W[, C])
        Linear radiance (e.g. W mm⁻² sr⁻¹); NaN where nothing was recorded.
    camera : PinholeCamera
    patches : facestats.acquire.patches.Patches
        With an occluding mesh, shadow maps decide occlusion; otherwise only facing and framing.
    eta : float
        Relative index of refraction of F_t,o (Suzuki: 1.3).
    shadow_resolution : int
        Side of the camera's shadow map in pixels.

    Returns
    -------
    exitance : ndarray, shape (m, C)
        l_j, 0 where not seen.
    seen : ndarray of bool, shape (m,)
    """

    img = np.asarray(image, np.float64)
    if img.ndim == 2:
        img = img[..., None]
    w, h = camera.image_size
    if img.ndim != 3 or img.shape[:2] != (h, w):
        raise ValidationError(
            f"image must have shape ({h}, {w}[, C]) to match the camera's image_size, got {img.shape}"
        )
    seen = camera_sees(camera, patches, shadow_resolution=shadow_resolution)
    pix, _ = camera.project(patches.centre)
    vals = sample_image(img, pix)
    seen &= np.all(np.isfinite(vals), axis=1)
    if np.any(vals[seen] < 0):
        k = np.flatnonzero(seen)[np.argmin(vals[seen].min(axis=1))]  # the patch with the most negative sample
        x, y = (float(c) for c in pix[k])
        raise ValidationError(
            f"image must hold radiance ≥ 0 where the camera sees patches, got {float(vals[k].min()):.4g} at pixel "
            f"(x {x:.1f}, y {y:.1f}) (patch {k}); a negative value is not a radiance (an image with its black "
            "level subtracted? clip it at 0)"
        )
    to_cam = camera.position - patches.centre
    cos_o = np.einsum("mk,mk->m", patches.normal, to_cam) / np.linalg.norm(to_cam, axis=1)
    out = np.zeros(vals.shape)
    out[seen] = exitance_from_radiance(vals[seen], np.clip(cos_o[seen], 0, 1), eta)
    return out, seen
