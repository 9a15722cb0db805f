"""Simulated images for contactless translucency: a face site lit by a projected pattern, seen by a close-up camera.

For a subject's ground truth (:class:`facestats.acquire.synthetic.population.SubjectTruth`)
and a site (cheek or forehead), :func:`simulate_site_image` renders the window
of :func:`facestats.acquire.synthetic.scenes.face_site_scene`:

1. the projector's irradiance c_k per patch and channel (eq. 16, η = 1.38;
   :func:`facestats.acquire.lights.patch_irradiance`);
2. the exitance l_j = Σ_k R(d_jk) c_k A_k with the site's true (σ's, σa) per
   channel (:func:`facestats.acquire.synthetic.subsurface.render_exitance`,
   the point kernel over every pair, no radius cut-off): the skin under the
   window is homogeneous with the site's coefficients, as the contact sensor
   assumes.  Before 2026-12-07 the renderer's default cut-off (where all but
   10⁻⁴ of the dipole's energy is in) applied: it dropped little light in
   total but much or all of the own light of the rows near or beyond it from
   the stripe, and fits by relative residuals read that as a faster fall
   (exitance + surface up to 89 % off in σtr on the cheeks of S003, S004 and
   S007, ``bench_contactless_methods``);
3. the radiance L = M F_t,o l / π with the modulation texture M = α/α_avg of
   the truth's albedo map at each patch (Weyrich et al. 2006 eq. 6-7: the
   dome-fitted albedo varies across the site), or M = 1.  The window is the
   procedural head's; a truth drawn on another face (``truth.geometry``, e.g. the
   default's ICT face) is read at that face's lumitexel nearest to each patch in
   the frontal plane (x, y), which puts both windows in the same region there;
4. the image (:func:`facestats.acquire.synthetic.patch_image.render_exitance_image`)
   with multiplicative Gaussian pixel noise of relative std ``noise``.

Specular reflection is left out: a cross-polarised projector and camera (as in
the dome's diffuse pass) remove it; the image holds subsurface light only.
"""

from __future__ import annotations

import numpy as np

from facestats.acquire.lights import patch_irradiance
from facestats.acquire.synthetic.patch_image import render_exitance_image
from facestats.acquire.synthetic.scenes import face_site_scene
from facestats.acquire.synthetic.subsurface import render_exitance
from facestats.core.conventions import SITES
from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_scalar, check_choice
from facestats.errors import ValidationError
from facestats.face.geometry import uv_to_texel
from facestats.face.named import named_face
from facestats.face.procedural import face_uv

__all__ = ["CONTACTLESS_SITES", "modulation_face", "patch_modulation", "simulate_site_image"]

#: Sites of the procedural face the contactless study images (the neck is not modelled).
CONTACTLESS_SITES = ("cheek", "forehead")


def modulation_face(name: str):
    """The face whose layout a modulation map follows, for :func:`patch_modulation`: None for the
    procedural head (and for a name facestats cannot rebuild: a scan), else
    :func:`facestats.face.named.named_face` (``ict-N``).

    :func:`patch_modulation` reads the lumitexels' positions and UVs, which do not depend on the map
    size, so the face is built with maps of its lumitexel grid (built with a 2048² subject's maps it
    took 3.5 s and 734 MiB, for the same lumitexels).

    Parameters
    ----------
    name : str
        The face's name (:attr:`FaceGeometry.name`, e.g. ``"ict-48"``), or empty.

    Returns
    -------
    FaceGeometry or None
    """
    if not name or name.startswith("procedural-"):
        return None
    try:
        return named_face(name)
    except ValidationError:
        return None


def patch_modulation(patches, modulation_map, geometry=None) -> np.ndarray:
    """M (m, 3) at the patches of a procedural-face window from a modulation map [v, u, channel].

    Parameters
    ----------
    patches : facestats.acquire.patches.Patches
        The window's patches (centres in mm).
    modulation_map : array_like, shape (S, S, C)
        The map, indexed [v, u, channel]; each patch reads the texel containing its UV (no interpolation).
    geometry : FaceGeometry, optional
        The face the map is laid out on, when it is not the procedural head (whose UV the patches'
        positions give exactly); each patch then takes the UV of the face's lumitexel nearest to it in
        (x, y), the frontal plane.  None (or a procedural face): the procedural head.

    Returns
    -------
    ndarray of float64, shape (m, C)
    """

    mod = np.asarray(modulation_map, np.float64)
    if geometry is None or geometry.meta.get("kind") == "procedural":
        uv = np.stack(face_uv(patches.centre[:, 0], patches.centre[:, 1]), -1)
    else:
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(geometry.position[:, :2]).query(patches.centre[:, :2])
        uv = geometry.uv[nearest]
    tex = uv_to_texel(uv, mod.shape[0])
    return mod[tex[:, 0], tex[:, 1]]


def simulate_site_image(truth, site="cheek", light="stripe", *, spacing=0.3, modulation=True, noise=0.01, seed=0):
    """A radiance image of a face site under a projected pattern (module docstring).

    Parameters
    ----------
    truth : SubjectTruth
    site : {"cheek", "forehead"}
    light : {"stripe", "spot"}
    spacing : float
        Grid spacing of the window mesh, mm.
    modulation : bool
        Modulate the exitance by the truth's M = α/α_avg.
    noise : float
        Relative std of multiplicative pixel noise, in [0, 1).
    seed : int
        Seed of the noise.

    Returns
    -------
    scene : PatchScene
    image : ndarray, shape (H, W, 3)
        Linear radiance (irradiance unit of the projector per sr), NaN off the window.
    """

    check_choice(site, "site", CONTACTLESS_SITES)
    nz = as_scalar(noise, "noise", 0, 1, high_inclusive=False)
    scene = face_site_scene(site, light, spacing=spacing)
    p = scene.patches
    c = patch_irradiance(p, scene.lights, eta=ETA_SKIN)
    sp, sa = truth.site_scattering
    i = SITES.index(site)
    l = render_exitance(p.centre, p.area, c, sp[i], sa[i], eta=ETA_SKIN, radius=np.inf)  # every pair: step 2
    if modulation:
        face = truth.region_map > 0
        avg = truth.albedo[face].mean(axis=0)
        geometry = modulation_face(truth.geometry)
        l = l * patch_modulation(p, np.where(face[..., None], truth.albedo / avg, 1.0), geometry)
    image = render_exitance_image(scene.camera, p, l, eta=ETA_SKIN, samples=2)
    if nz > 0:
        rng = np.random.default_rng(seed)
        image = np.maximum(image * (1 + nz * rng.standard_normal(image.shape)), 0).astype(np.float32)
    return scene, image
