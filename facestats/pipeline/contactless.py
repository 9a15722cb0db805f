"""Contactless skin translucency: σ's and σa of a subject's cheek and forehead from one image each, no contact sensor.

The stage between a subject's site images and the store.  Per site, given the
known scene (window patches, projector, camera — a
:class:`facestats.acquire.synthetic.scenes.PatchScene`) and its radiance image:

1. c_k from the projector (eq. 16, η = 1.38, shadow-mapped), l_j and the seen
   patches from the image (eq. 15, :func:`facestats.acquire.scene.patch_radiance`);
2. l_j divided by the subject's fitted modulation texture M = α/α_avg at each
   patch (the dome fit's albedo variation, Weyrich et al. 2006 eq. 6-7), so that
   the homogeneous dipole of Suzuki eq. 17 describes what is left;
3. per channel :func:`facestats.model.fitting.fit_scattering_image` with the
   default monotone solve, ``width="auto"``, a log-spaced skin grid
   (:data:`SKIN_GRID`: σ's 0.05-20, σa 0.001-5 mm⁻¹, 160 × 160 models) and
   continuous refinement.

:func:`fit_contactless` returns the subject's Dataset with ``image_sigma_s_prime``,
``image_sigma_a``, ``image_sigma_tr`` and the σtr interval
(``image_sigma_tr_low``/``_high``) on (site, channel) beside the sensor's
``site_*`` values (NaN at sites without an image, e.g. the neck), and a
provenance entry ``contactless_translucency`` (method, light, width, rank,
condition, intervals).  :func:`contactless_population` runs it over store
subjects and writes each one only after every fit of that subject completed.
"""

from __future__ import annotations

import warnings

import numpy as np

from facestats.acquire.lights import patch_irradiance
from facestats.acquire.scene import patch_radiance
from facestats.acquire.synthetic.contactless import (
    CONTACTLESS_SITES,
    modulation_face,
    patch_modulation,
    simulate_site_image,
)
from facestats.core.conventions import CHANNELS, SITES
from facestats.core.progress import progress_bar
from facestats.core.published import ETA_SKIN
from facestats.core.validate import check_choice
from facestats.errors import QuantisationWarning, ValidationError
from facestats.io.schema import modulation, provenance, set_provenance, set_variable_attrs
from facestats.model.fitting.profile_grid import ProfileGrid
from facestats.model.fitting.quantised import SELF_TERMS
from facestats.model.fitting.scattering_image import METHODS, fit_scattering_channels

__all__ = ["SKIN_GRID", "estimate_site", "fit_contactless", "contactless_population", "contactless_study"]

#: The eq. 36 grid for skin (log-spaced; refined continuously).
SKIN_GRID = ProfileGrid.log_spaced((0.05, 20.0), (1e-3, 5.0), (160, 160))

_VARS = ("image_sigma_s_prime", "image_sigma_a", "image_sigma_tr", "image_sigma_tr_low", "image_sigma_tr_high")


def estimate_site(
    scene,
    image,
    *,
    modulation_map=None,
    face=None,
    width="auto",
    grid=SKIN_GRID,
    refine=True,
    eta=ETA_SKIN,
    method="monotone",
    self_term="point",
):
    """The three channel fits (R, G, B) of one site image (module docstring, steps 1-3).

    Parameters
    ----------
    scene : PatchScene
        The known window, projector and camera.
    image : ndarray, shape (H, W, 3)
        Linear radiance.
    modulation_map : ndarray, shape (n, n, 3), optional
        The subject's fitted M = α/α_avg [v, u, channel]; None: no correction.
    face : FaceGeometry, optional
        The face the map is laid out on when it is not the procedural head
        (:func:`facestats.acquire.synthetic.contactless.patch_modulation`).
    width, grid, refine, eta, method, self_term
        As :func:`facestats.model.fitting.fit_scattering_image` (``method="exitance"`` with
        ``self_term="surface"`` for images of a continuous surface: ``docs/translucency_from_image.md``, Limits).

    Returns
    -------
    list of ScatteringImageFit
        One per channel.
    """

    p = scene.patches
    c = patch_irradiance(p, scene.lights, eta=eta)
    l, seen = patch_radiance(image, scene.camera, p, eta=eta)
    if l.shape[1] != 3:
        raise ValidationError(f"image must have 3 channels (R, G, B), got {l.shape[1]}")
    if modulation_map is not None:
        m = patch_modulation(p, modulation_map, face)
        ok = np.all(m > 0, axis=1)
        seen &= ok
        l = np.where(ok[:, None], l / np.where(m > 0, m, 1.0), 0.0)
    return fit_scattering_channels(
        p.centre,
        p.area,
        c,
        l,
        width=width,
        visible=seen,
        eta=eta,
        grid=grid,
        refine=refine,
        method=method,
        self_term=self_term,
    )


