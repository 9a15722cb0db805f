"""Stage 5 of the fit pipeline: per-lumitexel results to UV maps (Weyrich et al. 2006 §5.3).

Every per-lumitexel output is averaged into the texels its lumitexels fall in;
texels of the face that no lumitexel reached (maps finer than the mesh) and
texels whose fit is flagged are filled from their neighbours by push-pull, and
the flag maps record it.

The standard errors of the BRDF parameters are the standard errors of those
averages: a texel holding the mean of k lumitexel fits with standard errors
σ_i has σ = sqrt(Σ σ_i²)/k (independent fits).  Flagged and empty texels get
them filled from their neighbours like their values (the variances are filled,
then square-rooted); the ``filled`` bit of the flag map says which texels are
no measurements.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from facestats.errors import FitError
from facestats.io.schema import FLAG_BITS
from facestats.model import fitting
from facestats.pipeline.settings import MAP_VARS, STD_VARS

__all__ = ["subject_maps"]


def subject_maps(res, texel, face, workers=1):
    """The subject's maps from the per-lumitexel results ``res`` of stages 1-4.

    The map jobs (micro-normals, the averaged maps, then per-model filling, albedo,
    normals) run on a pool of ``workers`` threads (numpy releases the GIL in the
    heavy array work); with one worker, one job at a time.

    Parameters
    ----------
    res : dict of ndarray
        Output of :func:`facestats.pipeline.lumitexels.fit_lumitexels` over all
        lumitexels (``micro_normal`` is taken out of it when present).
    texel : ndarray of int, shape (n, 2)
        ``(v, u)`` texel of each lumitexel.
    face : ndarray of bool, shape (size, size)
        Face texels (region > 0).
    workers : int
        Threads for the map jobs.

    Returns
    -------
    maps : dict of ndarray
        ``albedo``, ``normal``, ``n_samples`` and, per fitted model, its three maps
        and ``<prefix>_flag``, filled over the face, 0 off it; and its two
        standard-error maps (module docstring), filled like the values.
    micro : ndarray or None
        Per-camera micro-normal maps (camera, v, u, 3), if they were fitted.
    """
    size = face.shape[0]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        jobs = {}
        if "micro_normal" in res:
            jobs["micro_normal"] = pool.submit(_micro_normal_map, res.pop("micro_normal"), texel, face)
        maps, has_data = pool.submit(_averaged_maps, res, texel, size).result()
        for key, map_vars in MAP_VARS.items():
            if f"{key}_flag" in res:
                names = map_vars + tuple(v for v in STD_VARS[key] if v in maps)
                jobs[key] = pool.submit(
                    _model_maps, [maps[v] for v in names], res[f"{key}_flag"], texel, face, has_data, key
                )
        jobs["albedo"] = pool.submit(_filled_map, maps["albedo"], face, has_data)
        jobs["normal"] = pool.submit(_filled_map, maps["normal"], face, has_data, unit=True)
        micro = jobs.pop("micro_normal").result() if "micro_normal" in jobs else None
        for key, job in jobs.items():
            if key in MAP_VARS:
                filled, maps[f"{key}_flag"] = job.result()
                names = MAP_VARS[key] + tuple(v for v in STD_VARS[key] if v in maps)
                maps.update(zip(names, filled))
            else:
                maps[key] = job.result()
    for name in (v for key in STD_VARS for v in STD_VARS[key] if v in maps):  # filled variances -> errors
        maps[name] = np.sqrt(np.maximum(maps[name], 0)).astype(np.float32)
    return maps, micro


def _averaged_maps(res, texel, size):
    """Every per-lumitexel float output of ``res`` averaged into (size, size[, 3]) maps, and where data landed.

    One grouping of the lumitexels by texel for all values and one for the variances
    (:func:`facestats.model.fitting.scatter_to_map`);
    NaN where no lumitexel landed.
    """
    stds = [name for key in ("ts", "bp") for name in STD_VARS[key] if name in res]
    names = [name for name in ("albedo", "normal", *MAP_VARS["ts"], *MAP_VARS["bp"], "n_samples") if name in res]
    n = len(texel)
    columns = [np.asarray(res[name], np.float32).reshape(n, -1) for name in names]
    stacked, count = fitting.scatter_to_map(np.concatenate(columns, axis=1), texel, size)
    maps, col = {}, 0
    for name, c in zip(names, columns):
        maps[name] = stacked[..., col : col + c.shape[1]]
        maps[name] = maps[name] if c.shape[1] > 1 and name in ("albedo", "normal") else maps[name][..., 0]
        col += c.shape[1]
    if stds:  # σ², averaged, in float64: the σ of an ill-conditioned texel can exceed float32's square root range
        squares = np.stack([np.square(np.asarray(res[name], np.float64)).reshape(n) for name in stds], axis=1)
        var, _ = fitting.scatter_to_map(squares, texel, size)
        maps.update({name: var[..., k] for k, name in enumerate(stds)})
    with np.errstate(invalid="ignore", divide="ignore"):
        for name in stds:  # mean σ² / k = Σσ²/k² (module docstring); the square root is taken by subject_maps
            maps[name] = maps[name] / count
    return maps, count > 0


def _model_maps(values, flags, texel, face, has_data, model):
    """One model's maps with flagged and empty face texels filled from their neighbours (§5.3), and its flag map.

    ``values`` are the model's (size, size) maps (NaN where no lumitexel landed),
    ``flags`` the per-lumitexel fit flags; off the face everything is 0.  A model whose every face texel is
    flagged leaves nothing to fill from: a :class:`FitError` naming the model and its flags.
    """
    size = face.shape[0]
    fl = np.zeros((size, size), np.uint8)
    np.bitwise_or.at(fl, (texel[:, 0], texel[:, 1]), flags.astype(np.uint8))
    hole = face & ~has_data  # texels no lumitexel maps to (the map is finer than the mesh)
    bad = face & ((fl != 0) | hole)
    if face.any() and bad[face].all():
        raised = {name: int(np.count_nonzero(fl[face] & bit)) for name, bit in FLAG_BITS.items() if bit}
        raise FitError(
            f"every face texel's {model}_ fit is flagged ({', '.join(f'{k}: {v}' for k, v in raised.items() if v)} "
            f"of {int(face.sum())} texels): nothing to fill its maps from; the sample limits (max_angle_deg, and "
            "bp_max_angle_deg for Blinn-Phong) may leave too few samples per lumitexel, or the capture holds no "
            "usable specular data"
        )
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
