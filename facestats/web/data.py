"""What the web app shows beyond the query document: Fig. 15 ellipses, Fig. 14 scatter, map images, a relit preview.

Every function takes store data and returns JSON-ready dicts or PNG bytes; the
Flask layer (:mod:`facestats.web.app`) only routes.  The statistics come from
:mod:`facestats.analysis` (:func:`~facestats.analysis.pca.region_pca` on the
region samples, :func:`~facestats.analysis.scatter.absorption_scattering`), the
preview from :func:`facestats.model.skin.skin_radiance`.
"""

from __future__ import annotations

import threading

import numpy as np

from facestats.analysis.pca import has_index_moments, region_pca
from facestats.analysis.population import region_samples
from facestats.analysis.scatter import absorption_scattering
from facestats.core.conventions import CHANNELS, REGIONS
from facestats.core.validate import check_choice
from facestats.errors import FacestatsError, ValidationError
from facestats.model.skin import SubsurfaceTransport, skin_radiance

__all__ = [
    "MAX_IMAGE_SIDE",
    "PREVIEW_SIDE",
    "image_view",
    "RegionSamples",
    "pca_document",
    "scatter_document",
    "map_names",
    "map_png",
    "preview_png",
    "PREVIEW_LIGHTS",
]

#: Largest side (pixels) to which map and preview images are enlarged (a 48² map: 4×, 192 pixels).
MAX_IMAGE_SIDE = 1024
#: Largest side (texels) of the relit preview: it is computed per texel in float64 (about 480 bytes a face
#: texel), so a 2048² subject took 5.2 s and 1.4 GB at full size; maps larger than this are strided first.
PREVIEW_SIDE = 512
#: Directions towards the three preview lights (key, fill, rim) and their irradiance (relative units).
PREVIEW_LIGHTS = (
    ((0.5, 0.45, 0.74), 1.0),
    ((-0.6, 0.1, 0.8), 0.35),
    ((0.0, 0.8, -0.2), 0.25),
)


class RegionSamples:
    """Where Fig. 15's PCA comes from: the population index, or region samples read once in the background.

    A store's index holds each subject's per-region moments, from which the
    pooled PCA of any selection follows exactly
    (:func:`facestats.analysis.pca.region_pca`): then nothing is read and
    :attr:`from_index` is True.  Stores written before the index held the
    (ρs, m) covariances need the per-texel samples of every subject (opening
    each subject: about 10 s for the 155 subjects of the default store), read
    through a store handle of its own so that requests never wait for it; the
    page asks again until :attr:`ready`.

    Parameters
    ----------
    store : facestats.io.store.Store
        The app's store; the background reader opens its own handle on the same path (or the default store).
    start : bool
        Start reading the samples now when the index lacks the moments (default True); False leaves them unread.
    """

    def __init__(self, store, start=True):
        self.store = store
        self.frame = None
        self.error = None
        self.failed = {}  # subject id -> why its samples could not be read
        self.from_index = has_index_moments(store, "ts")
        self._thread = threading.Thread(target=self._load, name="facestats-region-samples", daemon=True)
        if start and not self.from_index:
            self._thread.start()

    def _load(self):
        # local import: keeps facestats.io (23 modules) out of this module's import
        import pandas as pd

        from facestats.io.store import open_store

        try:  # a store handle of its own: requests never wait for this thread
            with open_store(self.store.path if self.store.label != "default" else None) as st:
                frames, failed = [], {}
                for sid in st.subjects().index:  # loop over subjects: one damaged subject spoils only itself
                    try:
                        frames.append(region_samples(st, model="ts", subjects=[str(sid)]))
                    except FacestatsError as exc:  # named when a selection includes it
                        failed[str(sid)] = str(exc)
                self.failed = failed
                self.frame = pd.concat(frames, ignore_index=True) if frames else region_samples(st, subjects=[])
        except Exception as exc:  # reported to the page, never raised in the thread
            self.error = f"region samples could not be read: {exc}"

    @property
    def ready(self) -> bool:
        return self.from_index or self.frame is not None or self.error is not None

    def wait(self, timeout=None) -> bool:
        """Wait (up to ``timeout`` s) for the samples being read in the background; return whether they are ready.

        Parameters
        ----------
        timeout : float, optional
            Seconds to wait at most; None waits until the reading ends.

        Returns
        -------
        bool
            :attr:`ready`: the PCA comes from the index, or the samples were read, or reading them failed.
        """
        if not self.from_index and self._thread.is_alive():
            self._thread.join(timeout)
        return self.ready


