"""The fit pipeline: from a capture to a subject's skin parameters (Weyrich et al. 2006 §4-5, Fig. 3).

:func:`fit_lumitexels` runs stages 1-4 on a block of lumitexels (they are
independent per lumitexel), :func:`fit_subject` runs every stage on a capture —
block by block, so a full-resolution capture streams from zarr with bounded
memory, optionally spread over Dask workers — and returns an
:class:`xarray.Dataset` in the subject schema of :mod:`facestats.io.schema`,
ready for the store.  :func:`fit_population` fits many subjects: the contact
sensor profiles of all of them first (cheap) to get the population's σtrAvg
(§5.4), then every subject's maps.

Stages (functions of :mod:`facestats.model.fitting`):

1. diffuse normals by photometric stereo, per-camera micro-normals;
2. albedo by the stable minimum of eq. 9 (then refined, see
   :func:`facestats.model.fitting.refine_albedo`);
3. grey specular residual, eq. 10;
4. Torrance-Sparrow and Blinn-Phong fits, eq. 14, flags;
5. maps at the capture's resolution, push-pull hole filling, flagged texels
   filled from neighbours;
6. dipole fits of the sensor profiles, σtr and ℓd per site, σtrAvg;
7. α_avg, σ's and σa from α_avg and σtrAvg (inverse of eq. 16), modulation M.

Invalid samples (NaN or negative radiance, zero irradiance, occluded or unlit
samples — all NaN in the capture —, and samples beyond 80°) are masked and
counted; a texel with too few valid samples is flagged and filled, never NaN in
the output maps.
"""

from __future__ import annotations

import functools
import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass

import numpy as np

from facestats.acquire.geometry import uv_to_texel
from facestats.core.conventions import CHANNELS, SITES
from facestats.core.published import ETA_SKIN, GRAZING_LIMIT_DEG, SIGMA_TR_AVG
from facestats.core.validate import as_finite, check_choice, check_integer, check_shape
from facestats.core.version import __version__
from facestats.errors import FitError, ValidationError
from facestats.io.schema import FLAG_BITS, SCHEMA_VERSION, set_variable_attrs
from facestats.model import fitting
from facestats.model.dipole import check_dipole_eta

__all__ = [
    "FitSettings",
    "fit_lumitexels",
    "fit_sensor",
    "fit_subject",
    "fit_population",
    "predict_radiance",
    "held_out_camera_error",
    "camera_image",
    "LUMITEXEL_OUTPUTS",
]


@dataclass
class FitSettings:
    """Settings of the fit pipeline (recorded in each subject's provenance).

    Attributes
    ----------
    discard : int
        k of the stable minimum (eq. 9): smallest values discarded (≥ 0).
    grazing_penalty : float
        γ ≥ 0 of the grazing penalty of the stable minimum (growing from θ = 60°
        to 80°, :func:`facestats.model.fitting.albedo_stable_minimum`).
    refine_albedo : bool
        Re-estimate the albedo as the mean over specular-free samples (removes
        the low bias of the minimum of noisy samples; see
        :func:`facestats.model.fitting.refine_albedo`).
    max_angle_deg : float
        Samples with θi or θo beyond this are ignored (eq. 14: 80°), in (0, 90].
    min_samples : int
        Texels with fewer usable samples are flagged ``few_samples`` (≥ 2).
    max_relative_error : float
        Relative standard error above which a fit is flagged ``ill_conditioned`` (> 0).
    models : tuple of str
        Specular models to fit, at least one, each once; the first is fitted from
        the log-linear start, the others start from its result.
    exclude_cameras : tuple of int
        Cameras left out of the fit (e.g. one held out to validate renderings), ≥ 0.
    micro_normals : bool
        Keep the per-camera micro-normal maps (16 × 3 values per texel).
    block : int
        Lumitexels per block, ≥ 1 (memory per block ≈ block × 0.1 MB); best equal to
        the capture's zarr chunk (2048 by default), so no chunk is decoded twice.
    eta : float
        Relative index of refraction, in [1, 3].
    """

    discard: int = 2
    grazing_penalty: float = 1.0
    refine_albedo: bool = True
    max_angle_deg: float = GRAZING_LIMIT_DEG
    min_samples: int = 30
    max_relative_error: float = 0.25
    models: tuple = ("torrance_sparrow", "blinn_phong")
    exclude_cameras: tuple = ()
    micro_normals: bool = True
    block: int = 2048
    eta: float = ETA_SKIN

    def __post_init__(self):
        if isinstance(self.models, str):
            raise ValidationError(f"models must be a tuple of model names, got the string {self.models!r}")
        self.models = tuple(self.models)
        if isinstance(self.exclude_cameras, (int, np.integer)):
            raise ValidationError(f"exclude_cameras must be a tuple of camera indices, got {self.exclude_cameras!r}")
        self.exclude_cameras = tuple(check_integer(c, "exclude_cameras", 0) for c in self.exclude_cameras)
        if not self.models or len(set(self.models)) != len(self.models):
            raise ValidationError(f"models must name at least one model, each once, got {self.models!r}")
        for m in self.models:
            if m not in fitting.DEFAULT_BOUNDS:
                raise ValidationError(f"models must be among {list(fitting.DEFAULT_BOUNDS)}, got {m!r}")
        check_integer(self.discard, "discard", 0)
        check_integer(self.min_samples, "min_samples", 2)
        check_integer(self.block, "block", 1)
        as_finite(self.grazing_penalty, "grazing_penalty", 0, None)
        as_finite(self.max_angle_deg, "max_angle_deg", 0, 90, low_inclusive=False, unit="deg")
        as_finite(self.max_relative_error, "max_relative_error", 0, None, low_inclusive=False)
        check_dipole_eta(self.eta)


