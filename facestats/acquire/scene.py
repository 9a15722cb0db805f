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

The fit compares the exitance with the light that entered, so the image must
hold radiance in the lights' unit per steradian.  A merged HDR image
(``facestats calibrate merge``: exp(g)/s, the response's arbitrary scale per
channel) becomes one by a factor per channel: with a flat, matte reference
target of known reflectance ρ in view, under the same light and exposure,
:func:`reference_radiance_scale` gives it as ρ E / (π L̄), E the lights'
irradiance at the target and L̄ the image's mean over it (a Lambertian
reflector's radiance is ρ E / π).
"""

from __future__ import annotations

import os

import numpy as np

from facestats.acquire.camera import PinholeCamera, sample_image
from facestats.acquire.visibility import ShadowMaps
from facestats.errors import FormatError, ValidationError
from facestats.model.irradiance import exitance_from_radiance

__all__ = ["camera_sees", "patch_radiance", "read_radiance_image", "reference_radiance_scale", "write_radiance_image"]


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


def reference_radiance_scale(image, mask, reflectance, lights, point, normal) -> np.ndarray:
    """Factor per channel that turns an image's values into radiance, from a reference target in it (module docstring).

    The target is flat and matte (Lambertian, e.g. a diffuse reflectance standard or a grey card of known
    reflectance), photographed under the same lights and exposure as the object.  Its radiance is ρ E / π, with E
    the lights' irradiance at ``point`` on a plane of ``normal`` (cones and cuts of the lights apply; no Fresnel
    term, the target has no interface: :func:`facestats.acquire.lights.patch_irradiance` with η = 1, where
    F_t = 1; no shadowing, so keep the target out of the object's shadow), so the factor is
    ρ E / (π mean(image over ``mask``)).  Multiply the image by it (``--radiance-scale`` of
    ``facestats translucency``).

    Parameters
    ----------
    image : ndarray, shape (H, W) or (H, W, C)
        The image as recorded (linear, any scale: e.g. the merge's exp(g)/s).
    mask : array_like of bool, shape (H, W)
        The target's pixels (inside its edges: every one finite and > 0).
    reflectance : float or array_like, shape (3,)
        The target's diffuse reflectance ρ in (0, 1], one value or one per R, G, B.
    lights : list of lights (:mod:`facestats.acquire.lights`)
        As the object's (``load_lights``), in mm.
    point, normal : array_like, shape (3,)
        The target's centre (mm) and its unit normal, towards the camera side, in the lights' frame.

    Returns
    -------
    ndarray, shape (C,)
        The factor per channel (C = 1 for a grey image, fitted against the mean of the lights' R, G and B as
        :func:`facestats.pipeline.image_translucency.fit_image_translucency` does, so ρ and E are averaged alike).

    Raises
    ------
    ValidationError
        A mask of another shape or selecting no pixel, target pixels not finite or ≤ 0, a reflectance outside
        (0, 1], a normal not of unit length, an image of other than 1 or 3 channels, or a target the lights do not
        reach (E = 0: in any channel of an RGB image, in the channels' mean for a grey one).
    """
    from facestats.acquire.lights import patch_irradiance
    from facestats.acquire.patches import Patches
    from facestats.core.validate import as_finite, check_range, check_shape

    img = np.asarray(image, np.float64)
    img = img[..., None] if img.ndim == 2 else img
    if img.ndim != 3:
        raise ValidationError(f"image must have shape (H, W) or (H, W, C), got {np.shape(image)}")
    m = np.asarray(mask)
    if m.dtype != bool or m.shape != img.shape[:2]:
        raise ValidationError(
            f"mask must be a bool array of the image's shape {img.shape[:2]}, got {m.dtype} {m.shape}"
        )
    if not m.any():
        raise ValidationError("mask must select the target's pixels, got none")
    pixels = img[m]
    bad = np.count_nonzero(~(np.isfinite(pixels) & (pixels > 0)))
    if bad:
        raise ValidationError(
            f"image must be finite and > 0 over the target (mask), got {bad} of {pixels.size} values that are not "
            "(unrecorded or black pixels: draw the mask inside the target)"
        )
    rho = np.atleast_1d(as_finite(reflectance, "reflectance", dtype=np.float64))
    if rho.shape not in ((1,), (3,)):
        raise ValidationError(f"reflectance must be one value or one per R, G, B, got shape {np.shape(reflectance)}")
    check_range(rho, "reflectance", 0, 1, low_inclusive=False)
    target = Patches(
        check_shape(as_finite(point, "point", dtype=np.float64), "point", (3,))[None],
        check_shape(as_finite(normal, "normal", dtype=np.float64), "normal", (3,))[None],
        np.ones(1),
    )
    if img.shape[2] not in (1, 3):
        raise ValidationError(f"image must have 1 or 3 channels, got {img.shape[2]}")
    e = patch_irradiance(target, lights, eta=1.0, shadows=False)[0]
    radiance = rho * e / np.pi  # a Lambertian reflector's radiance, per R, G, B
    if img.shape[2] == 1:  # a grey camera: the mean of the channels, as the fit takes the lights' (a colour may be 0)
        radiance = radiance.mean(keepdims=True)
    if not np.all(radiance > 0):
        which = "in every channel of an RGB image" if img.shape[2] == 3 else "in the mean of R, G and B"
        raise ValidationError(
            f"point must be lit by the lights (irradiance > 0 {which} at the target), got {e.tolist()}: the target "
            "outside a spot or a cut, or its normal facing away from the lights"
            + ("; a light without a colour gives that channel nothing to scale" if np.any(e > 0) else "")
        )
    return radiance / pixels.mean(axis=0)