def fit_contactless(subject, images: dict, *, light="stripe", use_modulation=True, **options):
    """A copy of a store subject with the contactless estimates of its sites (module docstring).

    Parameters
    ----------
    subject : xarray.Dataset
        A map subject (its M = albedo/albedo_avg is used when ``use_modulation``).
    images : dict
        ``{site: (scene, image)}`` for sites among cheek, forehead.
    light : str
        Name of the projector pattern (recorded in the provenance).
    use_modulation : bool
        Divide by the subject's fitted modulation texture.
    **options
        Passed to :func:`estimate_site`.

    Returns
    -------
    xarray.Dataset
    """

    unknown = sorted(set(images) - set(SITES))
    if unknown or not images:
        raise ValidationError(f"images must map sites among {list(SITES)} to (scene, image), got {sorted(images)}")
    check_choice(options.get("method", "monotone"), "method", METHODS)
    check_choice(options.get("self_term", "point"), "self_term", SELF_TERMS)
    mod = face = None
    if use_modulation:
        if "albedo" not in subject.data_vars or "albedo_avg" not in subject.data_vars:
            raise ValidationError(f"subject {subject.attrs.get('subject_id', '?')!r} has no albedo map to modulate by")
        mod = np.asarray(modulation(subject).values, np.float64)
        name = str(provenance(subject).get("capture_provenance", {}).get("geometry", ""))
        face = modulation_face(name)
    vals = {k: np.full((len(SITES), 3), np.nan) for k in _VARS}
    record = {}
    for site, (scene, image) in images.items():  # loop over the (two) sites
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", QuantisationWarning)
            fits = estimate_site(scene, image, modulation_map=mod, face=face, **options)
        i = SITES.index(site)
        for ch, fit in enumerate(fits):  # three channels
            vals["image_sigma_s_prime"][i, ch] = fit.sigma_s_prime
            vals["image_sigma_a"][i, ch] = fit.sigma_a
            vals["image_sigma_tr"][i, ch] = fit.sigma_tr
            vals["image_sigma_tr_low"][i, ch], vals["image_sigma_tr_high"][i, ch] = fit.sigma_tr_interval
        record[site] = {
            "scene": scene.name,
            "channels": {CHANNELS[ch]: fit.summary() for ch, fit in enumerate(fits)},
            "warnings": sorted({str(w.message) for w in caught}),
        }
    out = subject.copy()
    for k, v in vals.items():
        out[k] = (("site", "channel"), v)
    set_variable_attrs(out)
    previous = provenance(subject).get("contactless_translucency")
    entry = {
        "method": _method_text(options.get("method", "monotone"), options.get("self_term", "point")),
        "light": light,
        "modulation_corrected": bool(use_modulation),
        "eta": float(options.get("eta", ETA_SKIN)),
        "sites": record,
    }
    if previous is not None:
        entry["replaces"] = previous.get("method")
    return set_provenance(out, contactless_translucency=entry)


def _method_text(method, self_term) -> str:
    """The provenance's one-line description of the estimator."""
    solve = {
        "monotone": "solve (monotone, 1/l weights) + eq. 36 dipole fit",
        "pinv": "solve (pseudo-inverse, eq. 35) + eq. 36 dipole fit",
        "exitance": "system with the dipole fitted through W (eq. 34, 1/l weights)",
    }[method]
    own = "" if self_term == "point" else f"; self term {self_term}"
    return f"Suzuki, Mukaigawa & Yagi quantised-distance {solve}{own}"