def pca_document(samples: RegionSamples, subject_ids) -> dict:
    """Fig. 15 ellipses (centre, σ half-axes, first principal axis) of the matching subjects, or a pending/error status.

    Parameters
    ----------
    samples : RegionSamples
        The app's source of the PCA (the store's index, or the samples read in the background).
    subject_ids : iterable of str
        Subjects to pool (every condition of them is used).

    Returns
    -------
    dict
        ``status``: ``"pending"`` (samples still being read), ``"error"`` (with ``error``: the samples, or those of
        a selected subject, could not be read), ``"empty"`` (with ``error``: :func:`region_pca` refused the
        selection) or ``"ok"``, then with ``variables``, ``k`` (1), ``n_subjects`` and ``regions``: per region
        ``region``, ``name``, ``mean`` (ρs, m), ``half_axes`` (σ along each principal axis), ``axis`` (the first
        eigenvector) and ``n_samples``.
    """

    if not samples.ready:
        return {"status": "pending"}
    if samples.error:
        return {"status": "error", "error": samples.error}
    ids = list(subject_ids)
    broken = [sid for sid in ids if sid in samples.failed]
    if broken:
        why = samples.failed[broken[0]]
        return {"status": "error", "error": f"region samples of {broken} could not be read: {why}"}
    try:
        if samples.from_index:
            res = region_pca(samples.store, model="ts", subjects=ids, conditions=None, from_index=True)
        else:
            res = region_pca(samples.frame, model="ts", subjects=ids)
    except ValidationError as exc:
        return {"status": "empty", "error": str(exc)}
    out = []
    for r, e in sorted(res.regions.items()):
        vec = np.asarray(e.eigenvectors)
        out.append(
            {
                "region": int(r),
                "name": REGIONS[int(r)],
                "mean": [float(x) for x in e.mean],
                "half_axes": [float(x) for x in e.half_axes()],
                "axis": [float(vec[0, 0]), float(vec[1, 0])],
                "n_samples": int(e.n),
            }
        )
    return {"status": "ok", "variables": ["rho_s", "m"], "k": 1, "n_subjects": int(res.n_subjects), "regions": out}


def scatter_document(store, subject_ids) -> dict:
    """Fig. 14: σa and σ's (mm⁻¹) of the matching subjects per channel, with skin type, gender and age.

    Parameters
    ----------
    store : parameter store
        Anything with ``subjects()`` (the population index).
    subject_ids : iterable of str
        Subjects to show (every condition of them).

    Returns
    -------
    dict
        ``points`` (one dict per subject and channel: ``subject_id``, ``channel``, ``sigma_a``,
        ``sigma_s_prime``, ``skin_type``, ``gender``, ``age``; subjects without positive finite σ in a channel are
        left out of it) and ``units`` (``"mm-1"``); ``points`` is empty, with ``error``, where
        :func:`~facestats.analysis.scatter.absorption_scattering` refused the selection.
    """

    ids = list(subject_ids)
    if not ids:
        return {"points": [], "units": "mm-1"}
    try:
        res = absorption_scattering(store.subjects(), subjects=ids, conditions=None)
    except ValidationError as exc:
        return {"points": [], "units": "mm-1", "error": str(exc)}
    d = res.data
    pts = [
        {"subject_id": s, "channel": c, "sigma_a": float(a), "sigma_s_prime": float(p), "skin_type": int(t),
         "gender": g, "age": float(age)}
        for s, c, a, p, t, g, age in zip(d["subject_id"], d["channel"], d["sigma_a"], d["sigma_s_prime"],
                                          d["skin_type"], d["gender"], d["age"])
    ]  # fmt: skip
    return {"points": pts, "units": "mm-1"}


