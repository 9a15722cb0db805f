"""Rendering a fitted subject back into a capture's cameras, to validate the fit (Weyrich et al. 2006 §6).

:func:`predict_radiance` evaluates the fitted skin model for a capture's
calibrated lights and cameras; :func:`held_out_camera_error` compares it with a
camera left out of the fit; :func:`camera_image` interpolates per-sample values into
a camera's image for figures.
"""

from __future__ import annotations

import numpy as np

from facestats.core.published import ETA_SKIN, GRAZING_LIMIT_DEG
from facestats.core.validate import as_finite, check_choice, check_integer
from facestats.errors import ValidationError
from facestats.face.geometry import uv_to_texel
from facestats.io.schema import modulation as _modulation
from facestats.model.skin import SPECULAR_MODELS, SubsurfaceTransport, skin_radiance
from facestats.pipeline.settings import MAP_VARS, MODEL_PREFIX

__all__ = ["predict_radiance", "held_out_camera_error", "camera_image"]


def predict_radiance(
    subject,
    capture,
    start: int = 0,
    stop: int | None = None,
    *,
    specular: str = "torrance_sparrow",
    eta: float = ETA_SKIN,
):
    """Radiance the fitted skin model predicts for a capture's samples (for validation and rendering).

    The fitted maps of ``subject`` (a Dataset from :func:`fit_subject`) are sampled
    at the lumitexels ``start:stop`` of ``capture`` and rendered through
    :func:`facestats.model.skin.skin_radiance` with the capture's calibrated
    lights and cameras: specular from the fitted ``specular`` model with the
    diffuse normal map, diffuse from the fitted albedo (modulation α/α_avg and
    the subject's σ's, σa in the flat-patch transport).  Visibility is the
    capture's: samples that are invalid in the capture are NaN.

    Parameters
    ----------
    subject : xarray.Dataset
        A map subject (the fitted ``normal`` map is required).
    capture : Capture
    start, stop : int
        Lumitexel range.
    specular : {"torrance_sparrow", "blinn_phong"}
    eta : float
        Relative index of refraction.

    Returns
    -------
    predicted, measured : ndarray, shape (n, C, L, 3)
        Radiance in the capture's dome units per sr.
    """

    check_choice(specular, "specular", SPECULAR_MODELS)
    if "normal" not in subject.data_vars:
        raise ValidationError("subject must hold the fitted 'normal' map (a Dataset from fit_subject)")
    lt = capture.lumitexels(start, stop)
    texel = uv_to_texel(lt.uv, int(subject.sizes["u"]))
    v, u = texel[:, 0], texel[:, 1]
    normal = np.asarray(subject["normal"].values)[v, u].astype(np.float64)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    mod = np.asarray(_modulation(subject).values)[v, u]
    rho_var, lobe_var, _ = MAP_VARS[MODEL_PREFIX[specular]]
    rho = np.asarray(subject[rho_var].values)[v, u]
    rough = np.asarray(subject[lobe_var].values)[v, u]
    cos_i = np.einsum("nk,nlk->nl", normal, lt.wi)
    irr = lt.irradiance * np.maximum(cos_i, 0)[..., None]
    transport = SubsurfaceTransport(subject["sigma_s_prime"].values, subject["sigma_a"].values, eta)
    pred = skin_radiance(
        normal,
        lt.wi.astype(np.float64),
        irr,
        lt.wo.astype(np.float64),
        rho_s=rho,
        roughness=rough,
        modulation=mod,
        subsurface=transport,
        specular=specular,
        eta=eta,
    )
    valid = lt.valid
    return np.where(valid[..., None], pred, np.nan), np.where(valid[..., None], lt.radiance.astype(np.float32), np.nan)