#: Per-lumitexel outputs of :func:`fit_lumitexels` (a model's four entries only when it is
#: fitted; ``micro_normal`` is added when requested).
LUMITEXEL_OUTPUTS = (
    "normal",
    "albedo",
    "albedo_min",
    "n_samples",
    "n_invalid",
    "n_grazing",
    "ts_rho_s",
    "ts_m",
    "ts_error",
    "ts_flag",
    "bp_rho_s",
    "bp_exponent",
    "bp_error",
    "bp_flag",
)

#: Prefix of each specular model's outputs, and the (ρs, lobe, error) maps of each prefix.
_MODEL_PREFIX = {"torrance_sparrow": "ts", "blinn_phong": "bp"}
_MAP_VARS = {"ts": ("ts_rho_s", "ts_m", "ts_error"), "bp": ("bp_rho_s", "bp_exponent", "bp_error")}


#: Lumitexels per piece inside :func:`fit_lumitexels`: about 1 MB per per-sample array, so each
#: stage's temporaries stay in the CPU cache (0.47 s against 0.60 s per 2048 lumitexels).
PIECE = 256


def fit_lumitexels(lt, settings: FitSettings | None = None) -> dict:
    """Stages 1-4 on a block of lumitexels (:class:`facestats.acquire.capture.Lumitexels`).

    The block's valid samples (minus ``settings.exclude_cameras``) are flattened
    into :class:`facestats.model.fitting.Samples`, one contiguous run per
    lumitexel; then: diffuse normals by photometric stereo (3 passes) and
    micro-normals; BRDF samples f_r (eq. 8) with the photometric normal; the
    albedo by the stable minimum (eq. 9), refined over specular-free samples if
    ``settings.refine_albedo``; the grey specular residual (eq. 10); and the
    batch fit of each of ``settings.models`` (eq. 14), the later ones started
    from the first.  Lumitexels are independent: a block runs in pieces of
    :data:`PIECE` lumitexels (cache-sized), concatenated.

    Returns
    -------
    dict of ndarray
        ``normal`` (n, 3), ``micro_normal`` (n, C, 3) if requested, ``albedo`` and
        ``albedo_min`` (n, 3; refined and stable-minimum albedo), ``n_samples``
        (usable samples), ``n_invalid`` (masked: NaN, negative, unlit, occluded, clipped),
        ``n_grazing`` (valid but beyond the angle limit of eq. 14), and for each model
        ``*_rho_s``, ``*_m``/``*_exponent``, ``*_error``, ``*_flag``.
    """
    st = settings or FitSettings()
    if lt.n <= PIECE:
        return _fit_piece(lt, st)
    parts = [_fit_piece(lt[a : a + PIECE], st) for a in range(0, lt.n, PIECE)]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _fit_piece(lt, st):
    """Stages 1-4 on lumitexels ``lt`` (:func:`fit_lumitexels`)."""
    valid = lt.valid
    if st.exclude_cameras:
        valid = valid.copy()
        valid[:, list(st.exclude_cameras), :] = False
    n_cam = lt.wo.shape[1]
    samples = fitting.Samples.from_grid(lt.wi, lt.wo, lt.irradiance, lt.radiance, valid)
    out = {"n_invalid": (~valid).reshape(lt.n, -1).sum(1)}
    # Stage 1: normals.
    normal, _ = fitting.photometric_normals(samples, lt.scan_normal, n_cam, eta=st.eta)
    out["normal"] = normal
    if st.micro_normals:
        out["micro_normal"] = fitting.micro_normals(samples, n_cam)
    # Stage 2: albedo from BRDF samples with the photometric normal (eq. 8).
    cos_i, cos_o, ft2 = fitting.fresnel_factors(samples, normal, st.eta)
    lim = np.float32(np.cos(np.radians(st.max_angle_deg)))
    use = (cos_i > lim) & (cos_o > lim)
    with np.errstate(invalid="ignore", divide="ignore"):
        f_r = samples.radiance / (samples.irradiance * np.maximum(cos_i, 0))  # eq. 8, channel-major (3, S)
    albedo_min, _ = fitting.albedo_stable_minimum(
        samples, f_r, cos_i, cos_o, ft2, use, discard=st.discard, grazing_penalty=st.grazing_penalty
    )
    albedo = np.where(np.isfinite(albedo_min), albedo_min, 0).astype(np.float32)
    out["n_samples"] = samples.count(use)
    out["n_grazing"] = samples.count(~use)
    if st.refine_albedo:
        # Stage 2b: the mean over specular-free samples removes the noise bias of the minimum.
        cos_half = (cos_i + cos_o) / np.sqrt(np.maximum(2 + 2 * samples.cos_io(), 1e-12))
        refined, n_ref = fitting.refine_albedo(samples, f_r, ft2, cos_half, use)
        ok = np.isfinite(refined).all(1) & (n_ref >= st.min_samples)
        albedo = np.where(ok[:, None], refined, albedo).astype(np.float32)
    # Stages 3-4: the specular residual (eq. 10) and the batch fit of each model (eq. 14).
    f_s = fitting.specular_residual(samples, f_r, albedo, ft2)
    fits = fitting.fit_specular_models(
        samples,
        normal,
        f_s,
        use,
        st.models,
        eta=st.eta,
        min_samples=st.min_samples,
        max_relative_error=st.max_relative_error,
        cos=(cos_i, cos_o),
    )
    few = out["n_samples"] < st.min_samples
    out["albedo"] = np.where(few[:, None], np.nan, albedo).astype(np.float32)
    out["albedo_min"] = albedo_min.astype(np.float32)
    for model, res in fits.items():
        key = _MODEL_PREFIX[model]
        k_rho, k_lobe, k_err = _MAP_VARS[key]
        out[k_rho], out[k_lobe], out[k_err], out[f"{key}_flag"] = res.rho_s, res.lobe, res.error, res.flags
    return out


