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

__all__ = ["predict_radiance", "held_out_camera_error", "camera_image", "surface_triangles"]


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


def surface_triangles(position, uv):
    """Triangles of lumitexels on their surface: the Delaunay triangulation of their UVs, kept where on the surface.

    The UV chart is the surface's parametrisation, so neighbours in UV are neighbours on the surface, and a
    triangle of the UV triangulation follows the surface whatever the surface's folds in a camera's image.  A
    triangle is kept when it lies on the surface: its longest edge in 3-D is at most :data:`MAX_GAP` times the
    largest spacing of its corners (each lumitexel's distance to the nearest other position in 3-D; a position
    held twice, as at a UV seam, is one sample), so triangles across a hole of the face (the eyes), across the
    gaps between UV islands or across the UV chart's concave boundary are left out.

    Parameters
    ----------
    position : ndarray, shape (n, 3)
        Lumitexel positions, mm.
    uv : ndarray, shape (n, 2)
        Their texture coordinates.

    Returns
    -------
    faces : ndarray of int64, shape (F, 3)
        Lumitexel indices of the triangles on the surface (F = 0 for fewer than three lumitexels or UVs on a line).
    spacing : ndarray of float64, shape (n,)
        Each lumitexel's spacing, mm (inf for a lone position).
    """
    from scipy.spatial import Delaunay, QhullError, cKDTree

    position = np.asarray(position, np.float64)
    surface = np.unique(position, axis=0)
    spacing = cKDTree(surface).query(position, k=2)[0][:, 1] if len(surface) > 1 else np.full(len(position), np.inf)
    try:
        tri = Delaunay(np.asarray(uv, np.float64)[:, :2])
    except (QhullError, ValueError):  # fewer than three lumitexels, or UVs all on a line
        return np.zeros((0, 3), np.int64), spacing
    corners = position[tri.simplices]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(1)
    on_surface = longest <= MAX_GAP * spacing[tri.simplices].max(1)
    return tri.simplices[on_surface].astype(np.int64), spacing