def held_out_camera_error(
    subject, capture, camera: int, *, specular: str = "torrance_sparrow", max_angle_deg: float = GRAZING_LIMIT_DEG
):
    """Relative RMSE of the model's prediction against a camera (ideally one left out of the fit).

    RMSE over the valid samples of ``camera`` whose θi and θo (about the fitted
    normal) lie within ``max_angle_deg`` — the domain eq. 14 fits — and all
    channels, divided by the RMS of the measured radiance.

    Parameters
    ----------
    subject : xarray.Dataset
        A fitted map subject (its ``normal`` and the BRDF maps of ``specular``).
    capture : Capture
        The capture the subject was fitted from (or a re-simulation of it).
    camera : int
        Camera index, 0 … ``capture.dome.n_cameras`` − 1.
    specular : {"torrance_sparrow", "blinn_phong"}
        Specular model of the prediction (:func:`predict_radiance`).
    max_angle_deg : float
        Largest θi and θo counted, degrees in (0, 90] (default: the fit's 80°).

    Returns
    -------
    float
        RMS of (predicted − measured) over RMS of measured, dimensionless.

    Raises
    ------
    ValidationError
        A camera out of range, an angle outside (0, 90], or no valid sample within it.
    """
    check_integer(camera, "camera", 0, capture.dome.n_cameras - 1)
    as_finite(max_angle_deg, "max_angle_deg", 0, 90, low_inclusive=False, unit="deg")
    pred, meas = predict_radiance(subject, capture, specular=specular)
    lt = capture.lumitexels()
    texel = uv_to_texel(lt.uv, int(subject.sizes["u"]))
    normal = np.asarray(subject["normal"].values)[texel[:, 0], texel[:, 1]]
    lim = np.cos(np.radians(max_angle_deg))
    inside = (np.einsum("nk,nlk->nl", normal, lt.wi) > lim) & (np.einsum("nk,nk->n", normal, lt.wo[:, camera]) > lim)[
        :, None
    ]
    p, m = pred[:, camera], meas[:, camera]
    ok = np.isfinite(p) & np.isfinite(m) & inside[..., None]
    if not ok.any():
        raise ValidationError(f"camera {camera} has no valid sample in this capture")
    return float(np.sqrt(np.mean((p[ok] - m[ok]) ** 2)) / np.sqrt(np.mean(m[ok] ** 2)))


#: Longest triangle edge on the surface that :func:`camera_image` interpolates across, in its corners' spacings.
MAX_GAP = 3.0


