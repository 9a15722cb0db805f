"""What the emulated cameras see: dark-code sampling, HDR frames that recover the simulator's radiance, store truth."""

import numpy as np
import pytest

from facestats.acquire.devices.cameras import EmulatedCameras, Trigger
from facestats.acquire.devices.lab import emulated_rig
from facestats.acquire.devices.scene import DomeScene, SensorScene, dark_code_table, subject_truth
from facestats.acquire.devices.sensor import FiberLayout, merge_bracket
from facestats.acquire.response import ResponseCurve, merge_photographs
from facestats.core.published import ETA_SKIN
from facestats.errors import ValidationError


def test_dark_codes_follow_the_distribution_of_read_noise_through_the_camera():
    camera = ResponseCurve(12, 20000.0, 5.0)
    table = dark_code_table(camera)
    rng = np.random.default_rng(1)
    n = 2_000_000
    direct = camera.encode(np.zeros(n, np.float32), rng)  # the camera's own encoding of zero signal
    looked_up = table[rng.integers(0, 65536, n, dtype=np.uint16)]
    top = int(max(direct.max(), looked_up.max())) + 1
    p, q = np.bincount(direct, minlength=top) / n, np.bincount(looked_up, minlength=top) / n
    sigma = np.sqrt(p * (1 - p) / n) * np.sqrt(2)
    from scipy.special import ndtr

    # code 0 up to half a code: BT.709's linear toe 4.5 x, so e < 0.5 full_well / (4.5 · 4095) (clipped below 0)
    assert p[0] == pytest.approx(ndtr(0.5 * 20000 / (4.5 * 4095) / 5.0), abs=0.002)
    assert np.all(np.abs(p - q) < 5 * sigma + 2**-16)  # each code's frequency within noise (and the table's 2⁻¹⁶ steps)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    truth = subject_truth("S004", map_size=16)
    return DomeScene(truth, emulated_rig(64, leds=8, cameras=4), tmp_path_factory.mktemp("scene"), seed=3)


def test_emulated_frames_merge_back_to_the_simulated_radiance(scene):
    """Both exposures of a frame, merged with the cameras' true response (Debevec & Malik 1997 eq. 6), give the
    noise-free radiance of the simulator at the pixels showing the face."""
    dome = scene.dome
    g = np.repeat(scene.camera.log_exposure()[:, None], 3, axis=1)
    cams = EmulatedCameras(scene)
    checked = 0
    for camera, led in ((1, 2), (2, 5), (3, 7)):
        codes = [scene.render(camera, Trigger(0, led, e))[0] for e in (0, 1)]
        merged = merge_photographs(codes, dome.exposure_times, g) / dome.camera_scale  # exp(g)/s → dome units
        flat, node = scene.pixels[camera]
        on = node >= 0
        truth = scene.radiance[node[on], camera, led].astype(np.float64)
        got = merged.reshape(-1, 3)[flat[on]]
        bright = np.isfinite(truth) & (truth > 0.02) & np.isfinite(got)
        ratio = got[bright] / truth[bright]
        assert abs(np.median(ratio) - 1) < 0.01 and np.percentile(np.abs(ratio - 1), 90) < 0.05
        checked += bright.sum()
        assert cams.frame(camera, Trigger(5, led, 1)).data == cams.frame(camera, Trigger(9, led, 1)).data  # replayable
    assert checked > 300


def test_compiled_and_numpy_renders_give_the_same_frames(scene, tmp_path):
    twin = DomeScene(scene.truth, scene.dome, tmp_path, seed=3, backend="numpy")
    assert scene.backend == "numba" and twin.backend == "numpy"
    for camera, trigger in ((1, Trigger(0, 2, 0)), (3, Trigger(0, 7, 1, brightness=90)), (0, Trigger(0, -1, 1))):
        np.testing.assert_array_equal(scene.render(camera, trigger)[0], twin.render(camera, trigger)[0])
    with pytest.raises(ValidationError, match="backend"):
        DomeScene(scene.truth, scene.dome, tmp_path, backend="gpu")
    eight = ResponseCurve(8, 20000.0, 5.0)  # an 8-bit camera: a table of uint8 codes
    a = DomeScene(scene.truth, scene.dome, tmp_path / "a", camera=eight, seed=3)
    b = DomeScene(scene.truth, scene.dome, tmp_path / "b", camera=eight, seed=3, backend="numpy")
    frame_a, frame_b = a.render(2, Trigger(0, 5, 1))[0], b.render(2, Trigger(0, 5, 1))[0]
    assert frame_a.dtype == np.uint8 and frame_a.max() > 100
    np.testing.assert_array_equal(frame_a, frame_b)