def camera_image(values, capture, camera: int, light: int, channel=None, *, size=None):
    """Per-lumitexel sample values of one (camera, light) as the camera's image (for figures).

    The image crops the face's bounding box in the camera at ``size`` × ``size`` pixels.  The lumitexels in the
    camera's frame are triangulated on the surface (:func:`surface_triangles`: in UV, whatever their values) and
    the triangles drawn with a depth buffer (:func:`facestats.acquire.visibility.nearest_triangle`): each pixel
    shows the surface nearest the camera, as a photograph does.  A pixel holds the linear interpolation of its
    triangle's finite corner values, the barycentric weights renormalised over them: a corner with a NaN value
    (hidden from the camera, unlit, invalid) gives way to its finite neighbours across the triangles it shares
    with them, so the visible surface beside a hidden lumitexel (a cheek behind the nose's silhouette) is
    filled, and a region of NaN lumitexels (a shadow) stays empty but for its rim of triangles, which take the
    values of their lit corners.  A pixel no triangle covers holds the value of its nearest finite lumitexel in
    the image within half that lumitexel's spacing there (the patch it stands for, beyond the surface's
    boundary).  Other pixels (holes of the face, the background) are NaN.

    Triangles facing away from the camera (the far side of the skin, seen through a hole of the face) are not
    drawn.  Until 2026-12-08 the lumitexels with finite values were triangulated in the image (Delaunay of their
    projections), which connected lumitexels across the surface's folds, and triangles across a step in depth
    were left out: default S001's probe render in camera 5 had 23 enclosed empty components (169 pixels) along
    the nose, the cheek and the eye; 7 now (75 pixels), the face's own holes (74 pixels: the eyes, the mouth's
    corners, a sliver of the chin where the UV chart stretches a triangle past :data:`MAX_GAP`) but for one pixel
    (``benchmarks/bench_export.py`` ``bench_validation_images``).  Until 2026-12-07 each lumitexel was splatted
    into one pixel of a grid of about one pixel per lumitexel: 43-49 % of the pixels inside the face of default
    S003's probe renders were empty.

    Parameters
    ----------
    values : ndarray, shape (n, C, L, 3) or (n, 3)
        E.g. the output of :func:`predict_radiance`, or values already taken
        for this camera and light (one RGB value per lumitexel).
    capture : Capture
        Its first n lumitexels' ``position`` and ``uv`` and its ``dome``.
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
    from scipy.spatial import cKDTree

    from facestats.acquire.visibility import nearest_triangle

    check_integer(camera, "camera", 0, capture.dome.n_cameras - 1)
    check_integer(light, "light", 0, capture.dome.n_leds - 1)
    if channel is not None:
        check_integer(channel, "channel", 0, 2)
    n = values.shape[0]
    pos = capture.array("position").astype(np.float64)[:n]
    _, _, pix = capture.dome.view(pos, cameras=[camera])
    xy = pix[:, 0, :2]
    ok = np.isfinite(xy).all(1)
    n_px = int(np.clip(4 * np.sqrt(ok.sum()), 64, 1024)) if size is None else check_integer(size, "size", 16, 2048)
    sel = values if values.ndim == 2 else values[:, camera, light, :]
    vals = np.asarray(sel if channel is None else sel[:, channel : channel + 1], np.float64)
    img = np.full((n_px * n_px, vals.shape[1]), np.nan)
    finite = ok & np.all(np.isfinite(vals), axis=1)
    if not finite.any():
        return _image_shape(img, n_px, channel)
    # Crop to the face's bounding box (a margin of 2 % of its side); image coordinates in pixels of the crop.
    lo, hi = xy[ok].min(0), xy[ok].max(0)
    side = max(float((hi - lo).max()), 1e-9) * 1.04
    pixel = side / n_px
    corner = 0.5 * (lo + hi) - side / 2
    # A lumitexel held twice (same position and UV: a scan's triangle soup) is one vertex: its finite copies' mean.
    frame = np.flatnonzero(ok)
    uv = capture.array("uv")[:n][frame].astype(np.float64)
    _, first, vertex = np.unique(np.c_[pos[frame], uv], axis=0, return_index=True, return_inverse=True)
    vertex = vertex.ravel()
    count = np.bincount(vertex, finite[frame], len(first))
    sums = np.stack([np.bincount(vertex, np.where(finite[frame], vals[frame, c], 0.0), len(first))
                     for c in range(vals.shape[1])], 1)  # fmt: skip
    good = count > 0
    known = sums / np.maximum(count, 1)[:, None]
    frame = frame[first]
    pts, pts3, uv = (xy[frame] - corner) / pixel, pos[frame], uv[first]
    depth = ((pts3 - capture.dome.camera_position[camera]) @ capture.dome.camera_rotation[camera].T)[:, 2]
    faces, spacing3 = surface_triangles(pts3, uv)
    # Back faces culled: a triangle whose normal (its corners' cross product, turned to the side of their scan
    # normals) faces away from the camera is the far side of the skin, seen only through a hole of the face.
    scan_normal = capture.array("scan_normal")[:n][frame].astype(np.float64)
    corners = pts3[faces]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normal *= np.sign(np.einsum("fk,fk->f", normal, scan_normal[faces].sum(1)))[:, None]
    faces = faces[np.einsum("fk,fk->f", normal, capture.dome.camera_position[camera] - corners.mean(1)) > 0]
    tri = nearest_triangle(pts[:, 0], pts[:, 1], depth, faces, n_px, n_px)[0].ravel()
    covered = np.flatnonzero(tri >= 0)
    corners = faces[tri[covered]]  # (K, 3) lumitexels of each covered pixel's triangle
    centre = np.stack([covered % n_px, covered // n_px], 1) + 0.5
    a, b, c = pts[corners[:, 0]], pts[corners[:, 1]], pts[corners[:, 2]]
    den = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
    l0 = ((b[:, 1] - c[:, 1]) * (centre[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (centre[:, 1] - c[:, 1])) / den
    l1 = ((c[:, 1] - a[:, 1]) * (centre[:, 0] - c[:, 0]) + (a[:, 0] - c[:, 0]) * (centre[:, 1] - c[:, 1])) / den
    weights = np.clip(np.c_[l0, l1, 1 - l0 - l1], 0, 1) * good[corners]
    total = weights.sum(1)
    fill = total > 0
    img[covered[fill]] = np.einsum("nk,nkc->nc", weights[fill] / total[fill, None], known[corners[fill]])
    # Beyond the triangles, each finite lumitexel's patch: within half its spacing in the image (its nearest
    # neighbour's distance there, at most its surface spacing seen face-on at its depth) or half a pixel.
    empty = np.ones(n_px * n_px, bool)
    empty[covered] = False
    face_on = capture.dome.camera_matrix[camera][0, 0] / depth / pixel  # crop pixels per mm
    spacing = spacing3 * face_on
    flat = np.unique(pts, axis=0)
    if len(flat) > 1:
        spacing = np.minimum(cKDTree(flat).query(pts, k=2)[0][:, 1], spacing)
    lumi = np.flatnonzero(good)
    rest = np.flatnonzero(empty)
    dist, nearest = cKDTree(pts[lumi]).query(np.stack([rest % n_px, rest // n_px], 1) + 0.5)
    patch = dist <= np.maximum(0.5 * spacing[lumi[nearest]], 0.5)
    img[rest[patch]] = known[lumi[nearest[patch]]]
    return _image_shape(img, n_px, channel)


def _image_shape(img, n_px, channel):
    img = img.reshape(n_px, n_px, -1)
    return img if channel is None else img[..., 0]
