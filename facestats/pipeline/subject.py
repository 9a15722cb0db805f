"""The fit pipeline on one capture: stages 1-7 of Weyrich et al. 2006 §4-5 (Fig. 3), to a subject Dataset.

:func:`fit_subject` runs stages 1-4 block by block (a full-resolution capture
streams from zarr with bounded memory, optionally spread over Dask workers),
then the maps (stage 5), the dipole fits of the sensor profiles (stage 6) and
the subject's scattering coefficients (stage 7), and returns an
:class:`xarray.Dataset` in the subject schema of :mod:`facestats.io.schema`,
ready for the store.
"""

from __future__ import annotations

import functools
import json
import os
from dataclasses import asdict

import numpy as np

from facestats.acquire.capture import Capture, open_capture
from facestats.core.conventions import CHANNELS, COMPONENTS, SITES
from facestats.core.progress import progress_bar
from facestats.core.published import ETA_SKIN, SIGMA_TR_AVG
from facestats.core.validate import as_finite, check_integer, check_shape
from facestats.core.version import __version__
from facestats.errors import ValidationError
from facestats.face.geometry import uv_to_texel
from facestats.io.schema import SCHEMA_VERSION, set_variable_attrs
from facestats.model import fitting
from facestats.pipeline.lumitexels import fit_lumitexels
from facestats.pipeline.maps import subject_maps
from facestats.pipeline.settings import MAP_VARS, STD_VARS, FitSettings, checked_settings

__all__ = ["fit_subject", "fit_sensor"]


def fit_sensor(capture, eta=ETA_SKIN):
    """Stage 6 for one capture: dipole fits of its three sensor profiles (per site and channel).

    Weighted by the recorded noise model (``sensor_profile_std``) when the capture
    has one, else the log-space fit (:func:`facestats.model.fitting.fit_translucency`).

    Parameters
    ----------
    capture : Capture
        A capture holding ``fiber_distance`` (F,) in mm, ``sensor_profile`` (site, F, channel) in mm⁻² and
        ``sensor_profile_std`` (same shape; all ≤ 0 where no noise model was recorded).
    eta : float
        Relative index of refraction, in [1, 3] (default 1.38).

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
        it = progress_bar(ranges, desc=f"fit {capture.attrs.get('subject_id', '')}", unit="block", enabled=progress)
        parts = [run(a, b) for a, b in it]
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _fit_block_from_path(path, a, b, settings):
    try:  # a worker reuses its open capture across blocks while the group on disk is unchanged
        capture = _open_cached(str(path), os.stat(os.path.join(path, "zarr.json")).st_mtime_ns)
    except OSError:  # not a local directory store
        capture = open_capture(path)
    return fit_lumitexels(capture.lumitexels(a, b), settings)


@functools.lru_cache(maxsize=4)
def _open_cached(path, mtime_ns):
    """:func:`facestats.acquire.capture.open_capture`, cached per (path, modification time of its zarr.json)."""

    return open_capture(path)


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

    if not isinstance(capture, Capture):
        capture = open_capture(capture)
    if client is not None and capture.path is None:
        raise ValidationError("client requires a capture on disk (pass a path or write it with Capture.to_zarr)")
    workers = check_integer(workers, "workers", 1)
    if sigma_tr_avg is not None:
        as_finite(sigma_tr_avg, "sigma_tr_avg", 0, None, low_inclusive=False, unit="mm^-1")
        check_shape(np.asarray(sigma_tr_avg), "sigma_tr_avg", (3,))
    st = checked_settings(settings)
    res = _blocks_result(capture, st, client=client, progress=progress, workers=workers)

    # Stage 5: maps.
    face = capture.array("region_map") > 0
    texel = uv_to_texel(capture.array("uv").astype(np.float64), capture.map_size)
    on_face = face[texel[:, 0], texel[:, 1]]
    usable = on_face & (res["n_samples"] >= st.min_samples)
    if not usable.any():
        most = int(res["n_samples"][on_face].max()) if on_face.any() else 0
        raise ValidationError(
            f"no face lumitexel of the capture has the {st.min_samples} usable samples a fit needs (min_samples; "
            f"the most any has is {most} of {on_face.sum()} face lumitexels): the capture has too few cameras or "
            "lights, or its frames are dark, saturated or do not see the face"
        )
    maps, micro = subject_maps(res, texel, face, workers)
    # Stage 6: sensor profiles.
    tf = fit_sensor(capture, st.eta) if sensor_fit is None else sensor_fit
    # Stage 7: subject scattering from α_avg and σtrAvg.
    stra = SIGMA_TR_AVG if sigma_tr_avg is None else np.asarray(sigma_tr_avg, np.float64)
    alb = np.clip(maps["albedo"], 1e-4, 1 - 1e-4)
    alb_avg, sp, sa, maps["modulation"] = fitting.scattering_parameters(
        np.where(face[..., None], alb, 0), face, stra, st.eta
    )
    scattering = {"albedo_avg": alb_avg, "sigma_s_prime": sp, "sigma_a": sa, "sigma_tr": stra}
    prov = _provenance(capture, st, stra, res, maps)
    return _subject_dataset(capture, maps, micro, tf, scattering, prov)


def _provenance(capture, settings, sigma_tr_avg, res, maps) -> dict:
    """The subject's provenance: capture, fit settings, σtrAvg, software and sample counts."""
    return {
        "source": capture.provenance.get("source", "capture"),
        "capture": capture.path or f"in-memory capture of {capture.metadata['subject_id']}",
        "capture_provenance": capture.provenance,
        "fit_settings": asdict(settings),
        "sigma_tr_avg": [float(x) for x in sigma_tr_avg],
        "software": f"facestats {__version__}",
        "schema_version": SCHEMA_VERSION,
        "counts": {
            "lumitexels": int(capture.n_lumitexels),
            "samples_used": int(res["n_samples"].sum()),
            "samples_masked": int(res["n_invalid"].sum()),
            "samples_grazing": int(res["n_grazing"].sum()),
            "ts_flagged_texels": int((maps.get("ts_flag", np.zeros(1)) != 0).sum()),
            "face_texels": int((capture.array("region_map") > 0).sum()),
        },
    }


