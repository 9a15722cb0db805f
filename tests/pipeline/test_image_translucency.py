"""``fit_image_translucency``: the channels of the image against the lights' colours."""

import numpy as np
import pytest

from facestats.acquire.lights import DirectionalLight
from facestats.acquire.synthetic.patch_image import render_patch_image
from facestats.acquire.synthetic.scenes import pyramid_scene
from facestats.errors import ValidationError
from facestats.model.irradiance import radiance_from_exitance
from facestats.pipeline.image_translucency import fit_image_translucency
from facestats.pipeline.suzuki_studies import render_scene

COLOUR = np.array([1.0, 0.5, 0.25])  # a warm light: the mean of R, G, B is 0.58 × red


@pytest.fixture(scope="module")
def warm_scene():
    scene = pyramid_scene(2.5, "edge", image_size=300)
    light = scene.lights[0]
    scene.lights = [DirectionalLight(light.direction, light.irradiance * COLOUR, light.cuts)]
    r = render_scene(scene)  # the red channel, Suzuki Table 1's medium
    p = r.patches
    to_cam = scene.camera.position - p.centre
    cos = np.clip(np.einsum("mk,mk->m", p.normal, to_cam) / np.linalg.norm(to_cam, axis=1), 0, 1)
    rgb = radiance_from_exitance(r.exitance[:, None] * COLOUR / COLOUR[0], cos, 1.3)  # linear in the irradiance
    return scene, render_patch_image(scene.camera, p, rgb)


def test_a_grey_image_is_fitted_against_the_mean_of_the_lights_colours(warm_scene):
    """Grey = mean of R, G, B is exactly W r times the mean irradiance; against red's alone σ's would move."""
    scene, image = warm_scene
    grey = image.mean(axis=-1)
    (fit,) = fit_image_translucency(scene.patches, scene.lights, scene.camera, grey)
    red = fit_image_translucency(scene.patches, scene.lights, scene.camera, image)[0]
    assert abs(fit.sigma_s_prime - 2.19) <= 0.05 and abs(fit.sigma_a - 0.0021) <= 0.0003
    assert fit.sigma_s_prime == pytest.approx(red.sigma_s_prime, rel=1e-6)


def test_images_of_other_than_one_or_three_channels_are_refused_first(warm_scene):
    scene, image = warm_scene
    four = np.concatenate([image, image[..., :1]], axis=-1)
    with pytest.raises(
        ValidationError, match=r"image must have shape \(H, W\), \(H, W, 1\) or \(H, W, 3\), got \(300, 300, 4\)"
    ):
        fit_image_translucency(scene.patches, scene.lights, scene.camera, four)


def test_the_skin_grid_fits_through_the_api_although_its_far_corner_underflows(warm_scene):
    """fit_image_translucency(grid="skin") used to fail with numpy's "zero-size array to reduction operation"."""
    scene, image = warm_scene
    red = fit_image_translucency(scene.patches, scene.lights, scene.camera, image, grid="skin", refine=True)[0]
    (s0, s1), (a0, a1) = red.summary()["sigma_s_prime_interval"], red.summary()["sigma_a_interval"]
    assert s0 <= 2.19 <= s1 and a0 <= 0.0021 <= a1
    assert abs(red.sigma_s_prime - 2.19) <= 0.05 and abs(red.sigma_a - 0.0021) <= 0.0003


def test_file_names_are_refused_naming_the_loader(warm_scene, tmp_path):
    """The API takes loaded inputs; a file name gave numpy's "image must have shape ... got ()" (a walkthrough)."""
    scene, image = warm_scene
    args = {"patches": scene.patches, "lights": scene.lights, "camera": scene.camera, "image": image}
    for name in args:
        bad = dict(args, **{name: tmp_path / f"{name}.x"})
        with pytest.raises(ValidationError, match=rf"^{name} must be loaded, not a file name, got .*load_scene_inputs"):
            fit_image_translucency(**bad)
    with pytest.raises(ValidationError, match="camera must be a facestats.acquire.camera.PinholeCamera, got dict"):
        fit_image_translucency(scene.patches, scene.lights, {"matrix": None}, image)
