"""Known scenes for translucency from one image: Suzuki's pyramid and patches of the procedural face.

* :func:`square_pyramid` and :func:`pyramid_scene` — Suzuki, Mukaigawa & Yagi
  §4.1: "a square pyramid under one light" (Fig. 4), rendered with the dipole of
  Table 1.  The paper gives neither its size nor its light; facestats uses a
  pyramid of base 50 mm and height 25 mm (45° faces, apex towards +z, the
  camera), patches of edge ``spacing`` (:func:`facestats.acquire.patches.mesh_patches`),
  and one distant light: ``"edge"`` from (1, 0, −0.1), which lights only the +x
  face so the other three see light only through the medium (edge-like
  lighting: a lit half and a shadowed half), ``"oblique"`` from (1, 0.5, 0.5),
  lighting two faces unequally, or ``"uniform"`` from +z, which lights all four
  faces equally (the ill-posed case).  The camera looks down −z from 400 mm.
* :func:`face_site_scene` — a window of the procedural face
  (:func:`facestats.face.procedural.face_window`) around the cheek or
  forehead site, lit by a projector (a point light 300 mm away along the site
  normal with planar cuts, :class:`facestats.acquire.lights.PointLight`): a
  ``"stripe"`` 4 mm wide and 10 mm long, or a ``"spot"`` of 3 mm radius, both
  entirely inside the window so that the window holds all the light that enters
  the skin; a close-up camera 250 mm away along the normal with pixels of a quarter of the
  grid spacing.
* :func:`plate_scene` — a flat 40 mm plate under a point light 300 mm above: a
  ``"spot"`` (a cone of 1° half-angle, radius 5.2 mm on the plate), a
  ``"stripe"`` (a cut through the light: the half x ≥ 0 lit) or ``"uniform"``
  (no cone, no cut: the whole plate lit within 1.3 %, the ill-posed case of
  :mod:`facestats.model.fitting.light_edges`); the pyramid's camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.acquire.camera import PinholeCamera
from facestats.acquire.lights import DirectionalLight, PointLight
from facestats.acquire.patches import Patches, mesh_patches
from facestats.core.validate import as_scalar, check_choice
from facestats.errors import ValidationError
from facestats.face.procedural import SITE_CENTRES, face_window

__all__ = [
    "PatchScene",
    "square_pyramid",
    "pyramid_scene",
    "plate_scene",
    "face_site_scene",
    "PYRAMID_LIGHTS",
    "PLATE_LIGHTS",
    "SITE_LIGHTS",
]

#: Directions towards the distant light of :func:`pyramid_scene`.
PYRAMID_LIGHTS = {"edge": (1.0, 0.0, -0.1), "oblique": (1.0, 0.5, 0.5), "uniform": (0.0, 0.0, 1.0)}
#: Lights of :func:`plate_scene`: a point light 300 mm above the plate's centre, with a 1° cone, one cut or neither.
PLATE_LIGHTS = ("spot", "stripe", "uniform")
#: Projector patterns of :func:`face_site_scene`.
SITE_LIGHTS = ("stripe", "spot")


@dataclass
class PatchScene:
    """Patches, lights and a camera of a known scene (all mm; lights as :mod:`facestats.acquire.lights`).

    Attributes
    ----------
    patches : Patches
        The surface patches (:mod:`facestats.acquire.patches`).
    lights : list
        :class:`~facestats.acquire.lights.DirectionalLight` or :class:`~facestats.acquire.lights.PointLight`.
    camera : PinholeCamera
    eta : float
        Relative index of refraction of the scene's medium (1.3 for the pyramid, 1.38 for the face).
    name : str
    """

    patches: Patches
    lights: list
    camera: PinholeCamera
    eta: float
    name: str = "scene"


def square_pyramid(base=50.0, height=25.0):
    """A square pyramid (vertices (5, 3) mm, faces (6, 3)): base on z = 0, apex at (0, 0, height), outward normals.

    Parameters
    ----------
    base : float
        Side of the square base centred on the origin, mm (> 0).
    height : float
        mm (> 0).

    Returns
    -------
    vertices : ndarray of float64, shape (5, 3)
        The four base corners, then the apex.
    faces : ndarray of int, shape (6, 3)
        The four lateral triangles, then the base's two.

    Raises
    ------
    ValidationError
        ``base`` or ``height`` not a number > 0.
    """
    b = as_scalar(base, "base", 0, None, low_inclusive=False, unit="mm") / 2
    h = as_scalar(height, "height", 0, None, low_inclusive=False, unit="mm")
    v = np.array([[b, b, 0], [-b, b, 0], [-b, -b, 0], [b, -b, 0], [0, 0, h]], float)
    f = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [0, 2, 1], [0, 3, 2]])
    return v, f


def pyramid_scene(spacing=1.8, light="edge", *, base=50.0, height=25.0, image_size=400) -> PatchScene:
    """Suzuki §4.1's scene (module docstring): pyramid patches, one distant light, a camera above.

    Only the four lateral faces become patches (the base faces away from light
    and camera); the whole pyramid is the occluder.

    Parameters
    ----------
    spacing : float
        Target patch edge length in mm (:func:`facestats.acquire.patches.mesh_patches`).
    light : {"edge", "oblique", "uniform"}
        The distant light (:data:`PYRAMID_LIGHTS`, E⊥ = 1).
    base, height : float
        As :func:`square_pyramid`, mm.
    image_size : int
        Side of the square camera image in pixels; the base spans about 80 % of it.

    Returns
    -------
    PatchScene
        With η = 1.3 and the name ``"pyramid-<light>"``.

    Raises
    ------
    ValidationError
        An unknown ``light``, or a bad ``spacing``, ``base`` or ``height``.
    """
    check_choice(light, "light", PYRAMID_LIGHTS)
    v, f = square_pyramid(base, height)
    patches = mesh_patches(v, f[:4], spacing=spacing, occluder=False)
    patches = Patches(patches.centre, patches.normal, patches.area, patches.corners, v, f)
    lights = [DirectionalLight(PYRAMID_LIGHTS[light], 1.0)]
    size = int(image_size)
    focal = size / 2 / (0.6 * float(base)) * 400.0  # the base spans ~80 % of the image
    camera = PinholeCamera.looking_at((0.0, 0.0, 400.0), (0.0, 0.0, 0.0), focal_px=focal, image_size=(size, size))
    return PatchScene(patches, lights, camera, 1.3, name=f"pyramid-{light}")


def plate_scene(spacing=1.0, light="spot", *, side=40.0, image_size=300) -> PatchScene:
    """A flat square plate (z = 0, normal +z) under a point light 300 mm above its centre (module docstring).

    The mesh is a grid of ``side`` / 2 mm squares of two triangles each (20 × 20 squares), counter-clockwise seen
    from +z; patches of edge ``spacing`` (:func:`facestats.acquire.patches.mesh_patches`).  The light has radiant
    intensity 4·10⁴ per channel (irradiance about 0.44 at the plate); ``"spot"`` adds a cone of half-angle 1°
    around −z (``PointLight`` takes it in radians), ``"stripe"`` the cut n = (1, 0, 0) through the light.

    Parameters
    ----------
    spacing : float
        Target patch edge length in mm.
    light : {"spot", "stripe", "uniform"}
        :data:`PLATE_LIGHTS`.
    side : float
        Side of the plate, mm (> 0).
    image_size : int
        Side of the square image of the camera 400 mm above, which sees the plate over about 2/3 of it.

    Returns
    -------
    PatchScene
        With η = 1.3 and the name ``"plate-<light>"``.
    """
    check_choice(light, "light", PLATE_LIGHTS)
    half = as_scalar(side, "side", 0, None, low_inclusive=False, unit="mm") / 2
    n = 20
    xs = np.linspace(-half, half, n + 1)
    gx, gy = np.meshgrid(xs, xs)
    v = np.c_[gx.ravel(), gy.ravel(), np.zeros(gx.size)]
    a = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()  # lower-left corner of each square
    f = np.concatenate([np.c_[a, a + 1, a + n + 2], np.c_[a, a + n + 2, a + n + 1]])
    patches = mesh_patches(v, f, spacing=spacing, occluder=False)
    patches = Patches(patches.centre, patches.normal, patches.area, patches.corners, v, f)
    cone = (np.array([0.0, 0.0, -1.0]), np.radians(1.0)) if light == "spot" else None
    cuts = (np.array([1.0, 0.0, 0.0]),) if light == "stripe" else ()
    lights = [PointLight(np.array([0.0, 0.0, 300.0]), 4e4, cuts, cone)]
    size = int(image_size)
    focal = size / 2 / (0.6 * 2 * half) * 400.0
    camera = PinholeCamera.looking_at((0.0, 0.0, 400.0), (0.0, 0.0, 0.0), focal_px=focal, image_size=(size, size))
    return PatchScene(patches, lights, camera, 1.3, name=f"plate-{light}")


def face_site_scene(site="cheek", light="stripe", *, spacing=0.3, half_width=9.0, pixel_fraction=0.25) -> PatchScene:
    """A window of the procedural face around a sensor site, a projector pattern and a close-up camera.

    Parameters
    ----------
    site : {"cheek", "forehead"}
    light : {"stripe", "spot"}
    spacing : float
        Grid spacing of the window's mesh in x and y, mm; each triangle (two per
        grid cell) is a patch.
    half_width : float
        Half side of the window, mm (≥ 6: the pattern must fit with a margin).
    pixel_fraction : float
        Camera pixel size as a fraction of ``spacing``.

    Returns
    -------
    PatchScene
        The patches, lights and camera of the window.
    """

    check_choice(site, "site", tuple(SITE_CENTRES))
    check_choice(light, "light", SITE_LIGHTS)
    hw = as_scalar(half_width, "half_width", 6.0, None, unit="mm")
    v, f, centre, normal = face_window(site, half_width=hw, spacing=spacing)
    patches = mesh_patches(v, f, spacing=None)  # one patch per triangle of the window's grid
    # Projector frame: e1, e2 span the tangent plane at the site centre.
    e1 = np.cross([0.0, 1.0, 0.0], normal)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    pos = centre + 300.0 * normal
    if light == "stripe":  # 4 mm × 10 mm at the site: four planes through the projector
        cuts = []
        for axis, half in ((e1, 2.0), (e2, 5.0)):
            t = np.cross(normal, axis)  # direction of the pattern's edges across this axis
            for sign in (1.0, -1.0):
                n = np.cross(centre + sign * half * axis - pos, t)  # plane through projector and edge
                n *= np.sign(np.dot(centre - pos, n))  # the site centre is on the lit side
                cuts.append(n / np.linalg.norm(n))
        lights = [PointLight(pos, 300.0**2, tuple(cuts))]
    else:
        half = np.arctan2(3.0, 300.0)
        lights = [PointLight(pos, 300.0**2, (), (-normal, half))]
    pix = pixel_fraction * spacing
    cam_pos = centre + 250.0 * normal
    size = int(np.ceil(3.0 * hw / pix))  # the window's corners lie √2 hw from its centre
    camera = PinholeCamera.looking_at(cam_pos, centre, focal_px=250.0 / pix, image_size=(size, size))
    if not np.all(camera.in_frame(patches.centre)):
        raise ValidationError("the close-up camera does not frame the whole window; lower half_width")
    return PatchScene(patches, lights, camera, 1.38, name=f"face-{site}-{light}")