def _subject_dataset(capture, maps, micro, tf, scattering, provenance):
    """The subject Dataset (schema of :mod:`facestats.io.schema`) from the results of stages 1-7.

    ``maps`` are stage 5's maps plus the modulation texture, ``micro`` the micro-normal maps
    (or None), ``tf`` the sensor fits (stage 6), ``scattering`` stage 7's per-channel
    ``albedo_avg``, ``sigma_s_prime``, ``sigma_a``, ``sigma_tr``.
    """
    import xarray as xr

    n = capture.map_size
    data = {
        "region": (("v", "u"), capture.array("region_map").astype(np.uint8)),
        "albedo": (("v", "u", "channel"), maps["albedo"].astype(np.float32)),
        "modulation": (("v", "u", "channel"), maps["modulation"].astype(np.float32)),
        "normal": (("v", "u", "component"), maps["normal"].astype(np.float32)),
        "n_samples": (("v", "u"), np.nan_to_num(maps["n_samples"]).round().astype(np.int16)),
        "sensor_profile": (("site", "fiber", "channel"), capture.array("sensor_profile")),
        "sensor_profile_std": (("site", "fiber", "channel"), capture.array("sensor_profile_std")),
        "site_sigma_s_prime": (("site", "channel"), tf.sigma_s_prime),
        "site_sigma_a": (("site", "channel"), tf.sigma_a),
        "site_sigma_tr": (("site", "channel"), tf.sigma_tr),
        "site_sigma_s_prime_std": (("site", "channel"), tf.sigma_s_prime_std),
        "site_sigma_a_std": (("site", "channel"), tf.sigma_a_std),
        "site_sigma_tr_std": (("site", "channel"), tf.sigma_tr_std),
        **{name: (("channel",), np.asarray(value, np.float64)) for name, value in scattering.items()},
    }
    for key, map_vars in MAP_VARS.items():
        if f"{key}_flag" in maps:
            for var in map_vars + STD_VARS[key]:
                data[var] = (("v", "u"), maps[var].astype(np.float32, copy=False))  # 0 off the face (stage 5)
            data[f"{key}_flag"] = (("v", "u"), maps[f"{key}_flag"])
    if micro is not None:
        data["micro_normal"] = (("camera", "v", "u", "component"), micro.astype(np.float32, copy=False))
    meta = capture.metadata
    ds = xr.Dataset(
        data,
        coords={
            "u": (np.arange(n) + 0.5) / n,
            "v": (np.arange(n) + 0.5) / n,
            "channel": list(CHANNELS),
            "site": list(SITES),
            "component": list(COMPONENTS),
            "fiber_distance": ("fiber", capture.array("fiber_distance")),
        },
        attrs={
            "subject_id": str(meta["subject_id"]),
            "person_id": str(meta.get("person_id", meta["subject_id"])),
            "age": int(meta["age"]),
            "gender": str(meta["gender"]),
            "skin_type": int(meta["skin_type"]),
            "condition": str(meta["condition"]),
            "provenance": json.dumps(provenance, sort_keys=True, default=str),
        },
    )
    return set_variable_attrs(ds)
