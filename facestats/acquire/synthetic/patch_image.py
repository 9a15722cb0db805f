"""Image formation for patch renderings: what a pinhole camera records of patches with known radiance.

Each patch is a triangle of constant radiance (its corners, from
:func:`facestats.acquire.patches.mesh_patches`).  The patches are split into
sub-triangles small enough that at least ``samples`` of them fall into a pixel
(:func:`facestats.acquire.patches.subdivide_triangles`); each sub-triangle's
centroid is projected (:meth:`facestats.acquire.camera.PinholeCamera.project`),
kept if it faces the camera and passes the camera's shadow map
(:class:`facestats.acquire.visibility.ShadowMaps`), and a pixel records the
mean radiance of the samples that land in it (an area average, as a sensor
integrates over its pixel).  Pixels no sample reaches are NaN.  Work runs over
blocks of patches; per block the samples are binned with ``numpy.bincount``.

:func:`render_exitance_image` is the camera's image of a rendered scene: the
patches' exitance l (e.g. :func:`facestats.pipeline.suzuki_studies.render_scene`'s)
turned into the radiance each patch sends towards the camera (Suzuki eq. 15)
and rendered as above; :func:`facestats.acquire.scene.patch_radiance` reads it
back.
"""

from __future__ import annotations

import numpy as np

from facestats.acquire.camera import PinholeCamera
from facestats.acquire.patches import subdivide_triangles
from facestats.acquire.visibility import ShadowMaps
from facestats.core.validate import as_finite, check_integer
from facestats.errors import ValidationError
from facestats.model.irradiance import radiance_from_exitance

__all__ = ["render_patch_image", "render_exitance_image"]

#: Sub-triangle samples per block (bounds memory).
_BLOCK_SAMPLES = 2_000_000