def fit_sensor(capture, eta=ETA_SKIN):
    """Stage 6 for one capture: dipole fits of its three sensor profiles (per site and channel).

    Weighted by the recorded noise model (``sensor_profile_std``) when the capture
    has one, else the log-space fit (:func:`facestats.model.fitting.fit_translucency`).

    Returns
    -------
    TranslucencyFit
        Arrays of shape (site, channel).
    """
    r = capture.array("fiber_distance")
    prof = capture.array("sensor_profile")  # (site, fiber, channel)
    std = capture.array("sensor_profile_std")
    has_std = np.any(std > 0)
    return fitting.fit_translucency(r, np.moveaxis(prof, 1, 2), np.moveaxis(std, 1, 2) if has_std else None, eta=eta)


def _blocks_result(capture, settings, client=None, progress=False, workers=1):
    """Stages 1-4 over all blocks of a capture (on a Dask client or Dask's local scheduler), concatenated."""
    ranges = list(capture.blocks(settings.block))

    def run(a, b):
        return fit_lumitexels(capture.lumitexels(a, b), settings)

    if client is not None:
        futures = [client.submit(_fit_block_from_path, capture.path, a, b, settings, pure=False) for a, b in ranges]
        parts = client.gather(futures)
    elif workers > 1 and len(ranges) > 1:
        import dask

        if capture.path is not None:  # worker processes read their own blocks from disk
            tasks = [dask.delayed(_fit_block_from_path, pure=False)(capture.path, a, b, settings) for a, b in ranges]
            scheduler = "processes"
        else:
            tasks = [dask.delayed(run, pure=False)(a, b) for a, b in ranges]
            scheduler = "threads"
        parts = list(dask.compute(*tasks, scheduler=scheduler, num_workers=workers))
    else:
        it = ranges
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(ranges, desc=f"fit {capture.attrs.get('subject_id', '')}", unit="block")
        parts = [run(a, b) for a, b in it]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _fit_block_from_path(path, a, b, settings):
    from facestats.acquire.capture import open_capture

    try:  # a worker reuses its open capture across blocks while the group on disk is unchanged
        capture = _open_cached(str(path), os.stat(os.path.join(path, "zarr.json")).st_mtime_ns)
    except OSError:  # not a local directory store
        capture = open_capture(path)
    return fit_lumitexels(capture.lumitexels(a, b), settings)