def map_names(ds) -> list:
    """Names of the maps a subject page shows: every (v, u[, 3]) variable plus ``modulation``.

    Parameters
    ----------
    ds : xarray.Dataset
        A subject.

    Returns
    -------
    list of str
        Variables whose first two dimensions are (v, u) and that have 2 or 3 dimensions, sorted, then
        ``modulation`` if ``albedo`` is among them (empty for a region-sample subject).
    """
    names = [v for v in sorted(ds.data_vars) if tuple(ds[v].dims[:2]) == ("v", "u") and ds[v].ndim in (2, 3)]
    return names + (["modulation"] if "albedo" in names and "modulation" not in names else [])


def _scalar_rgb(values, face, name):
    """A scalar map as colour: viridis over the 2-98 % range of the face (flags 0-8; regions: tab10 labels 1-10),
    outside black.  Returns ``(rgb, colormap, lo, hi)``: the image and its scale (:func:`map_png`'s text)."""
    from matplotlib import colormaps

    if name == "region":
        rgb = colormaps["tab10"]((values.astype(int) - 1) % 10)[..., :3]
        cmap, lo, hi = "tab10", 1.0, 10.0
    else:
        v = values[face]
        lo, hi = (np.percentile(v, [2, 98]) if v.size else (0.0, 1.0)) if name.find("flag") < 0 else (0, 8)
        rgb = colormaps["viridis"](np.clip((values - lo) / max(hi - lo, 1e-12), 0, 1))[..., :3]
        cmap = "viridis"
    rgb[~face] = 0
    return rgb, cmap, float(lo), float(hi)


def image_view(ds, max_side=None):
    """``ds`` with every k-th texel along v and u, k the smallest step that brings the maps to at most
    ``max_side`` (default :data:`MAX_IMAGE_SIDE`) texels a side: a web image never needs more, and a lazy
    subject then reads and converts only what is shown (a 2048² map took a 688 MB transient for a 50 MB map;
    the speed red team).

    Parameters
    ----------
    ds : xarray.Dataset
        A subject (eager or lazy); without a ``v`` or ``u`` dimension that side counts as 1.
    max_side : int, optional
        Largest side in texels (default :data:`MAX_IMAGE_SIDE`).

    Returns
    -------
    xarray.Dataset
        ``ds`` itself when no striding is needed, else a strided view (``isel``).
    """
    # local import: keeps facestats.io (24 modules) out of this module's import
    from facestats.io.images import stride_step

    side = MAX_IMAGE_SIDE if max_side is None else max_side
    k = stride_step(ds.sizes.get("v", 1), ds.sizes.get("u", 1), side)
    return ds if k == 1 else ds.isel(v=slice(None, None, k), u=slice(None, None, k))


