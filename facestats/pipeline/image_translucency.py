"""Translucency from one image of a known scene: mesh, lights and camera in, (σ's, σa) per channel out.

The stage behind ``facestats translucency``: the patches of the mesh
(:func:`facestats.acquire.patches.read_mesh_patches` or given), c_k from the
lights (eq. 16, :func:`facestats.acquire.lights.patch_irradiance`, with shadow
maps), l_j and the seen patches from the radiance image (eq. 15,
:func:`facestats.acquire.scene.patch_radiance`), then
:func:`facestats.model.fitting.fit_scattering_channels` per image channel
(channels lit alike share one W).
"""

from __future__ import annotations

import numpy as np

from facestats.acquire.camera import PinholeCamera
from facestats.acquire.lights import load_lights, patch_irradiance
from facestats.acquire.patches import read_mesh_patches
from facestats.acquire.scene import patch_radiance, read_radiance_image
from facestats.core.validate import check_choice
from facestats.errors import ValidationError
from facestats.model.fitting.profile_grid import TABLE2_GRID, ProfileGrid
from facestats.model.fitting.scattering_image import fit_scattering_channels

__all__ = ["GRIDS", "fit_image_translucency", "load_scene_inputs"]

#: Named grids of the command line: Suzuki Table 2, or log-spaced for skin-like media.
GRIDS = {"table2": TABLE2_GRID, "skin": ProfileGrid.log_spaced((0.05, 20.0), (1e-3, 5.0), (160, 160))}


def load_scene_inputs(mesh, lights, camera, image, *, spacing=1.0, scale=1.0):
    """``(patches, lights, eta, camera, image)`` from a mesh (OBJ/PLY), lights and camera (JSON) and an HDR image.

    Parameters
    ----------
    mesh : path
        Triangle mesh of the lit surface (OBJ or PLY), in the frame of the lights and camera.
    lights : path
        JSON description of the lights and the relative index of refraction
        (:func:`facestats.acquire.lights.load_lights`).
    camera : path
        JSON pinhole camera (:meth:`facestats.acquire.camera.PinholeCamera.load`).
    image : path
        Linear radiance image (OpenEXR, PFM or ``.npz``: :func:`facestats.acquire.scene.read_radiance_image`).
    spacing : float
        Target patch edge, mm (:func:`facestats.acquire.patches.mesh_patches`).
    scale : float
        Mesh units to mm.

    Returns
    -------
    tuple
        ``(patches, lights, eta, camera, image)``: the inputs of :func:`fit_image_translucency`.
    """

    light_list, eta = load_lights(lights)
    cam = PinholeCamera.load(camera)
    img = read_radiance_image(image)
    patches = read_mesh_patches(mesh, spacing=spacing, scale=scale)
    return patches, light_list, eta, cam, img


def fit_image_translucency(
    patches, lights, camera, image, *, eta=1.3, width="auto", method="monotone", grid="table2", **options
) -> list:
    """Fit the dipole to one radiance image of known patches, lights and camera (module docstring).

    Parameters
    ----------
    patches : Patches
    lights : list of lights (:mod:`facestats.acquire.lights`)
    camera : PinholeCamera
    image : ndarray, shape (H, W), (H, W, 1) or (H, W, 3)
        Linear radiance.  An RGB image is fitted per channel against the lights'
        RGB irradiance.  A grey image is fitted once against the mean of the
        lights' R, G and B irradiance: a camera equally sensitive to the three
        light colours (exact for white lights; for coloured lights, give RGB).
    eta : float
        Relative index of refraction (Suzuki: 1.3).
    width, method
        As :func:`facestats.model.fitting.fit_scattering_image`.
    grid : str or ProfileGrid
        ``"table2"``, ``"skin"`` (:data:`GRIDS`) or a grid.
    **options
        Passed to :func:`facestats.model.fitting.fit_scattering_channels`.

    Returns
    -------
    list of ScatteringImageFit
        One per image channel.
    """
    shape = np.shape(image)
    if len(shape) not in (2, 3) or (len(shape) == 3 and shape[2] not in (1, 3)):
        raise ValidationError(f"image must have shape (H, W), (H, W, 1) or (H, W, 3), got {shape}")
    if isinstance(grid, str):
        check_choice(grid, "grid", GRIDS)
        grid = GRIDS[grid]
    c = patch_irradiance(patches, lights, eta=eta)
    l, seen = patch_radiance(image, camera, patches, eta=eta)
    if l.shape[1] == 1:  # grey: equal sensitivity to the lights' three colours (docstring)
        c = c.mean(axis=1, keepdims=True)
    return fit_scattering_channels(
        patches.centre, patches.area, c, l, width=width, visible=seen, eta=eta, method=method, grid=grid, **options
    )