@functools.lru_cache(maxsize=4)
def _open_cached(path, mtime_ns):
    """:func:`facestats.acquire.capture.open_capture`, cached per (path, modification time of its zarr.json)."""
    from facestats.acquire.capture import open_capture

    return open_capture(path)


def _averaged_maps(res, texel, size):
    """Every per-lumitexel float output of ``res`` averaged into (size, size[, 3]) maps, and where data landed.

    One grouping of the lumitexels by texel for all of them (:func:`facestats.model.fitting.scatter_to_map`);
    NaN where no lumitexel landed.
    """
    names = [name for name in ("albedo", "normal", *_MAP_VARS["ts"], *_MAP_VARS["bp"], "n_samples") if name in res]
    n = len(texel)
    columns = [np.asarray(res[name], np.float32).reshape(n, -1) for name in names]
    stacked, count = fitting.scatter_to_map(np.concatenate(columns, axis=1), texel, size)
    maps, col = {}, 0
    for name, c in zip(names, columns):
        maps[name] = stacked[..., col : col + c.shape[1]]
        maps[name] = maps[name] if c.shape[1] > 1 and name in ("albedo", "normal") else maps[name][..., 0]
        col += c.shape[1]
    return maps, count > 0


def _model_maps(values, flags, texel, face, has_data):
    """One model's maps with flagged and empty face texels filled from their neighbours (§5.3), and its flag map.

    ``values`` are the model's (size, size) maps (NaN where no lumitexel landed),
    ``flags`` the per-lumitexel fit flags; off the face everything is 0.
    """
    size = face.shape[0]
    fl = np.zeros((size, size), np.uint8)
    np.bitwise_or.at(fl, (texel[:, 0], texel[:, 1]), flags.astype(np.uint8))
    hole = face & ~has_data  # texels no lumitexel maps to (the map is finer than the mesh)
    bad = face & ((fl != 0) | hole)
    filled = fitting.fill_flagged(np.stack(values, axis=-1), bad, face)  # filled together: push-pull is linear
    fl[bad] |= FLAG_BITS["filled"]
    fl[~face] = 0
    return [np.where(face, filled[..., i], 0) for i in range(len(values))], fl


def _filled_map(values, face, has_data, unit=False):
    """A (size, size, 3) map push-pull filled over the face (renormalised if ``unit``), 0 off the face."""
    known = face & has_data & np.all(np.isfinite(values), axis=-1)
    out = fitting.push_pull(values, known, fill=face)
    if unit:
        out = out / np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-12)
    return np.where(face[..., None], out, 0)


