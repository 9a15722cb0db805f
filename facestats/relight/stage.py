"""The virtual light stage: a fitted store subject imaged under every light of a light stage → a reflectance field.

Debevec et al. 2000 §3.1-3.2 record a face under 64 × 32 directions of a
distant light and stack the images into reflectance functions (eq. 2).  Here a
subject of the store (a Weyrich et al. 2006 skin model: albedo/modulation map,
diffuse normal map, Torrance-Sparrow or Blinn-Phong maps, σ's and σa) is
imaged the same way through the skin model, so every face of the population
can be relit under measured light (:func:`facestats.relight.relighting.relight`).

Pipeline for one camera (:class:`StageCamera`, pinhole, square image):

1. **Surface per pixel.**  The face mesh (:func:`subject_geometry`) is
   rasterised into the camera (:func:`facestats.acquire.visibility.rasterize`);
   each covered pixel's ray is intersected with its triangle (Möller-Trumbore),
   giving the surface point, its barycentric coordinates and, through the
   mesh's UV coordinates, the texture coordinate where the subject's maps are
   read (bilinear, over face texels only).  Pixels whose UV falls off the
   face region are background (``mask`` False, reflectance 0).
2. **Visibility.**  Every light is a distant source: its shadow map is that of
   :class:`facestats.acquire.visibility.ShadowMaps` from a viewpoint 10⁵ mm away
   along the light direction (an orthographic map to 10⁻³).  Visibility is
   evaluated at the mesh vertices and interpolated to pixels with the
   barycentric coordinates (a fraction in [0, 1]: shadow edges are as sharp as
   the mesh, about one shadow-map texel).  Lights that reach no pixel's front
   side are skipped.
3. **Skin model per (pixel, light)** — Weyrich et al. 2006 eq. 6 with eq. 5's
   1/π (:mod:`facestats.model.skin`), per unit irradiance L·δA of a white light:

       R = f_s(N, l, v) (N·l) V + M F_t(N·v)/π · R_tot F_t(N·l) (N·l) V

   with f_s = ρs D(N·H; m) K (eq. 12-13, :func:`facestats.model.brdf.torrance_sparrow_cosines`,
   :func:`~facestats.model.brdf.beckmann_distribution`) or ρs (n+2)/(2π) (N·H)ⁿ
   (eq. 11), F_t = 1 − F_r (:func:`facestats.model.fresnel.fresnel_reflectance`),
   V the visibility, M = α/α_avg, and R_tot the total diffuse reflectance of the
   subject's (σ's, σa) through :class:`facestats.model.skin.SubsurfaceTransport`
   in its local (flat-patch) mode, as :func:`facestats.pipeline.render.predict_radiance`
   renders fitted subjects.  The diffuse term factors into a per-(pixel, channel)
   colour times a per-(pixel, light) shape, so it is evaluated once per sample
   instead of per channel; ``tests/relight/test_stage.py`` checks the result
   against :func:`facestats.model.skin.skin_radiance` sample by sample.

The same per-sample evaluation, summed over lights with weights L·δA instead of
stored per light, is :func:`render_subject`, the direct render that relighting
a stage field must reproduce.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from facestats.acquire.visibility import DISTANT_LIGHT_MM, ShadowMaps
from facestats.core.blocked import blockwise
from facestats.core.processes import available_memory
from facestats.core.progress import progress_bar
from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_finite, as_float, check_choice, check_integer, check_shape
from facestats.errors import ValidationError
from facestats.face.geometry import FaceGeometry
from facestats.model.brdf import (
    beckmann_distribution_unchecked,
    blinn_phong_lobe_unchecked,
    torrance_sparrow_cosines_unchecked,
)
from facestats.model.fresnel import fresnel_reflectance_unchecked
from facestats.model.skin import SPECULAR_MODELS, SubsurfaceTransport
from facestats.model.sphere import light_stage_directions, unit_directions
from facestats.relight.camera import (
    StageCamera,
    ViewSurface,
    stage_camera,
    subject_geometry,
    vertex_normals,
    view_surface,
)
from facestats.relight.field import FieldStore, make_field
from facestats.relight.lighting import resample_probe
from facestats.relight.relighting import check_relit

__all__ = [
    "StageCamera",
    "stage_camera",
    "subject_geometry",
    "view_surface",
    "SubjectShading",
    "light_stage_field",
    "render_subject",
    "relight_subject",
    "LIGHT_GRID_BYTES",
    "check_light_grid",
]

#: Lights whose shadow maps are held in memory at once.
SHADOW_BATCH = 256
#: Normals whose lights give a lower bound of the lights that reach the face, checked against the memory first.
VISIBILITY_SAMPLE = 64
#: Samples (pixels × lights) evaluated per chunk of the direct render.
RENDER_SAMPLES = 1 << 22
#: Bytes per light of a lat-long grid that :func:`relight_subject` holds at once before the memory check of the
#: visibility table (:func:`check_light_grid`), counted from the code: the grid's directions (3 float64: 24 bytes),
#: kept throughout, with its solid angles (8, dropped on return) and their temporaries (8): 40; in
#: :func:`facestats.relight.lighting.resample_probe`, the directions' unit-normalised copy (24) and the test that
#: they form a lat-long grid (``np.allclose`` against a fresh grid, 24, with its temporaries, 2 × 24 and a boolean
#: 3): 123 with the directions, the peak; then in :func:`render_subject` beside the directions and the resampled
#: probe (3 float64, 24): the directions' unit copy and its norms (32), the float32 weights (12), the weights'
#: finite test (3) and the lights facing the surface (1; beyond 4 M lights a float64 product row and its mask per
#: light, 9): 96 counted, 109 measured with the checks' temporaries.  tracemalloc's slopes between 512x256,
#: 1024x512 and 2048x1024 lights (2026-12-08): 40, 123 and 109 bytes a light for these three steps, 117 over
#: ``relight_subject``; 128 leaves a margin.
LIGHT_GRID_BYTES = 128


def _map_weights(uv, size):
    """Bilinear neighbours and weights of UV coordinates in a size² map indexed [v, u] (texel centres at (i+½)/size)."""
    x = uv[:, 0] * size - 0.5
    y = uv[:, 1] * size - 0.5
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx, fy = x - x0, y - y0
    iv = np.clip(np.stack([y0, y0, y0 + 1, y0 + 1], 1), 0, size - 1)
    iu = np.clip(np.stack([x0, x0 + 1, x0, x0 + 1], 1), 0, size - 1)
    w = np.stack([(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy], 1)
    return iv, iu, w


@dataclass
class SubjectShading:
    """The skin-model parameters of a subject at each pixel of a view (:meth:`from_subject`).

    Attributes
    ----------
    normal : ndarray, shape (N, 3)
        Unit diffuse normals (the subject's fitted normal map, bilinear, renormalised).
    colour : ndarray, shape (N, 3)
        M F_t(N·v)/π R_tot per channel: the diffuse radiance per unit entering
        flux F_t(N·l)(N·l) (Weyrich eq. 6, local transport).
    rho_s, roughness : ndarray, shape (N,)
        Specular parameters of ``specular``.
    cos_o : ndarray, shape (N,)
        N·v.
    specular : str
    eta : float
    """

    normal: np.ndarray
    colour: np.ndarray
    rho_s: np.ndarray
    roughness: np.ndarray
    cos_o: np.ndarray
    specular: str
    eta: float

    @classmethod
    def from_subject(cls, subject, surface: ViewSurface, *, specular="torrance_sparrow", eta=ETA_SKIN):
        """Sample a map subject at the surface's UVs; returns ``(shading, on_face)`` (on_face: (N,) bool).

        A pixel is on the face when at least half of its bilinear weight falls
        on face texels (region > 0); its parameters are the bilinear mean over
        the face texels only.

        Parameters
        ----------
        subject : xarray.Dataset
            A fitted map subject (``region``, ``normal``, ``albedo``, ``albedo_avg``, ``sigma_s_prime``, ``sigma_a``
            and the specular model's two maps).
        surface : ViewSurface
            The pixels of the view and their UVs and view directions (:func:`view_surface`).
        specular : {"torrance_sparrow", "blinn_phong"}
            Which fitted specular model (``ts_rho_s``, ``ts_m`` or ``bp_rho_s``, ``bp_exponent``) to sample.
        eta : float
            Relative index of refraction of the Fresnel terms (default skin's).

        Returns
        -------
        shading : SubjectShading
        on_face : ndarray of bool, shape (N,)

        Raises
        ------
        ValidationError
            An unknown ``specular``, or a subject missing a variable it needs.
        """
        # local import: keeps facestats.io (21 modules) out of this module's import
        from facestats.io.schema import modulation

        check_choice(specular, "specular", SPECULAR_MODELS)
        needed = ("region", "normal", "albedo", "albedo_avg", "sigma_s_prime", "sigma_a")
        missing = [v for v in needed if v not in subject.data_vars]
        if missing:
            raise ValidationError(f"subject must be a fitted map subject with {list(needed)}, missing {missing}")
        size = int(subject.sizes["u"])
        iv, iu, w = _map_weights(surface.uv, size)
        face = (np.asarray(subject["region"].values) > 0)[iv, iu]
        wf = w * face
        tot = wf.sum(1)
        on_face = tot >= 0.5
        wf = wf / np.where(tot > 0, tot, 1)[:, None]

        def sample(name, values=None):
            a = np.asarray(subject[name].values if values is None else values, np.float64)
            return np.einsum("nk,nk...->n...", wf, a[iv, iu])

        rho_var, lobe_var = ("ts_rho_s", "ts_m") if specular == "torrance_sparrow" else ("bp_rho_s", "bp_exponent")
        transport = SubsurfaceTransport(subject["sigma_s_prime"].values, subject["sigma_a"].values, eta)
        shading = cls.from_parameters(
            sample("normal"), surface.view, sample("albedo", modulation(subject).values), sample(rho_var),
            sample(lobe_var), transport, specular=specular, eta=eta,
        )  # fmt: skip
        return shading, on_face

    @classmethod
    def from_parameters(cls, normal, view, modulation, rho_s, roughness, transport: SubsurfaceTransport, *,
                        specular="torrance_sparrow", eta=ETA_SKIN):  # fmt: skip
        """Shading from per-pixel skin-model parameters (normals need not be unit: they are normalised).

        Pixels with a zero normal take the view direction.

        Parameters
        ----------
        normal : array_like, shape (N, 3)
            Diffuse normals.
        view : array_like, shape (N, 3)
            Unit vectors towards the camera.
        modulation : array_like, shape (N, 3)
            M per channel.
        rho_s, roughness : array_like, shape (N,)
            Specular parameters of ``specular`` (Beckmann m, at least 1e-3, or the Blinn-Phong exponent).
        transport : facestats.model.skin.SubsurfaceTransport
            A local-mode transport whose total reflectance R_tot enters the diffuse colour.
        specular : {"torrance_sparrow", "blinn_phong"}
            The specular model.
        eta : float
            Relative index of refraction of the Fresnel terms.

        Returns
        -------
        SubjectShading

        Raises
        ------
        ValidationError
            An unknown ``specular``.
        """
        check_choice(specular, "specular", SPECULAR_MODELS)
        view = np.asarray(view, np.float64)
        normal = np.asarray(normal, np.float64)
        norm = np.linalg.norm(normal, axis=1, keepdims=True)
        normal = np.where(norm > 1e-6, normal / np.where(norm > 1e-6, norm, 1), view)
        rough = np.asarray(roughness, np.float64)
        if specular == "torrance_sparrow":
            rough = np.maximum(rough, 1e-3)  # m > 0 off the face, where the maps hold 0
        cos_o = np.clip(np.einsum("nk,nk->n", normal, view), 0, 1)
        t_o = np.where(cos_o > 0, 1 - fresnel_reflectance_unchecked(cos_o, eta), 0.0)
        colour = np.asarray(modulation, np.float64) * (t_o / np.pi)[:, None] * transport.total_reflectance[None, :]
        return cls(normal, colour, np.asarray(rho_s, np.float64), rough, cos_o, specular, float(eta))

    def subset(self, keep):
        """The pixels selected by a mask or index.

        Parameters
        ----------
        keep : ndarray of bool, shape (N,), or index array
            The pixels to keep.

        Returns
        -------
        SubjectShading
        """
        return SubjectShading(
            self.normal[keep], self.colour[keep], self.rho_s[keep], self.roughness[keep], self.cos_o[keep],
            self.specular, self.eta,
        )  # fmt: skip

    def factors(self, directions, view, visibility):
        """Per (pixel, light): specular radiance and the diffuse shape, per unit irradiance L·δA.

        Parameters
        ----------
        directions : ndarray, shape (L, 3)
            Unit vectors towards the lights.
        view : ndarray, shape (N, 3)
            Unit vectors towards the camera.
        visibility : ndarray, shape (N, L)
            Fraction of each light reaching each pixel, [0, 1].

        Returns
        -------
        specular, shape : ndarray of float32, shape (N, L)
            f_s (N·l) V and F_t(N·l) (N·l) V; the reflectance is
            ``specular + shape · colour`` per channel (module docstring).
        """
        d = directions.astype(np.float32)
        ci = self.normal.astype(np.float32) @ d.T
        io = view.astype(np.float32) @ d.T
        co = np.broadcast_to(self.cos_o.astype(np.float32)[:, None], ci.shape)
        rho = np.broadcast_to(self.rho_s.astype(np.float32)[:, None], ci.shape)
        rough = np.broadcast_to(self.roughness.astype(np.float32)[:, None], ci.shape)
        kernel = _ts_kernel if self.specular == "torrance_sparrow" else _bp_kernel
        ops = [ci, co, io, rho, rough, np.asarray(visibility, np.float32), np.float32(self.eta)]
        return blockwise(kernel, ops, np.float32, n_out=2)


def _shape(ci, vis, eta):
    """F_t(N·l) (N·l) V, 0 below the horizon."""
    c = np.maximum(ci, 0)
    return (1 - fresnel_reflectance_unchecked(np.minimum(c, 1), eta)) * c * vis


def _ts_kernel(ci, co, io, rho, m, vis, eta):
    """Torrance-Sparrow f_s (N·l) V (Weyrich eq. 12-13) and the diffuse shape, per sample (no checks)."""
    cos_delta, k = torrance_sparrow_cosines_unchecked(ci, co, io, eta)
    spec = rho * beckmann_distribution_unchecked(cos_delta, m) * k * np.maximum(ci, 0) * vis
    return spec, _shape(ci, vis, eta)


def _bp_kernel(ci, co, io, rho, n, vis, eta):
    """Blinn-Phong f_s (N·l) V (Weyrich eq. 11) and the diffuse shape, per sample (no checks)."""
    cos_delta, k = torrance_sparrow_cosines_unchecked(ci, co, io, eta)  # N·H, and K = 0 below the horizon
    spec = np.where(k > 0, rho * blinn_phong_lobe_unchecked(cos_delta, n), 0) * np.maximum(ci, 0) * vis
    return spec, _shape(ci, vis, eta)


def _lights_facing(normals, directions, block_elements: int = 1 << 22):
    """Whether each light has some normal facing it (N·l > 0), (L,) bool, over blocks of normals: the whole
    (pixels × lights) product took 1.2 GB at 512² and 8,192 lights (a red team); a block holds ≤ 4 M products."""
    normals = np.asarray(normals).reshape(-1, 3)
    facing = np.zeros(directions.shape[0], bool)
    rows = max(1, block_elements // max(1, directions.shape[0]))
    for a in range(0, normals.shape[0], rows):  # blocks of pixels, not pixels
        facing |= (normals[a : a + rows] @ directions.T > 0).any(axis=0)
    return facing


def _visibility_setup(geometry, surface, normals, directions, shadow_resolution, shadows, progress=False):
    """Vertex visibility (V_used, L_active) of the lights that reach some pixel, and those lights' indices
    (``progress``: a bar over the lights' shadow maps, most of a direct render's time)."""
    used, inverse = np.unique(surface.vertices, return_inverse=True)
    normals = np.asarray(normals).reshape(-1, 3)
    # Every light facing one of a sample of the normals reaches the face: a table that cannot hold even those is
    # refused before the full pass, whose pixels x lights products took minutes at 4096x2048 lights.
    sample = normals[:: max(1, normals.shape[0] // VISIBILITY_SAMPLE)]
    _check_visibility_memory(used.size, int(np.count_nonzero(_lights_facing(sample, directions))), at_least=True)
    active = np.nonzero(_lights_facing(normals, directions))[0]
    _check_visibility_memory(used.size, active.size)  # the table of ones without shadows too
    if not shadows or active.size == 0:
        return np.ones((used.size, active.size), np.float32), active, inverse.reshape(surface.vertices.shape)
    verts = np.asarray(geometry.mesh_vertices, np.float64)
    faces = np.asarray(geometry.mesh_faces, np.int64)
    vn = vertex_normals(verts, faces)
    target = 0.5 * (verts.min(0) + verts.max(0))
    eyes = target + DISTANT_LIGHT_MM * directions[active]
    vis = np.empty((used.size, active.size), np.float32)
    with progress_bar(total=active.size, desc="shadow maps", unit="light", enabled=progress, leave=False) as bar:
        for a in range(0, active.size, SHADOW_BATCH):  # batches of lights: bounded memory for many lights
            maps = ShadowMaps(verts, faces, eyes[a : a + SHADOW_BATCH], target=target, resolution=shadow_resolution)
            vis[:, a : a + SHADOW_BATCH] = maps.visible(verts[used], vn[used])
            bar.update(min(SHADOW_BATCH, active.size - a))
    return vis, active, inverse.reshape(surface.vertices.shape)


def check_light_grid(n_theta: int, n_phi: int, *, name: str = "lights", value=None) -> None:
    """Refuse, before any array of it is made, a lat-long light grid whose own arrays exceed the memory available.

    A grid's directions, solid angles, resampled probe and their temporaries take :data:`LIGHT_GRID_BYTES` per
    light before the visibility table is checked (:func:`_check_visibility_memory`): a grid just under the cap of
    ``--lights`` (2^28 lights) built 6 GiB of directions and more before that check refused it.

    Parameters
    ----------
    n_theta, n_phi : int
        The grid (azimuths θ × inclinations φ), integers ≥ 1.
    name : str
        The option or argument for the message (``"--lights"`` on the command line).
    value : object, optional
        Its value as given, for the message (default ``(n_theta, n_phi)``).

    Raises
    ------
    ValidationError
        Naming ``name``, the value, the bytes needed and available, and the most lights (and the largest 2:1 grid,
        the stage's layout) that fit.
    """
    n = int(n_theta) * int(n_phi)  # Python integers: no overflow
    need, have = LIGHT_GRID_BYTES * n, available_memory()
    if have is None or need <= have:
        return
    fit = int(have // LIGHT_GRID_BYTES)
    side = math.isqrt(fit // 2)
    largest = f"{2 * side}x{side}" if side else "none"
    shown = (n_theta, n_phi) if value is None else value
    raise ValidationError(
        f"{name} must make at most {fit:,} lights on this machine (the largest 2:1 grid that fits: {largest}), got "
        f"{shown!r} = {n:,} lights, whose directions, resampled probe and their temporaries need "
        f"{need / 2**20:,.0f} MiB ({LIGHT_GRID_BYTES} bytes a light, before the shadow maps' visibility table), more "
        f"than the {have / 2**20:,.0f} MiB available"
    )


def _check_visibility_memory(n_vertices: int, n_lights: int, *, at_least: bool = False) -> None:
    """Refuse, before the shadow maps, a visibility table (float32, one value per mesh vertex and light that reaches
    the face) larger than the memory available (:func:`facestats.core.processes.available_memory`).

    The table is what grows with the lights: 4 bytes × vertices per light (17 KB on the default face; the
    relight of S001 took 0.40, 0.50 and 0.92 GB at 64x32, 128x64 and 256x128 lights, 2026-12-07), so a grid far
    finer than the probe failed late with an out-of-memory error (100000x100000 asked for 74.5 GiB).  The
    message names the most lights that fit; ``at_least``: ``n_lights`` is a lower bound of those that reach the
    face (a sample of its normals'), as the message says.
    """
    need, have = 4.0 * n_vertices * n_lights, available_memory()
    if have is not None and need > have:
        reach = f"{n_lights:,} or more reach the face" if at_least else f"{n_lights:,} reach the face"
        raise ValidationError(
            f"lights must be at most {int(have // (4.0 * n_vertices)):,} on this machine: {reach}, and their "
            f"visibility at its {n_vertices:,} mesh vertices needs {need / 2**20:,.0f} MiB, more than the "
            f"{have / 2**20:,.0f} MiB available"
        )


def _prepare(subject, geometry, camera, directions, *, specular, eta, shadows, shadow_resolution, progress=False):
    """Shared set-up of the stage and of the direct render: surface, shading, visibility."""
    if geometry is None:
        geometry = subject_geometry(subject)
    if not isinstance(geometry, FaceGeometry):
        raise ValidationError(f"geometry must be a FaceGeometry, got {type(geometry).__name__}")
    if not isinstance(camera, StageCamera):
        raise ValidationError(f"camera must be a StageCamera (facestats.relight.stage_camera), got {camera!r}")
    surface = view_surface(geometry, camera)
    shading, on_face = SubjectShading.from_subject(subject, surface, specular=specular, eta=eta)
    if not on_face.any():  # an image with nothing on it is an error, not a black file with a NaN mean
        raise ValidationError(_no_face_seen(subject, geometry, camera, surface.pixel.size))
    surface, shading = surface.subset(on_face), shading.subset(on_face)
    res = check_integer(shadow_resolution, "shadow_resolution", 8, 4096)
    vis_v, active, vidx = _visibility_setup(geometry, surface, shading.normal, directions, res, shadows, progress)
    return surface, shading, vis_v, active, vidx


def _no_face_seen(subject, geometry, camera, covered) -> str:
    """Why ``camera`` sees no face pixel: the mesh's extent and distance against the camera's view, or (``covered``
    pixels on the mesh) a mesh whose UVs miss the maps' face texels."""
    sid = subject.attrs.get("subject_id", "?")
    verts = np.asarray(geometry.mesh_vertices, np.float64)
    if covered:
        return (
            f"camera sees {covered} pixels of the mesh of {geometry.name!r} but none on a face texel of subject "
            f"{sid!r}: the mesh's UV layout is not the one the subject's maps follow"
        )
    across = float(np.ptp(verts, axis=0).max())
    dist = float(np.linalg.norm(verts.mean(0) - camera.position))
    width = 2 * dist * np.tan(np.radians(camera.fov_deg) / 2)
    return (
        f"camera sees no pixel of the face of subject {sid!r}: its mesh {geometry.name!r} is {across:.4g} mm across, "
        f"{dist:.4g} mm from the camera, whose {camera.fov_deg:g}° view is {width:.4g} mm wide there (a mesh in "
        "another unit than mm, or a camera aimed away from the face)"
    )


def _pixel_visibility(vis_v, vidx, bary, rows):
    """Barycentric interpolation of vertex visibility to the pixels ``rows``: (n, L_active) float32."""
    b = bary[rows].astype(np.float32)
    v = vidx[rows]
    return b[:, 0:1] * vis_v[v[:, 0]] + b[:, 1:2] * vis_v[v[:, 1]] + b[:, 2:3] * vis_v[v[:, 2]]


def _light_set(directions):
    """(flat unit directions (L, 3), grid shape or None) of the stage's lights (default 64 × 32)."""
    if directions is None:
        directions, _ = light_stage_directions()
    d = unit_directions(directions)
    if d.ndim == 3:
        return d.reshape(-1, 3), d.shape[:2]
    check_shape(d, "directions", (None, 3))
    return d, None


def _tiles_of(pixel, size, tile):
    """Pixels grouped by image tile: ``[(tile row, tile col, indices into pixel)]``."""
    rows, cols = pixel // size, pixel % size
    key = (rows // tile) * ((size + tile - 1) // tile) + cols // tile
    order = np.argsort(key, kind="stable")
    bounds = np.flatnonzero(np.diff(key[order])) + 1
    n_tx = (size + tile - 1) // tile
    return [(int(key[g[0]] // n_tx), int(key[g[0]] % n_tx), g) for g in np.split(order, bounds) if g.size]


def light_stage_field(
    subject,
    camera: StageCamera | None = None,
    *,
    geometry: FaceGeometry | None = None,
    directions=None,
    specular: str = "torrance_sparrow",
    eta: float = ETA_SKIN,
    shadows: bool = True,
    shadow_resolution: int = 128,
    tile: int = 64,
    out=None,
    dtype: str = "float32",
    overwrite: bool = False,
    progress: bool = False,
    visibility: bool = False,
):
    """Image a fitted subject under every light of a light stage: its reflectance field (module docstring).

    Parameters
    ----------
    subject : xarray.Dataset
        A map subject of the store (fitted maps, σ's, σa).
    camera : StageCamera or list of StageCamera, optional
        Default: the frontal camera of :func:`stage_camera` (256²).  A list gives
        one field per camera (``out`` then lists one store per camera).
    geometry : FaceGeometry, optional
        Default: the subject's recorded procedural head (:func:`subject_geometry`).
    directions : array_like, optional
        Light directions: a lat-long grid (n_phi, n_theta, 3) (default Debevec's
        64 × 32, :func:`facestats.model.sphere.light_stage_directions`) or any
        list (L, 3) (solid angles then from spherical Voronoi cells).
    specular : {"torrance_sparrow", "blinn_phong"}
        Which fitted specular model renders highlights.
    eta : float
        Relative index of refraction (Fresnel terms).
    shadows : bool
        Cast shadows from the face mesh (False: only the N·l > 0 test).
    shadow_resolution : int
        Side of each light's shadow map, pixels.
    tile : int
        Image tile side: the unit of work and the zarr chunk.
    out : str or path-like, optional
        Write the field to this zarr store tile by tile (memory: one tile under
        all lights) and return it opened lazily; default: in memory.
    dtype : {"float32", "float16"}
        Storage type when writing to ``out``.
    overwrite : bool
        Replace an existing store at ``out``.
    progress : bool
        Show a progress bar over tiles.
    visibility : bool
        Also return the geometric visibility (in memory only): a ``visibility``
        variable (light dims, y, x), the fraction of each light reaching each
        pixel's front side (N·l > 0, unoccluded) — the truth that the
        thresholded shadow maps of :mod:`facestats.relight.shadows` estimate.

    Returns
    -------
    xarray.Dataset (or a list of them, one per camera)
        The field (:mod:`facestats.relight.field`) with ``mask``, ``view``,
        ``normal`` and ``position`` per pixel; attributes record the subject,
        camera and model.
    """
    if isinstance(camera, (list, tuple)):  # several cameras: one field each (Debevec used two)
        outs = [None] * len(camera) if out is None else list(out)
        if len(outs) != len(camera):
            raise ValidationError(f"out must list one store per camera ({len(camera)}), got {len(outs)}")
        kw = dict(geometry=geometry, directions=directions, specular=specular, eta=eta, shadows=shadows,
                  shadow_resolution=shadow_resolution, tile=tile, dtype=dtype, overwrite=overwrite,
                  progress=progress, visibility=visibility)  # fmt: skip
        return [light_stage_field(subject, cam, out=o, **kw) for cam, o in zip(camera, outs)]
    camera = stage_camera() if camera is None else camera
    flat, grid = _light_set(directions)
    surface, shading, vis_v, active, vidx = _prepare(
        subject, geometry, camera, flat, specular=specular, eta=eta, shadows=shadows,
        shadow_resolution=shadow_resolution, progress=progress,
    )  # fmt: skip
    size = camera.size
    t = check_integer(tile, "tile", 1)
    per_pixel = _per_pixel_maps(surface, shading, size)
    lshape = grid if grid is not None else (flat.shape[0],)
    attrs = {
        "source": "facestats virtual light stage",
        "subject_id": str(subject.attrs.get("subject_id", "?")),
        "specular": specular,
        "eta": float(eta),
        "shadows": bool(shadows),
        "camera_position_mm": camera.position.tolist(),
        "camera_target_mm": camera.target.tolist(),
        "camera_fov_deg": camera.fov_deg,
    }
    dirs = flat.reshape(lshape + (3,))
    if visibility and out is not None:
        raise ValidationError("visibility=True keeps the field in memory: it cannot be combined with out=")
    store = None
    if out is not None:
        store = FieldStore(out, dirs, (size, size), per_pixel=per_pixel, attrs=attrs, dtype=dtype, tile=t,
                           overwrite=overwrite)  # fmt: skip
    sink = _Sink(flat.shape[0], size, t, active, store, visibility)
    try:
        for ti, tj, rows in progress_bar(_tiles_of(surface.pixel, size, t), desc="light stage tiles", enabled=progress,
                                 leave=False):  # fmt: skip
            vis = _pixel_visibility(vis_v, vidx, surface.bary, rows)
            spec, shape = shading.subset(rows).factors(flat[active], surface.view[rows], vis)
            refl = spec[..., None] + shape[..., None] * shading.colour[rows, None, :].astype(np.float32)  # (n, La, 3)
            facing = (shading.normal[rows] @ flat[active].T) > 0
            sink.put(ti, tj, surface.pixel[rows], refl, vis * facing)
        if store is not None:
            return store.close()
    except BaseException:
        if store is not None:
            store.abort()
        raise
    ds = make_field(sink.values.reshape(lshape + (size, size, 3)), dirs, attrs=attrs, **per_pixel)
    if visibility:
        ldims = ("light_phi", "light_theta") if grid is not None else ("light",)
        ds["visibility"] = (ldims + ("y", "x"), sink.visibility.reshape(lshape + (size, size)))
    return ds


class _Sink:
    """Where the stage's tiles go: in-memory arrays, or tile by tile into a :class:`FieldStore`."""

    def __init__(self, n_lights, size, tile, active, store, visibility):
        self.n, self.size, self.tile, self.active, self.store = n_lights, size, tile, active, store
        self.values = np.zeros((n_lights, size, size, 3), np.float32) if store is None else None
        self.visibility = np.zeros((n_lights, size, size), np.float32) if visibility else None

    def put(self, ti, tj, pixels, refl, vis):
        """Reflectance (n, La, 3) and visibility (n, La) of the tile's face pixels (flat indices)."""
        r, c = pixels // self.size, pixels % self.size
        a = self.active[:, None]
        if self.visibility is not None:
            self.visibility[a, r[None, :], c[None, :]] = vis.T
        if self.store is None:
            self.values[a, r[None, :], c[None, :], :] = np.swapaxes(refl, 0, 1)
            return
        t, y0, x0 = self.tile, ti * self.tile, tj * self.tile
        block = np.zeros((self.n, min(t, self.size - y0), min(t, self.size - x0), 3), np.float32)
        block[a, (r - y0)[None, :], (c - x0)[None, :], :] = np.swapaxes(refl, 0, 1)
        self.store.write(slice(y0, y0 + block.shape[1]), slice(x0, x0 + block.shape[2]), block)


def _per_pixel_maps(surface, shading, size):
    """``mask``, ``view``, ``normal``, ``position`` images of the covered face pixels (0 elsewhere)."""
    n = size * size
    mask = np.zeros(n, bool)
    mask[surface.pixel] = True
    out = {"mask": mask.reshape(size, size)}
    for name, vals in (("view", surface.view), ("normal", shading.normal), ("position", surface.position)):
        img = np.zeros((n, 3), np.float32)
        img[surface.pixel] = vals
        out[name] = img.reshape(size, size, 3)
    return out


def render_subject(
    subject,
    lighting,
    directions=None,
    camera: StageCamera | None = None,
    *,
    geometry: FaceGeometry | None = None,
    specular: str = "torrance_sparrow",
    eta: float = ETA_SKIN,
    shadows: bool = True,
    shadow_resolution: int = 128,
    chunk: int | None = None,
    progress: bool = False,
):
    """Render a subject directly under distant lights with weights L·δA: Σ_l R_l L_l δA_l without a stored field.

    The same surface, shading and visibility as :func:`light_stage_field`; each
    chunk of pixels is summed over the lights at once.  Relighting a stage field
    with the same lights must give this image (the cross-check of both paths).

    Parameters
    ----------
    subject : xarray.Dataset
    lighting : array_like, shape (L, 3) or directions.shape[:-1] + (3,)
        L·δA per light and channel (:func:`facestats.relight.lighting.resample_probe`), ≥ 0.
    directions : array_like, optional
        Light directions (default the 64 × 32 stage).  For a full-resolution
        probe pass :func:`facestats.model.sphere.latlong_directions` of its size
        and the probe times :func:`~facestats.model.sphere.latlong_solid_angles`.
    camera, geometry, specular, eta, shadows, shadow_resolution
        As :func:`light_stage_field`.
    chunk : int, optional
        Pixels per chunk (default: about 4 million pixel-light samples per chunk).
    progress : bool
        Show a progress bar over the chunks.

    Returns
    -------
    image : ndarray of float32, shape (size, size, 3)
        Radiance in the unit of ``lighting`` per sr (0 off the face).
    mask : ndarray of bool, shape (size, size)
    """
    camera = stage_camera() if camera is None else camera
    flat, _ = _light_set(directions)
    w = as_finite(lighting, "lighting", 0, None, dtype=np.float64)
    if w.ndim < 1 or w.shape[-1] != 3:
        raise ValidationError(f"lighting must hold L·δA per light and channel, shape (L, 3), got {w.shape}")
    w = w.reshape(-1, 3)
    if w.shape[0] != flat.shape[0]:
        raise ValidationError(f"lighting must hold one RGB weight per light ({flat.shape[0]}), got {w.shape[0]}")
    w32 = as_float(w, "lighting", np.float32)  # its range checked before the shadow maps are made
    surface, shading, vis_v, active, vidx = _prepare(
        subject, geometry, camera, flat, specular=specular, eta=eta, shadows=shadows,
        shadow_resolution=shadow_resolution, progress=progress,
    )  # fmt: skip
    wa = w32[active]
    step = max(1, RENDER_SAMPLES // max(active.size, 1)) if chunk is None else check_integer(chunk, "chunk", 1)
    out = np.zeros((surface.pixel.size, 3), np.float32)
    chunks = range(0, surface.pixel.size, step)
    for a in progress_bar(chunks, desc="render", unit="chunk", enabled=progress, leave=False):  # chunks of pixels
        rows = np.arange(a, min(a + step, surface.pixel.size))
        vis = _pixel_visibility(vis_v, vidx, surface.bary, rows)
        spec, shape = shading.subset(rows).factors(flat[active], surface.view[rows], vis)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported by check_relit
            out[rows] = (spec @ wa) + (shape @ wa) * shading.colour[rows].astype(np.float32)
    img = np.zeros((camera.size * camera.size, 3), np.float32)
    img[surface.pixel] = out
    mask = np.zeros(camera.size * camera.size, bool)
    mask[surface.pixel] = True
    image = check_relit(img.reshape(camera.size, camera.size, 3), "render_subject")
    return image, mask.reshape(camera.size, camera.size)


def relight_subject(
    subject,
    probe,
    *,
    layout: str = "latlong",
    rotate: float = 0.0,
    camera: StageCamera | None = None,
    lights: tuple = (64, 32),
    geometry: FaceGeometry | None = None,
    specular: str = "torrance_sparrow",
    shadows: bool = True,
    progress: bool = False,
):
    """A store subject relit under a light probe through the virtual light stage (Debevec et al. 2000 eq. 4).

    The probe is resampled to the stage's ``lights`` = (n_theta, n_phi) lat-long
    directions (:func:`facestats.relight.lighting.resample_probe`, exact cell
    integrals) and the subject rendered under those lights
    (:func:`render_subject`); this equals relighting the subject's stage field
    (:func:`light_stage_field`) with the same probe, without storing the field.  ``progress``: a progress bar
    over the rendered chunks.

    Parameters
    ----------
    subject : xarray.Dataset
        A map subject of the store (fitted maps, σ's, σa).
    probe : array_like, shape (H, W, 3)
        Linear radiance of the light probe (any unit).
    layout : {"latlong", "angular"}
        Layout of the probe (:func:`facestats.model.sphere.check_probe`).
    rotate : float
        Rotate the environment about +y by this angle first (radians, right-handed,
        :func:`facestats.relight.lighting.rotate_probe`).
    camera : StageCamera, optional
        Default: the frontal camera of :func:`stage_camera`.
    lights : tuple of int
        (n_theta, n_phi) of the lat-long light stage the probe is resampled to
        (:func:`facestats.model.sphere.light_stage_directions`).
    geometry : FaceGeometry, optional
        Default: the subject's recorded procedural head (:func:`subject_geometry`).
    specular : {"torrance_sparrow", "blinn_phong"}
        Which fitted specular model renders highlights.
    shadows : bool
        Cast shadows from the face mesh (False: only the N·l > 0 test).
    progress : bool
        Show a progress bar over the rendered chunks.

    Returns
    -------
    image : ndarray of float32, shape (size, size, 3)
        Linear radiance in the probe's unit.
    mask : ndarray of bool, shape (size, size)

    Raises
    ------
    ValidationError
        ``lights`` not two integers ≥ 1 or a grid whose arrays exceed the memory available (:func:`check_light_grid`),
        or a probe or option the resampling or the renderer refuses.
    """

    if np.ndim(lights) != 1 or np.size(lights) != 2:
        raise ValidationError(f"lights must be (n_theta, n_phi), two integers, got {lights!r}")
    n_theta, n_phi = check_integer(lights[0], "n_theta", 1), check_integer(lights[1], "n_phi", 1)
    check_light_grid(n_theta, n_phi, value=lights)  # before any array of the grid
    d, _ = light_stage_directions(n_theta, n_phi)
    w = resample_probe(probe, d, layout=layout, rotate=rotate)
    return render_subject(
        subject, w, d, camera, geometry=geometry, specular=specular, shadows=shadows, progress=progress
    )