def test_led_drive_scales_the_exposure(scene):
    g = scene.camera.log_exposure()
    full = scene.render(2, Trigger(0, 5, 1))[0].astype(np.int64)
    half = scene.render(2, Trigger(0, 5, 1, brightness=128))[0].astype(np.int64)
    red = scene.render(2, Trigger(0, 5, 1, colour=(255, 0, 0)))[0].astype(np.int64)
    lit = (full > 400) & (full < 3500)
    ratio = np.exp(g[half[lit]] - g[full[lit]])
    assert np.median(ratio) == pytest.approx(128 / 255, rel=0.02)  # electrons ∝ drive
    assert np.all(red[..., 1:] < 40)  # green and blue dark: read noise only
    dark = scene.render(2, Trigger(0, -1, 1))[0]
    assert dark.max() < 40


def test_a_store_subject_becomes_the_truth_with_its_own_scattering():
    from facestats.io import open_store

    truth = subject_truth("S010", store="default")
    ds = open_store().subject("S010")
    sp, sa = truth.site_scattering
    np.testing.assert_allclose(sp, ds["site_sigma_s_prime"].values, rtol=1e-9)
    np.testing.assert_allclose(sa, ds["site_sigma_a"].values, rtol=1e-9)
    face = truth.region_map > 0
    assert np.all(truth.ts_m[face] > 0) and np.all(np.isfinite(truth.albedo[face]))
    assert truth.metadata()["age"] == int(ds.attrs["age"]) and truth.region_map.shape == (48, 48)
    with pytest.raises(Exception, match="S999"):
        subject_truth("S999", store="default")


def test_fiber_layout_and_bracket_merge_recover_the_dipole_profile():
    layout = FiberLayout()
    labels = layout.labels()
    assert labels.shape == (17, 233) and layout.size == (233, 17)
    assert np.all(np.bincount(labels[labels >= 0]) == 21)  # the pixels within 2.5 px of each spot centre
    sp, sa = np.array([[1.0, 1.2, 1.5]] * 3), np.array([[0.03, 0.08, 0.2]] * 3)
    scene = SensorScene(sp, sa, seed=4)
    times = scene.sensor.exposure_times
    stack = [scene.render(0, Trigger(0, exposure=j, lamp=1, shutter=1, site=1))[0] for j in range(len(times))]
    profile, std = merge_bracket(np.stack(stack), times, scene.sensor, layout)
    from facestats.model.dipole import dipole_profile

    truth = dipole_profile(scene.sensor.fiber_distance[:, None], sp[1], sa[1], ETA_SKIN)
    z = (profile - truth) / std
    assert np.all(np.abs(z) < 5)
    strong = truth > 1e-5  # the merge's noise model is evaluated at the measured rate: loose near the floor
    want = scene.sensor.profile_std(truth) / np.sqrt(21)  # the sensor's noise model, averaged over 21 pixels a fibre
    np.testing.assert_allclose(np.median(std[strong] / want[strong]), 1, rtol=0.01)
    np.testing.assert_allclose(std[strong], want[strong], rtol=0.15)  # pixels near clipping use fewer exposures
    closed = scene.render(0, Trigger(0, exposure=22, lamp=1, shutter=0, site=1))[0]
    black = scene.sensor.camera.black_level
    assert np.abs(closed.astype(np.int64) - black).max() < 6  # shutter closed: black level and read noise only
    with pytest.raises(ValidationError, match="radius_px"):
        FiberLayout(radius_px=4)
