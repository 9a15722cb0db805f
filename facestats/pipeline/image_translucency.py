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

import os

import numpy as np

from facestats.acquire.camera import PinholeCamera
from facestats.acquire.lights import load_lights, patch_irradiance
from facestats.acquire.patches import Patches, read_mesh_patches
from facestats.acquire.scene import patch_radiance, read_radiance_image
from facestats.core.validate import check_choice
from facestats.errors import ValidationError
from facestats.model.fitting.profile_grid import TABLE2_GRID, ProfileGrid
from facestats.model.fitting.scattering_image import fit_scattering_channels

__all__ = ["GRIDS", "fit_image_translucency", "load_scene_inputs"]

#: Named grids of the command line: Suzuki Table 2, or log-spaced for skin-like media.
GRIDS = {"table2": TABLE2_GRID, "skin": ProfileGrid.log_spaced(n=(160, 160))}


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


def _check_loaded(patches, lights, camera, image):
    """A path among the inputs of :func:`fit_image_translucency` (which takes them loaded) is refused, naming the
    loader; so are patches or a camera of another type."""
    for name, value in (("patches", patches), ("lights", lights), ("camera", camera), ("image", image)):
        if isinstance(value, (str, bytes, os.PathLike)):
            raise ValidationError(
                f"{name} must be loaded, not a file name, got {os.fsdecode(value)!r}: fit_image_translucency takes the "
                "patches, lights, camera and radiance array; read the four files with load_scene_inputs(mesh, lights, "
                "camera, image), which also returns the lights file's eta to pass on"
            )
    if not isinstance(patches, Patches):
        raise ValidationError(f"patches must be a facestats.acquire.patches.Patches, got {type(patches).__name__}")
    if not isinstance(camera, PinholeCamera):
        raise ValidationError(f"camera must be a facestats.acquire.camera.PinholeCamera, got {type(camera).__name__}")


def fit_image_translucency(
    patches, lights, camera, image, *, eta=1.3, width="auto", method="monotone", grid="table2", **options
) -> list:
    """Fit the dipole to one radiance image of known patches, lights and camera (module docstring).

    The inputs are loaded objects and arrays, not file names: :func:`load_scene_inputs` reads the four files
    and returns them, with the lights file's ``eta`` (pass it on: the default here is Suzuki's 1.3, not the
    file's).

    Parameters
    ----------
    patches : Patches
    lights : list of lights (:mod:`facestats.acquire.lights`)
    camera : PinholeCamera
    image : ndarray, shape (H, W), (H, W, 1) or (H, W, 3)
        Linear radiance, in the lights' unit per sr (multiply an image in other units, e.g. the merge's
        exp(g)/s, by the factor :func:`facestats.acquire.scene.reference_radiance_scale` gives).  An RGB image is
        fitted per channel against the lights' RGB irradiance.  A grey image is fitted once against the mean of
        the lights' R, G and B irradiance: a camera equally sensitive to the three light colours (exact for white
        lights; for coloured lights, give RGB).
    eta : float
        Relative index of refraction (Suzuki: 1.3; :func:`load_scene_inputs` returns the lights file's).
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

    Raises
    ------
    ValidationError
        A file name (or a wrong type) given for ``patches``, ``lights``, ``camera`` or ``image``; an image of
        another shape.
    FitError
        As :func:`facestats.model.fitting.fit_scattering_channels` (e.g. light without edges near the patches the
        camera sees, for eq. 36).
    """
    _check_loaded(patches, lights, camera, image)
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