def contactless_population(
    store, ids, population, *, light="stripe", noise=0.01, spacing=0.3, progress=True, **options
):
    """Simulate site images from the population's truth, estimate, and write each subject (module docstring).

    A subject is written (``store.write_subject``) only after all its site fits
    completed; a failure leaves it untouched and is raised.  Its micro-normals are
    read from the stored generation while the new one is written: if another
    writer replaces or deletes the subject meanwhile, a
    :class:`~facestats.errors.StoreError` says so and nothing is written.

    Parameters
    ----------
    store : Store
        A store open for writing that holds the subjects.
    ids : iterable of str
        The subjects, in order.
    population : Population
        The synthetic population whose truth (``population[id]``) the site images are simulated from
        (e.g. :func:`facestats.acquire.synthetic.population.default_population`).
    light : {"stripe", "spot"}
        The projector pattern.
    noise : float
        Relative standard deviation of the images' multiplicative pixel noise, in [0, 1) (default 1 %).
    spacing : float
        Grid spacing of the site's window mesh, mm (default 0.3).
    progress : bool
        Show a bar over the subjects.
    **options
        Passed to :func:`fit_contactless` (``use_modulation``) and :func:`estimate_site`.

    Returns
    -------
    list of str
        The subject ids written.
    """
    it = list(ids)
    it = progress_bar(it, desc="contactless translucency", unit="subject", enabled=progress)
    written = []
    for sid in it:  # loop over subjects
        truth = population[sid]
        images = {
            site: simulate_site_image(truth, site, light, spacing=spacing, noise=noise, seed=truth.seed + k)
            for k, site in enumerate(CONTACTLESS_SITES)
        }
        # The micro-normals (805 MB of a 2048² subject of 16 cameras), which the fit does not read, stay on disk
        # and are copied band by band into the new generation of the subject.
        subject = store.subject(sid, on_disk=["micro_normal"])
        ds = fit_contactless(subject, images, light=light, **options)
        store.write_subject(ds, overwrite=True)  # same subject, the new variables beside the sensor values
        written.append(sid)
    return written


def contactless_study(
    ids,
    store,
    population,
    *,
    light="stripe",
    noise=0.01,
    spacing=0.3,
    sites=CONTACTLESS_SITES,
    progress=False,
    **options,
):
    """σtr from images against the truth and the contact-sensor fit, per subject, site and channel (no writing).

    Parameters
    ----------
    ids : iterable of str
        The subjects, in order.
    store : Store
        The store holding them (only read).
    population : Population
        The synthetic population whose truth (``population[id]``) gives the site images and the ``truth`` column.
    light : {"stripe", "spot"}
        The projector pattern.
    noise : float
        Relative standard deviation of the images' multiplicative pixel noise, in [0, 1) (default 1 %).
    spacing : float
        Grid spacing of the site's window mesh, mm (default 0.3).
    sites : sequence of str
        Sites among cheek and forehead (default both).
    progress : bool
        Show a bar over the subjects.
    **options
        Passed to :func:`fit_contactless` (``use_modulation``) and :func:`estimate_site`.

    Returns
    -------
    pandas.DataFrame
        Rows (subject, site, channel) with ``truth``, ``sensor``, ``image``, the
        interval ``image_low``/``image_high`` (σtr, mm⁻¹), and the relative errors
        ``error_vs_truth`` and ``error_vs_sensor`` of the image estimate.
    """
    import pandas as pd

    it = list(ids)
    it = progress_bar(it, desc="contactless study", unit="subject", enabled=progress)
    rows = []
    for sid in it:  # loop over subjects
        truth = population[sid]
        subject = store.subject(sid, exclude=["micro_normal"])  # the study writes nothing: what it reads suffices
        images = {
            site: simulate_site_image(truth, site, light, spacing=spacing, noise=noise, seed=truth.seed + k)
            for k, site in enumerate(sites)
        }
        ds = fit_contactless(subject, images, light=light, **options)
        for site in sites:
            i = SITES.index(site)
            for ch, name in enumerate(CHANNELS):
                t = float(truth.site_sigma_tr[i, ch])
                rows.append(
                    {
                        "subject": sid,
                        "site": site,
                        "channel": name,
                        "truth": t,
                        "sensor": float(subject["site_sigma_tr"].values[i, ch]),
                        "image": float(ds["image_sigma_tr"].values[i, ch]),
                        "image_low": float(ds["image_sigma_tr_low"].values[i, ch]),
                        "image_high": float(ds["image_sigma_tr_high"].values[i, ch]),
                    }
                )
    df = pd.DataFrame(rows)
    df["error_vs_truth"] = df["image"] / df["truth"] - 1
    df["error_vs_sensor"] = df["image"] / df["sensor"] - 1
    return df