def _micro_normal_map(micro, texel, face):
    """Per-camera micro-normal maps (camera, v, u, 3) from (lumitexel, camera, 3): NaN where unseen or off the face."""
    n, n_cam = micro.shape[:2]
    size = face.shape[0]
    micro[~face[texel[:, 0], texel[:, 1]]] = np.nan  # off the face: NaN like texels no camera saw
    mn, _ = fitting.scatter_to_map(micro.reshape(n, -1), texel, size)
    # scatter_to_map's (size, size, K) is a view of a (camera, component, v, u) array: reorder as a
    # view (no copy of what is 0.8 GB at full resolution).
    return np.moveaxis(np.moveaxis(mn, -1, 0).reshape(n_cam, 3, size, size), 1, -1)


def fit_subject(
    capture,
    sigma_tr_avg=None,
    settings: FitSettings | None = None,
    *,
    client=None,
    workers: int = 1,
    progress=False,
    sensor_fit=None,
):
    """Run the whole pipeline on one capture and return the subject Dataset.

    Parameters
    ----------
    capture : Capture or str
        The capture (:mod:`facestats.acquire.capture`) or the path of one on disk.
    sigma_tr_avg : array_like, shape (3,), optional
        The population's σtrAvg (mm⁻¹) for stage 7; default the published
        [0.5508, 0.9791, 1.5497] (use :func:`fit_population` to derive it from the
        subjects themselves).
    settings : FitSettings, optional
    client : dask.distributed.Client, optional
        Spread the lumitexel blocks over its workers (the capture must be on disk).
    workers : int
        Without a client: spread the blocks over this many local workers with
        Dask's local scheduler (processes reading their blocks from disk for a
        capture on disk, threads for one in memory).
    progress : bool
        Show a progress bar over blocks.
    sensor_fit : TranslucencyFit, optional
        Precomputed stage 6 result (as :func:`fit_population` passes).

    Returns
    -------
    xarray.Dataset
        Maps on (v, u[, channel | component]) at the capture's map size, sensor data
        and fits per site, subject-level scattering coefficients; provenance in attrs.
    """
    import xarray as xr

    from facestats.acquire.capture import Capture, open_capture

    if not isinstance(capture, Capture):
        capture = open_capture(capture)
    if client is not None and capture.path is None:
        raise ValidationError("client requires a capture on disk (pass a path or write it with Capture.to_zarr)")
    workers = check_integer(workers, "workers", 1)
    if sigma_tr_avg is not None:
        as_finite(sigma_tr_avg, "sigma_tr_avg", 0, None, low_inclusive=False, unit="mm^-1")
        check_shape(np.asarray(sigma_tr_avg), "sigma_tr_avg", (3,))
    st = settings or FitSettings()
    res = _blocks_result(capture, st, client=client, progress=progress, workers=workers)

    # Stage 5: maps.  The map jobs (micro-normals, the averaged maps, then per-model filling, albedo,
    # normals) run on a pool of ``workers`` threads (numpy releases the GIL in the heavy array work);
    # with one worker, one job at a time.
    size = capture.map_size
    region_map = capture.array("region_map")
    face = region_map > 0
    texel = uv_to_texel(capture.array("uv").astype(np.float64), size)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        jobs = {}
        if "micro_normal" in res:
            jobs["micro_normal"] = pool.submit(_micro_normal_map, res.pop("micro_normal"), texel, face)
        maps, has_data = pool.submit(_averaged_maps, res, texel, size).result()
        for key, map_vars in _MAP_VARS.items():
            if f"{key}_flag" in res:
                jobs[key] = pool.submit(
                    _model_maps, [maps[var] for var in map_vars], res[f"{key}_flag"], texel, face, has_data
                )
        jobs["albedo"] = pool.submit(_filled_map, maps["albedo"], face, has_data)
        jobs["normal"] = pool.submit(_filled_map, maps["normal"], face, has_data, unit=True)
        micro = jobs.pop("micro_normal").result() if "micro_normal" in jobs else None
        for key, job in jobs.items():
            if key in _MAP_VARS:
                filled, maps[f"{key}_flag"] = job.result()
                maps.update(zip(_MAP_VARS[key], filled))
            else:
                maps[key] = job.result()
    n_samples = maps.pop("n_samples")

    # Stage 6: sensor profiles.
    tf = fit_sensor(capture, st.eta) if sensor_fit is None else sensor_fit
    # Stage 7: subject scattering from α_avg and σtrAvg.
    stra = SIGMA_TR_AVG if sigma_tr_avg is None else np.asarray(sigma_tr_avg, np.float64)
    alb = np.clip(maps["albedo"], 1e-4, 1 - 1e-4)
    alb_avg, sp, sa, modulation = fitting.scattering_parameters(np.where(face[..., None], alb, 0), face, stra, st.eta)

    n = size
    data = {
        "region": (("v", "u"), region_map.astype(np.uint8)),
        "albedo": (("v", "u", "channel"), maps["albedo"].astype(np.float32)),
        "modulation": (("v", "u", "channel"), modulation.astype(np.float32)),
        "normal": (("v", "u", "component"), maps["normal"].astype(np.float32)),
        "n_samples": (("v", "u"), np.nan_to_num(n_samples).round().astype(np.int16)),
        "sensor_profile": (("site", "fiber", "channel"), capture.array("sensor_profile")),
        "sensor_profile_std": (("site", "fiber", "channel"), capture.array("sensor_profile_std")),
        "site_sigma_s_prime": (("site", "channel"), tf.sigma_s_prime),
        "site_sigma_a": (("site", "channel"), tf.sigma_a),
        "site_sigma_tr": (("site", "channel"), tf.sigma_tr),
        "site_sigma_s_prime_std": (("site", "channel"), tf.sigma_s_prime_std),
        "site_sigma_a_std": (("site", "channel"), tf.sigma_a_std),
        "site_sigma_tr_std": (("site", "channel"), tf.sigma_tr_std),
        "albedo_avg": (("channel",), alb_avg.astype(np.float64)),
        "sigma_s_prime": (("channel",), sp),
        "sigma_a": (("channel",), sa),
        "sigma_tr": (("channel",), stra.astype(np.float64)),
    }
    for key, map_vars in _MAP_VARS.items():
        if f"{key}_flag" in maps:
            for var in map_vars:
                data[var] = (("v", "u"), maps[var].astype(np.float32, copy=False))  # 0 off the face (stage 5)
            data[f"{key}_flag"] = (("v", "u"), maps[f"{key}_flag"])
    if micro is not None:
        data["micro_normal"] = (("camera", "v", "u", "component"), micro.astype(np.float32, copy=False))
    meta = capture.metadata
    face_n = int(face.sum())
    prov = {
        "source": capture.provenance.get("source", "capture"),
        "capture": capture.path or f"in-memory capture of {meta['subject_id']}",
        "capture_provenance": capture.provenance,
        "fit_settings": asdict(st),
        "sigma_tr_avg": [float(x) for x in stra],
        "software": f"facestats {__version__}",
        "schema_version": SCHEMA_VERSION,
        "counts": {
            "lumitexels": int(capture.n_lumitexels),
            "samples_used": int(res["n_samples"].sum()),
            "samples_masked": int(res["n_invalid"].sum()),
            "samples_grazing": int(res["n_grazing"].sum()),
            "ts_flagged_texels": int((maps.get("ts_flag", np.zeros(1)) != 0).sum()),
            "face_texels": face_n,
        },
    }
    ds = xr.Dataset(
        data,
        coords={
            "u": (np.arange(n) + 0.5) / n,
            "v": (np.arange(n) + 0.5) / n,
            "channel": list(CHANNELS),
            "site": list(SITES),
            "component": ["x", "y", "z"],
            "fiber_distance": ("fiber", capture.array("fiber_distance")),
        },
        attrs={
            "subject_id": str(meta["subject_id"]),
            "person_id": str(meta.get("person_id", meta["subject_id"])),
            "age": int(meta["age"]),
            "gender": str(meta["gender"]),
            "skin_type": int(meta["skin_type"]),
            "condition": str(meta["condition"]),
            "provenance": json.dumps(prov, sort_keys=True, default=str),
        },
    )
    return set_variable_attrs(ds)