def camera_image(values, capture, camera: int, light: int, channel=None, *, size=None):
    """Per-lumitexel sample values of one (camera, light) as the camera's image (for figures).

    The image crops the face's bounding box in the camera at ``size`` × ``size`` pixels.  A pixel inside a
    triangle of the Delaunay triangulation of the finite values' projections (:class:`scipy.spatial.Delaunay`)
    holds their linear interpolation, if the triangle lies on the surface: its longest edge in 3-D is at most
    :data:`MAX_GAP` times the largest spacing of its corners (each lumitexel's distance to its nearest neighbour
    in 3-D), so triangles across a hole of the face or a step in depth (a silhouette in front of the surface
    behind it) are left out; a pixel within half its nearest lumitexel's spacing in the image (the patch the
    lumitexel stands for) holds that lumitexel's value.  Other pixels are NaN: shadows, unlit and hidden
    lumitexels (NaN values), holes and the background stay empty, and a NaN value never hides a finite one.
    Until 2026-12-07 each lumitexel was splatted into one pixel of a grid of about one pixel per lumitexel: the
    projections are uneven (foreshortening), so 43-49 % of the pixels inside the face of default S003's probe
    renders in cameras 0, 5 and 9 were empty; 2.9-3.2 % now, the eyes' holes included
    (``benchmarks/bench_export.py`` ``bench_validation_images``).

    Parameters
    ----------
    values : ndarray, shape (n, C, L, 3) or (n, 3)
        E.g. the output of :func:`predict_radiance`, or values already taken
        for this camera and light (one RGB value per lumitexel).
    capture : Capture
    camera, light : int
    channel : int, optional
        Channel to return; default all three (RGB image).
    size : int, optional
        Image side in pixels, in [16, 2048]; default 4 √n (n the lumitexels in the camera's frame), within
        [64, 1024].  The work arrays take about 10 times the image: 0.27 GB at 1024, 1.0 GB at 2048.

    Returns
    -------
    ndarray, shape (size, size[, 3])
        NaN where no finite value is near (see above).
    """
    from scipy.spatial import Delaunay, QhullError, cKDTree

    check_integer(camera, "camera", 0, capture.dome.n_cameras - 1)
    check_integer(light, "light", 0, capture.dome.n_leds - 1)
    if channel is not None:
        check_integer(channel, "channel", 0, 2)
    pos = capture.array("position").astype(np.float64)[: values.shape[0]]
    _, _, pix = capture.dome.view(pos, cameras=[camera])
    xy = pix[:, 0, :2]
    ok = np.isfinite(xy).all(1)
    n_px = int(np.clip(4 * np.sqrt(ok.sum()), 64, 1024)) if size is None else check_integer(size, "size", 16, 2048)
    sel = values if values.ndim == 2 else values[:, camera, light, :]
    vals = np.asarray(sel if channel is None else sel[:, channel : channel + 1], np.float64)
    img = np.full((n_px * n_px, vals.shape[1]), np.nan)
    if not ok.any():
        return _image_shape(img, n_px, channel)
    # Crop to the face's bounding box (a margin of 2 % of its side); pixel centres in the camera's pixel units.
    lo, hi = xy[ok].min(0), xy[ok].max(0)
    side = max(float((hi - lo).max()), 1e-9) * 1.04
    corner = 0.5 * (lo + hi) - side / 2
    centres = corner + (np.stack(np.meshgrid(np.arange(n_px), np.arange(n_px)), -1).reshape(-1, 2) + 0.5) * (
        side / n_px
    )
    good = ok & np.all(np.isfinite(vals), axis=1)
    if not good.any():
        return _image_shape(img, n_px, channel)
    pts, known, pts3 = xy[good], vals[good], pos[good]
    tree = cKDTree(pts)
    dist, nearest = tree.query(centres)
    pixel = side / n_px
    # Each lumitexel's own spacing on the surface (mm) and in the image (pixels): its nearest neighbour's distance
    # there, at most its surface spacing seen face-on at its depth (a lumitexel alone in the image is a patch).
    depth = ((pts3 - capture.dome.camera_position[camera]) @ capture.dome.camera_rotation[camera].T)[:, 2]
    face_on = capture.dome.camera_matrix[camera][0, 0] / depth  # pixels per mm
    # Every lumitexel in the frame samples the surface, whatever its value; a position held twice (a scan's vertices
    # split at UV seams, or one per triangle) is one sample: the spacing is to the nearest other position.
    surface = np.unique(pos[ok], axis=0)
    spacing3 = cKDTree(surface).query(pts3, k=2)[0][:, 1] if len(surface) > 1 else np.full(len(pts3), np.inf)
    spacing = spacing3 * face_on
    flat = np.unique(pts, axis=0)
    if len(flat) > 1:
        spacing = np.minimum(cKDTree(flat).query(pts, k=2)[0][:, 1], spacing)
    edge = dist <= np.maximum(0.5 * spacing[nearest], 0.5 * pixel)  # the patch a lumitexel stands for
    img[edge] = known[nearest[edge]]
    try:
        tri = Delaunay(pts)
    except (QhullError, ValueError):  # fewer than three points, or all on a line: the nearest value only
        return _image_shape(img, n_px, channel)
    # A triangle whose longest edge on the surface (mm) exceeds MAX_GAP times its corners' own spacing spans a gap,
    # a hole of the face or a step in depth (a silhouette over the surface behind it), not the surface.
    corners = pts3[tri.simplices]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(1)
    on_surface = longest <= MAX_GAP * spacing3[tri.simplices].max(1)
    simplex = tri.find_simplex(centres)
    hit = simplex >= 0
    hit[hit] = on_surface[simplex[hit]]
    inside, simplex = np.flatnonzero(hit), simplex[hit]
    affine = tri.transform[simplex]  # barycentric coordinates: T (x − r)
    b = np.einsum("nij,nj->ni", affine[:, :2], centres[inside] - affine[:, 2])
    weights = np.c_[b, 1 - b.sum(1)]
    img[inside] = np.einsum("nk,nkc->nc", weights, known[tri.simplices[simplex]])
    return _image_shape(img, n_px, channel)


def _image_shape(img, n_px, channel):
    img = img.reshape(n_px, n_px, -1)
    return img if channel is None else img[..., 0]