def render_patch_image(camera: PinholeCamera, patches, radiance, *, samples=4, shadow_resolution=512) -> np.ndarray:
    """Radiance image (H, W, C) float32 of patches of known radiance (module docstring).

    Parameters
    ----------
    camera : PinholeCamera
    patches : facestats.acquire.patches.Patches
        With ``corners`` (the patch triangles).
    radiance : array_like, shape (m,) or (m, C)
        Radiance leaving each patch towards the camera, ≥ 0.
    samples : int
        Minimum samples per pixel side squared, about (≥ 1).
    shadow_resolution : int
        Side of the camera's shadow map.

    Returns
    -------
    ndarray, shape (H, W, C)
        Mean radiance per pixel; NaN where no patch is seen.
    """

    if patches.corners is None:
        raise ValidationError("patches must carry their triangles (corners) to be rendered into an image")
    rad = as_finite(radiance, "radiance", 0, None, dtype=np.float64)
    rad = rad[:, None] if rad.ndim == 1 else rad
    if rad.shape[0] != len(patches) or rad.ndim != 2:
        raise ValidationError(f"radiance must have shape ({len(patches)},) or ({len(patches)}, C), got {rad.shape}")
    check_integer(samples, "samples", 1)
    w, h = camera.image_size
    facing = np.einsum("mk,mk->m", patches.normal, camera.position - patches.centre) > 0
    footprint = float(camera.pixel_footprint(patches.centre[facing]).min()) if facing.any() else 1.0
    edge = float(np.linalg.norm(patches.corners - np.roll(patches.corners, 1, axis=1), axis=2).max())
    k = max(1, int(np.ceil(edge * np.sqrt(samples) / footprint)))
    maps = None
    if patches.has_mesh:
        maps = ShadowMaps(
            patches.mesh_vertices, patches.mesh_faces, camera.position[None], resolution=shadow_resolution
        )
    total = np.zeros((h * w, rad.shape[1]))
    count = np.zeros(h * w)
    idx = np.nonzero(facing)[0]
    step = max(1, _BLOCK_SAMPLES // (k * k))
    for start in range(0, idx.size, step):  # loop over blocks of patches, vectorised over their samples
        sel = idx[start : start + step]
        pts = subdivide_triangles(patches.corners[sel], k).mean(axis=2).reshape(-1, 3)
        owner = np.repeat(sel, k * k)
        pix, depth = camera.project(pts)
        ok = (depth > 0) & np.all(np.isfinite(pix), axis=1)
        ok &= (pix[:, 0] >= 0) & (pix[:, 1] >= 0) & (pix[:, 0] < w) & (pix[:, 1] < h)
        if maps is not None and ok.any():
            ok[ok] = maps.visible(pts[ok], patches.normal[owner[ok]])[:, 0]
        flat = np.floor(pix[ok, 1]).astype(np.int64) * w + np.floor(pix[ok, 0]).astype(np.int64)
        count += np.bincount(flat, minlength=h * w)
        for ch in range(rad.shape[1]):  # loop over channels (≤ 3)
            total[:, ch] += np.bincount(flat, weights=rad[owner[ok], ch], minlength=h * w)
    with np.errstate(invalid="ignore", divide="ignore"):
        img = np.where(count[:, None] > 0, total / count[:, None], np.nan)
    return img.reshape(h, w, rad.shape[1]).astype(np.float32)


def render_exitance_image(camera: PinholeCamera, patches, exitance, *, eta, samples=4, shadow_resolution=512):
    """The camera's radiance image (H, W, C) float32 of patches of known exitance (Suzuki et al. eq. 15).

    Each patch j sends L_o = F_t,o(η, cos θo) l_j / π towards the camera
    (Suzuki, Mukaigawa & Yagi eq. 15, :func:`facestats.model.irradiance.radiance_from_exitance`;
    F_t,o the unpolarised Fresnel transmittance, :func:`facestats.model.fresnel.fresnel_transmittance`),
    with cos θo = N_j·ω_o taken at the patch's centre (ω_o the unit vector from
    the centre to the camera, clipped to [0, 1]); each pixel holds the mean of
    its patches' L_o (:func:`render_patch_image`: an area average, shadow-mapped
    occlusion by the patches' mesh).  The inverse of
    :func:`facestats.acquire.scene.patch_radiance`, which reads l_j back at the
    patches' centres.

    Parameters
    ----------
    camera : PinholeCamera
    patches : facestats.acquire.patches.Patches
        With ``corners`` (the patch triangles); their mesh, if any, occludes.
    exitance : array_like, shape (m,) or (m, C)
        l_j per patch (and channel) in an irradiance unit, ≥ 0 (e.g. W mm⁻²: the unit of the lights' irradiance
        c, as :func:`facestats.acquire.synthetic.subsurface.render_exitance` gives it).
    eta : float
        Relative index of refraction of the medium (Suzuki: 1.3; skin 1.38): the η of the scene, which the
        estimate (``facestats translucency``, :func:`patch_radiance`) must use too.
    samples, shadow_resolution
        As :func:`render_patch_image`.

    Returns
    -------
    ndarray of float32, shape (H, W, C)
        Radiance in the unit of ``exitance`` per steradian (e.g. W mm⁻² sr⁻¹); (H, W) from the camera's
        ``image_size`` (W, H); C = 1 for an ``exitance`` of shape (m,), else its C channels, in order.  NaN in
        every channel where no patch is seen (facing away, outside the object, occluded).

    Raises
    ------
    ValidationError
        ``exitance`` of another shape, negative or not finite; an invalid ``eta``; patches without corners.
    """
    l = np.asarray(exitance)
    if l.ndim not in (1, 2) or l.shape[0] != len(patches):
        raise ValidationError(f"exitance must have shape ({len(patches)},) or ({len(patches)}, C), got {l.shape}")
    to_camera = camera.position - patches.centre
    cos_o = np.einsum("mk,mk->m", patches.normal, to_camera) / np.linalg.norm(to_camera, axis=1)
    radiance = radiance_from_exitance(l, np.clip(cos_o, 0, 1), eta)
    radiance = radiance[:, None] if radiance.ndim == 1 else radiance
    return render_patch_image(camera, patches, radiance, samples=samples, shadow_resolution=shadow_resolution)
