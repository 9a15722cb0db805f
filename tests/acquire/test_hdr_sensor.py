"""Camera HDR merging and the contact sensor (Weyrich et al. 2006 §5, §5.4)."""

import numpy as np
import pytest

from facestats import FacestatsError
from facestats.acquire.hdr import CameraResponse, expose, merge_exposures, merged_std
from facestats.acquire.sensor import ContactSensor
from facestats.model import dipole


def test_hdr_merge_unbiased_with_predicted_noise(rng):
    cam = CameraResponse()
    times = np.array([1 / 60, 1 / 8])
    rate = np.geomspace(50, 5e6, 40)  # electrons per second: dark to clipped in the long exposure
    reps = np.repeat(rate[None], 4000, 0)
    dn = expose(reps, times, cam, rng, dtype=np.float64)
    est, std, n_used = merge_exposures(dn, times, cam)
    ok = np.all(n_used > 0, axis=0)
    assert ok.sum() >= 30
    mean = est[:, ok].mean(0)
    sd = est[:, ok].std(0)
    pred = merged_std(rate[ok], times, cam)
    np.testing.assert_allclose(mean, rate[ok], rtol=0.02, atol=3 * pred.max() / np.sqrt(4000) + 1)
    np.testing.assert_allclose(sd, pred, rtol=0.12)
    # Highlights that clip in the long exposure are read from the short one.
    bright = rate > 0.95 * cam.full_well / times[1]
    assert np.all(n_used[:, bright & ok] == 1)


def test_the_noise_model_drops_the_exposures_the_merge_drops():
    """The merge drops a reading at or above 0.95 of the ADC's full scale, black level included: 18,687 e⁻ for the
    default camera. The model dropped it from 19,000 e⁻ (0.95 × full well), so a long exposure expecting 18,950 e⁻
    counted in the model and not in the merge (an audit)."""
    cam, times = CameraResponse(), np.array([1 / 60, 1 / 8])
    rate = np.full((20000, 1), 18950 / times[1])
    est, _, _ = merge_exposures(expose(rate, times, cam, np.random.default_rng(1), dtype=np.float64), times, cam)
    assert est.std() / merged_std(rate[0], times, cam)[0] == pytest.approx(1, abs=0.05)  # 0.99


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_compiled_and_numpy_camera_give_the_same_bits(dtype):
    """Readings and merges from numba and from the numpy twins agree exactly (dark, clipped, mid-range)."""
    cam = CameraResponse(adc_bits=12, black_level=64)
    times = [1 / 60, 1 / 8, 1 / 2]
    rate = np.random.default_rng(4).exponential(2e4, (5000, 3)).astype(dtype)
    rate[:50], rate[50:100] = 0, 1e9  # no signal; clipped in every exposure
    dn = {b: expose(rate, times, cam, np.random.default_rng(7), dtype=dtype, backend=b) for b in ("numba", "numpy")}
    assert dn["numba"].dtype == dtype and np.array_equal(dn["numba"], dn["numpy"])
    merged = {b: merge_exposures(dn["numpy"], times, cam, backend=b) for b in ("numba", "numpy")}
    for x, y in zip(merged["numba"], merged["numpy"]):
        assert x.dtype == y.dtype and x.shape == y.shape == rate.shape
        np.testing.assert_array_equal(x, y)
    rate_hat, _, n_used = merged["numba"]
    assert np.all(np.isnan(rate_hat[50:100])) and np.all(n_used[50:100] == 0)
    assert np.all(n_used[:50] == 3) and np.all(np.isfinite(rate_hat[:50]))


def test_all_clipped_is_nan():
    cam = CameraResponse()
    dn = np.full((3, 2), cam.max_dn, float)
    est, std, n = merge_exposures(dn, [0.1, 1.0], cam)
    assert np.all(np.isnan(est)) and np.all(n == 0)


def test_sensor_layout_and_bracket():
    s = ContactSensor()
    assert s.n_fibers == 28 and s.n_exposures == 23
    np.testing.assert_allclose(np.diff(np.log2(s.exposure_times)), 2 / 3)
    # The 23-image bracket takes about the 88 s of §5.4 at the default shortest exposure.
    assert 60 < s.exposure_times.sum() < 100
    with pytest.raises(FacestatsError, match="fiber_distance must be strictly increasing"):
        ContactSensor(fiber_distance=np.array([1.0, 0.5]))


def test_sensor_profiles_follow_the_dipole(rng):
    s = ContactSensor()
    sp = np.array([2.4, 1.7, 1.8])
    sa = np.array([0.04, 0.17, 0.36])
    truth = dipole.dipole_profile(s.fiber_distance[:, None], sp, sa)  # (fiber, channel)
    meas = np.stack([s.capture(truth, rng)[0] for _ in range(300)])
    std = s.profile_std(truth)
    z = (meas - truth) / std
    strong = truth / std > 10
    assert abs(z[:, strong].mean()) < 0.05
    assert z[:, strong].std() == pytest.approx(1.0, abs=0.1)
    # Relative noise below 1 % where the signal is strong: a profile good enough to fit.
    assert np.all((std / truth)[:10] < 0.01)


def test_invalid_inputs_name_the_argument(rng):
    cam = CameraResponse()
    with pytest.raises(FacestatsError, match="rate must be finite and >= 0"):
        expose(np.array([1.0, -2.0]), [0.1], cam, rng)
    with pytest.raises(FacestatsError, match="rate must be finite and >= 0"):
        expose(np.array([1.0, np.nan]), [0.1], cam, rng)
    with pytest.raises(FacestatsError, match=r"times must lie in \(0, inf\]"):
        expose(np.array([1.0]), [0.0], cam, rng)
    with pytest.raises(FacestatsError, match="times must be a 1-D array"):
        merge_exposures(np.zeros((3, 2)), [[0.1, 1.0]], cam)
    with pytest.raises(FacestatsError, match="dn must have 2 exposures on its last axis"):
        merge_exposures(np.zeros((3, 4)), [0.1, 1.0], cam)
    with pytest.raises(FacestatsError, match="CameraResponse needs full_well > 0"):
        CameraResponse(full_well=0.0)
    with pytest.raises(FacestatsError, match=r"profile must have shape \(\.\.\., 28, 3\)"):
        ContactSensor().capture(np.ones((27, 3)), rng)


def test_a_sensor_description_without_a_key_names_it():
    """A missing key raised a bare KeyError, through ``Capture.sensor`` as well (a reviewer)."""
    from facestats.errors import FormatError

    attrs = ContactSensor().to_attrs()
    assert ContactSensor.from_attrs(attrs).n_fibers == ContactSensor().n_fibers
    del attrs["stop"]
    with pytest.raises(FormatError, match="contact sensor description is missing the key 'stop'"):
        ContactSensor.from_attrs(attrs)
    with pytest.raises(FormatError, match="malformed field"):
        ContactSensor.from_attrs({**ContactSensor().to_attrs(), "n_exposures": [3]})
    with pytest.raises(FormatError, match="must be a JSON object, got list"):
        ContactSensor.from_attrs([])