def _fit_capture_task(capture, sigma_tr_avg, settings, sensor_fit):
    return fit_subject(capture, sigma_tr_avg, settings, sensor_fit=sensor_fit)


def fit_population(
    captures,
    settings: FitSettings | None = None,
    *,
    client=None,
    scheduler="processes",
    num_workers=None,
    progress=False,
):
    """Fit many captures: σtrAvg from the sensor fits (§5.4), then every subject (in parallel).

    σtrAvg is the mean cheek and forehead σtr over the captures of condition
    "normal" (:func:`facestats.model.fitting.population_sigma_tr_avg`).

    Parameters
    ----------
    captures : sequence of Capture or str
        Captures or paths of captures on disk.
    settings : FitSettings, optional
    client : dask.distributed.Client, optional
        Run subjects on a distributed cluster (captures must be paths, readable by
        the workers).
    scheduler : {"processes", "threads", "synchronous"}
        Dask's local scheduler when no client is given.
    num_workers : int, optional
        Local workers (default: number of cores).
    progress : bool
        Show a progress bar over subjects.

    Returns
    -------
    datasets : list of xarray.Dataset
    sigma_tr_avg : ndarray, shape (3,)
    """
    from facestats.acquire.capture import Capture, open_capture

    check_choice(scheduler, "scheduler", ("processes", "threads", "synchronous"))
    if num_workers is not None:
        check_integer(num_workers, "num_workers", 1)
    st = settings or FitSettings()
    caps = [c if isinstance(c, Capture) else open_capture(c) for c in captures]
    if not caps:
        raise ValidationError("captures must contain at least one capture, got none")
    fits = [fit_sensor(c, st.eta) for c in caps]
    sites = list(SITES)
    condition_normal = [i for i, c in enumerate(caps) if c.attrs.get("condition", "normal") == "normal"]
    if not condition_normal:
        raise ValidationError(
            "captures must include at least one subject of condition 'normal' (σtrAvg is their mean), got none"
        )
    tr = np.stack([fits[i].sigma_tr for i in condition_normal])
    stra = fitting.population_sigma_tr_avg(tr, sites)
    if client is not None:
        futs = [
            client.submit(_fit_capture_task, c.path if c.path else c, stra, st, f, pure=False)
            for c, f in zip(caps, fits)
        ]
        if progress:
            from distributed import progress as dprogress

            dprogress(futs)
        return client.gather(futs), stra
    if scheduler == "synchronous" or len(caps) == 1:
        it = zip(caps, fits)
        if progress:
            from tqdm.auto import tqdm

            it = tqdm(list(it), desc="fit", unit="subject")
        return [fit_subject(c, stra, st, sensor_fit=f) for c, f in it], stra
    import dask

    tasks = [dask.delayed(_fit_capture_task)(c.path if c.path else c, stra, st, f) for c, f in zip(caps, fits)]
    if progress:
        from dask.diagnostics import ProgressBar

        with ProgressBar():
            out = dask.compute(*tasks, scheduler=scheduler, num_workers=num_workers)
    else:
        out = dask.compute(*tasks, scheduler=scheduler, num_workers=num_workers)
    if any(o is None for o in out):
        raise FitError("a subject fit returned nothing")
    return list(out), stra


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
    from facestats.io.schema import modulation as _modulation
    from facestats.model.skin import SPECULAR_MODELS, SubsurfaceTransport, skin_radiance

    check_choice(specular, "specular", SPECULAR_MODELS)
    if "normal" not in subject.data_vars:
        raise ValidationError("subject must hold the fitted 'normal' map (a Dataset from fit_subject)")
    lt = capture.lumitexels(start, stop)
    texel = uv_to_texel(lt.uv, int(subject.sizes["u"]))
    v, u = texel[:, 0], texel[:, 1]
    normal = np.asarray(subject["normal"].values)[v, u].astype(np.float64)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    mod = np.asarray(_modulation(subject).values)[v, u]
    rho_var, lobe_var, _ = _MAP_VARS[_MODEL_PREFIX[specular]]
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

    Parameters
    ----------
    values : ndarray, shape (n, C, L, 3)
        E.g. the output of :func:`predict_radiance`.
    capture : Capture
    camera, light : int
    channel : int, optional
        Channel to return; default all three (RGB image).

    Returns
    -------
    ndarray, shape (H, W[, 3])
        NaN where no lumitexel projects.
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
    vals = values[:, camera, light, :] if channel is None else values[:, camera, light, channel : channel + 1]
    img = np.full((n_px, n_px, vals.shape[-1]), np.nan)
    img[iy[ok], ix[ok]] = vals[ok]
    return img if channel is None else img[..., 0]
