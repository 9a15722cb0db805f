"""Rendering a fitted subject back into a capture's cameras, to validate the fit (Weyrich et al. 2006 §6).

:func:`predict_radiance` evaluates the fitted skin model for a capture's
calibrated lights and cameras; :func:`held_out_camera_error` compares it with a
camera left out of the fit; :func:`camera_image` splats per-sample values into
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


def camera_image(values, capture, camera: int, light: int, channel=None):
    """Splat per-lumitexel sample values of one (camera, light) into the camera's image (for figures).

    The image crops the face's bounding box at about one pixel per lumitexel; a pixel holds the mean of the
    finite values of the lumitexels that project into it (a sample invalid in this camera, NaN, never hides a
    valid one in the same pixel; until 2026-12-07 the last lumitexel in a pixel won, NaN or not).

    Parameters
    ----------
    values : ndarray, shape (n, C, L, 3) or (n, 3)
        E.g. the output of :func:`predict_radiance`, or values already taken
        for this camera and light (one RGB value per lumitexel).
    capture : Capture
    camera, light : int
    channel : int, optional
        Channel to return; default all three (RGB image).

    Returns
    -------
    ndarray, shape (H, W[, 3])
        NaN where no lumitexel with a finite value projects.
    """
    check_integer(camera, "camera", 0, capture.dome.n_cameras - 1)
    check_integer(light, "light", 0, capture.dome.n_leds - 1)
    if channel is not None:
        check_integer(channel, "channel", 0, 2)
    pos = capture.array("position").astype(np.float64)[: values.shape[0]]
    _, _, pix = capture.dome.view(pos, cameras=[camera])
    x, y = pix[:, 0, 0], pix[:, 0, 1]
    ok = np.isfinite(x) & np.isfinite(y)
    # Crop to the face's bounding box, about one image pixel per lumitexel.
    x0, x1 = np.floor(x[ok].min()) - 2, np.ceil(x[ok].max()) + 2
    y0, y1 = np.floor(y[ok].min()) - 2, np.ceil(y[ok].max()) + 2
    n_px = int(np.clip(np.sqrt(ok.sum()) * 1.6, 16, 1024))
    res = n_px / max(x1 - x0, y1 - y0)
    ix = np.clip(((x - x0) * res).astype(np.int64), 0, n_px - 1)
    iy = np.clip(((y - y0) * res).astype(np.int64), 0, n_px - 1)
    sel = values if values.ndim == 2 else values[:, camera, light, :]
    vals = np.asarray(sel if channel is None else sel[:, channel : channel + 1], np.float64)
    good = ok & np.all(np.isfinite(vals), axis=1)
    pixel = iy[good] * n_px + ix[good]
    sums = np.zeros((n_px * n_px, vals.shape[1]))
    np.add.at(sums, pixel, vals[good])
    count = np.bincount(pixel, minlength=n_px * n_px)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        img = np.where(count > 0, sums / count, np.nan).reshape(n_px, n_px, vals.shape[1])
    return img if channel is None else img[..., 0]