def _png_scale(shape, scale: int) -> int:
    """The enlargement :func:`_encode_png` applies: ``scale``, reduced to keep :data:`MAX_IMAGE_SIDE` pixels a side."""
    return max(1, min(int(scale), MAX_IMAGE_SIDE // max(shape[:2])))


def _encode_png(rgb, scale: int, text=None) -> bytes:
    """PNG bytes of an RGB image in [0, 1], enlarged ``scale`` times (texels as blocks) up to
    :data:`MAX_IMAGE_SIDE` pixels a side (:func:`_png_scale`); images larger than that are not enlarged.  ``text``:
    PNG text chunks (:func:`facestats.io.png.text_chunks`) inserted after the header."""
    import cv2

    # local import: keeps facestats.io (24 modules) out of this module's import
    from facestats.io.png import add_chunks, text_chunks

    img = np.clip(np.asarray(rgb, np.float64), 0, 1)
    scale = _png_scale(img.shape, scale)
    if scale > 1:
        img = np.repeat(np.repeat(img, scale, 0), scale, 1)
    q = np.round(img * 255).astype(np.uint8)[..., ::-1]
    ok, buf = cv2.imencode(".png", q)
    return add_chunks(buf.tobytes(), text_chunks(text)) if text else buf.tobytes()


def map_png(ds, name: str, scale: int = 4) -> bytes:
    """One map of a subject as a PNG (albedo and modulation sRGB-encoded, normals as (n + 1)/2, others colour-mapped).

    The map is first strided to at most :data:`MAX_IMAGE_SIDE` texels a side (:func:`image_view`); texels outside
    the face (``region`` 0) are black.

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject, with a ``region`` map.
    name : str
        One of :func:`map_names`.
    scale : int
        Enlargement (texels as ``scale`` × ``scale`` blocks), reduced so the image stays within
        :data:`MAX_IMAGE_SIDE` pixels a side.

    Returns
    -------
    bytes
        The PNG file, 8-bit RGB.

    Raises
    ------
    ValidationError
        ``name`` is not one of :func:`map_names`, or ``ds`` is a region-sample subject.
    """
    # local import: keeps facestats.io (24 modules) out of this module's import
    from facestats.io.exr_set import check_map_subject
    from facestats.io.images import linear_to_srgb, stride_step
    from facestats.io.png import map_scale_text
    from facestats.io.schema import VARIABLES, modulation

    names = map_names(ds)
    if not names:  # a region-sample subject: say so, not "map must be one of []"
        check_map_subject(ds, "a map image")
    check_choice(name, "map", tuple(names))
    step = stride_step(ds.sizes.get("v", 1), ds.sizes.get("u", 1), MAX_IMAGE_SIDE)  # image_view's
    ds = image_view(ds)
    face = np.asarray(ds["region"].values) > 0
    if name == "modulation":
        vals = np.asarray(modulation(ds).values) * 0.5
    else:
        vals = np.nan_to_num(np.asarray(ds[name].values, np.float64))
    if name in ("albedo", "modulation"):
        rgb, cmap, lo, hi = linear_to_srgb(vals), "sRGB", 0.0, 2.0 if name == "modulation" else 1.0  # M / 2 drawn
    elif vals.ndim == 3 and vals.shape[2] == 3:
        rgb, cmap, lo, hi = (vals + 1) / 2, "(n + 1) / 2", -1.0, 1.0
    else:  # a scalar map, or the first channel of another
        rgb, cmap, lo, hi = _scalar_rgb(vals[..., 0] if vals.ndim == 3 else vals, face, name)
    rgb = np.array(rgb, np.float64)
    rgb[~face] = 0
    pixels = _png_scale(face.shape, scale)
    known = name in VARIABLES
    attrs = ds[name].attrs if name in ds.data_vars else {}
    note = "; the 2nd-98th percentile of the face's texels" if cmap == "viridis" and "flag" not in name else ""
    note += "; black outside the face" + (f"; every {step}th texel along v and u" if step > 1 else "")
    text, _ = map_scale_text(
        name, cmap, lo, hi, pixels, units=None if known else str(attrs.get("units", "unknown")),
        long_name=None if known else str(attrs.get("long_name", name)), note=note,
    )  # fmt: skip
    text.update({"facestats:subject_id": str(ds.attrs.get("subject_id", "")), "facestats:texel_step": str(step)})
    return _encode_png(rgb, scale, text)


def preview_radiance(ds, lights=PREVIEW_LIGHTS, view=(0.0, 0.0, 1.0)):
    """The subject relit by directional lights and seen from ``view``, in UV layout (v, u, 3), linear.

    Weyrich et al. 2006 eq. 6 through :func:`facestats.model.skin.skin_radiance`:
    Torrance-Sparrow specular with the fitted (ρs, m) and diffuse normal, diffuse
    from the modulation texture and the subject's σ's, σa (flat-patch dipole
    transport, no shadows); irradiance E = E⊥ (N·ωi).  Maps larger than :data:`PREVIEW_SIDE` texels a side are
    strided to it first (:func:`image_view`).

    Raises
    ------
    ValidationError
        A region-sample subject (:func:`facestats.io.exr_set.check_map_subject`): it has no maps to relight.
    """
    # local import: keeps facestats.io (23 modules) out of this module's import
    from facestats.io.exr_set import check_map_subject
    from facestats.io.schema import modulation

    check_map_subject(ds, "the relit preview")
    ds = image_view(ds, PREVIEW_SIDE)
    face = np.asarray(ds["region"].values) > 0
    if "normal" in ds.data_vars:
        n = np.asarray(ds["normal"].values, np.float64)[face]
    else:  # a subject without a normal map is shown as a flat patch facing the viewer
        n = np.tile([0.0, 0.0, 1.0], (int(face.sum()), 1))
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    bad = ~np.all(np.isfinite(n), axis=1) | (np.linalg.norm(n, axis=1) < 0.5)
    n[bad] = (0.0, 0.0, 1.0)
    dirs = np.array([np.asarray(d, np.float64) / np.linalg.norm(d) for d, _ in lights])
    power = np.array([p for _, p in lights])
    wi = np.broadcast_to(dirs, (len(n), len(dirs), 3))
    irr = (np.clip(n @ dirs.T, 0, None) * power)[..., None] * np.ones(3)
    wo = np.broadcast_to(np.asarray(view, np.float64) / np.linalg.norm(view), (len(n), 1, 3))
    mod = np.nan_to_num(np.asarray(modulation(ds).values, np.float64))[face]
    transport = SubsurfaceTransport(ds["sigma_s_prime"].values, ds["sigma_a"].values)
    rad = skin_radiance(
        n, wi, irr, wo, rho_s=np.asarray(ds["ts_rho_s"].values)[face], roughness=np.asarray(ds["ts_m"].values)[face],
        modulation=mod, subsurface=transport,
    )  # fmt: skip
    img = np.zeros(face.shape + (3,))
    img[face] = rad[:, 0].sum(axis=1)
    return img


def preview_png(ds, scale: int = 4) -> bytes:
    """:func:`preview_radiance` tone-mapped (99th percentile to white, sRGB) as a PNG.

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject (strided to at most :data:`PREVIEW_SIDE` texels a side first).
    scale : int
        Enlargement (texels as ``scale`` × ``scale`` blocks), reduced so the image stays within
        :data:`MAX_IMAGE_SIDE` pixels a side.

    Returns
    -------
    bytes
        The PNG file, 8-bit RGB.

    Raises
    ------
    ValidationError
        ``ds`` is a region-sample subject: it has no maps to relight.
    """
    # local import: keeps facestats.io (24 modules) out of this module's import
    from facestats.io.images import linear_to_srgb

    img = preview_radiance(ds)
    face = np.asarray(image_view(ds, PREVIEW_SIDE)["region"].values) > 0
    white = np.percentile(img[face], 99) if face.any() else 1.0
    return _encode_png(linear_to_srgb(img / max(white, 1e-12)), scale)


def subject_document(ds) -> dict:
    """Metadata, kind (``maps`` or ``samples``), coefficients and map names of a subject (JSON-ready).

    Only a ``maps`` subject has a relit preview and an EXR texture set (the subject page links them only then).
    """
    # local import: keeps facestats.io (23 modules) out of this module's import
    from facestats.io.schema import subject_kind

    meta = {k: (v.item() if hasattr(v, "item") else v) for k, v in ds.attrs.items() if k != "provenance"}
    coeffs = {
        v: dict(zip(CHANNELS, (float(x) for x in np.asarray(ds[v].values))))
        for v in ("albedo_avg", "sigma_a", "sigma_s_prime", "sigma_tr")
        if v in ds.data_vars
    }
    return {
        "subject": meta,
        "kind": subject_kind(ds),
        "coefficients": coeffs,
        "units": {"sigma": "mm-1", "albedo": "1"},
        "maps": map_names(ds),
    }
