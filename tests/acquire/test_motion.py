"""The head-motion statistic (:func:`facestats.acquire.photographs.exposure_consistency`): moved frames score, still
frames do not, and an error of the response curve, which depends only on the code, is not taken for motion."""

import numpy as np
import pytest
from scipy import ndimage

from facestats.acquire.photographs import exposure_consistency
from facestats.acquire.response import ResponseCurve
from tests.helpers import real_bracket_dir

TIMES = np.array([1 / 60, 1 / 8])  # the simulated dome's two exposures
CAMERA = ResponseCurve(12, 20000.0, 3.0)  # 12-bit codes, full well 20,000 e-, read noise 3 e-


def _scene(rng, side=160):
    """Electrons per second (H, W, 3) of a smooth shaded surface with blotches and sharp dark spots."""
    y, x = np.mgrid[0:side, 0:side] / side
    shade = 0.25 + 0.75 * np.exp(-((x - 0.5) ** 2 + (y - 0.5) ** 2) / 0.18)
    blotch = ndimage.gaussian_filter(rng.standard_normal((side, side)), 6)
    albedo = np.exp(0.15 * blotch / blotch.std())
    albedo[rng.random((side, side)) < 0.01] *= 0.35  # sharp dark spots, a pixel each
    rate = 1.2e5 * shade * albedo  # the long exposure's green codes span 37-79 % of the range
    return np.stack([rate, 0.8 * rate, 0.6 * rate], axis=-1)


def _frame(rate, rng, shift=0.0):
    """Codes of the two exposures; the long one sees the scene moved by ``shift`` pixels (bilinear)."""
    moved = ndimage.shift(rate, (shift, 0.7 * shift, 0), order=1, mode="nearest") if shift else rate
    return [CAMERA.encode(r * t, rng) for r, t in ((rate, TIMES[0]), (moved, TIMES[1]))]


def _g():
    return np.repeat(CAMERA.log_exposure()[:, None], 3, axis=1)


def _shoulder(g, size=1.5):
    """g with an error growing from 0 at 60 % of the codes to ``size`` ln units at the top (a rolled-off shoulder the
    calibration missed)."""
    z = np.arange(g.shape[0]) / (g.shape[0] - 1)
    return g - size * np.clip((z - 0.6) / 0.4, 0, 1)[:, None]


BOX = (0, 0, 160, 160)


def test_still_frames_score_zero_and_moved_frames_score(rng):
    rate = _scene(rng)
    still = exposure_consistency(*(_frame(rate, rng), TIMES), _g(), BOX)
    assert still[0] == 0.0 and still[1] > 30000  # noise never reaches e^0.5
    for shift in (1.0, 2.0):  # the dark spots move (scores 1.1 % and 0.66 %; 0.5 px: 0.22 %)
        score, _ = exposure_consistency(_frame(rate, rng, shift), TIMES, _g(), BOX)
        assert score > 0.001, shift  # the ingest's default threshold (MOTION_TOLERANCE)


def test_a_response_error_at_the_shoulder_is_not_taken_for_motion(rng):
    """The long exposure's bright codes read up to 1.1 too low: without the per-code median (one bin: a constant error
    only) a still frame scores far above the threshold; with it, below. A moved frame is still caught."""
    rate = _scene(rng)
    g = _shoulder(_g())
    frame = _frame(rate, rng)
    flat, n = exposure_consistency(frame, TIMES, g, BOX, code_bins=1)
    binned, n2 = exposure_consistency(frame, TIMES, g, BOX)
    assert n == n2 and flat > 0.01 and binned < 0.001  # measured 9.3 % and 0.012 % (threshold 0.1 %)
    moved, _ = exposure_consistency(_frame(rate, rng, 1.0), TIMES, g, BOX)
    assert moved > 0.001


def test_the_score_counts_distances_from_each_bins_median_as_numpy_does(rng):
    """An independent count: numpy's median of d per (channel, code bin), then the share beyond ``jump``. The
    statistic takes the median to 0.01, so samples within 0.01 of the jump may count differently."""
    from facestats.acquire.response import hat_weights

    codes = rng.integers(0, CAMERA.levels, (300, 300, 3))
    long_codes = np.clip(2 * codes + rng.integers(-300, 301, codes.shape), 0, CAMERA.levels - 1)
    g = _g()
    ch = np.arange(3)
    d = (g[long_codes, ch] - np.log(TIMES[1])) - (g[codes, ch] - np.log(TIMES[0]))
    w = hat_weights(CAMERA.levels)
    ok = (w[codes] >= 0.2 * w.max()) & (w[long_codes] >= 0.2 * w.max())
    cell = codes * 32 // CAMERA.levels + 32 * ch
    dist = np.full(d.shape, np.nan)
    for c in np.unique(cell[ok]):  # a loop over bins, in the test only
        sel = ok & (cell == c)
        dist[sel] = np.abs(d[sel] - (np.median(d[sel]) if sel.sum() >= 20 else 0.0))
    dist = dist[ok]
    for jump in (0.05, 0.2, 0.5):
        score, n = exposure_consistency([codes, long_codes], TIMES, g, (0, 0, 300, 300), jump=jump)
        assert n == dist.size
        lo, hi = np.mean(dist > jump + 0.01), np.mean(dist > jump - 0.01)
        assert lo <= score <= hi, (jump, lo, score, hi)


def test_a_real_still_bracket_is_not_flagged():
    """frobisher_001's 1 s and 8 s JPEGs (a tripod; whole frame): the response recovered from the bracket is low at
    the 8 s frame's shoulder, which scored 0.48 % without the per-code median and scores 0.084 % with it (threshold
    0.1 %)."""
    from facestats.acquire.response import recover_response
    from facestats.io.images import read_integer_image

    d = real_bracket_dir()
    imgs = [read_integer_image(d / f"IMG_260{k}.jpg")[0] for k in (0, 1, 2)]
    times = np.array([0.125, 1.0, 8.0])
    g = recover_response(imgs, times)
    box = (0, 0, imgs[0].shape[1], imgs[0].shape[0])
    flat, _ = exposure_consistency(imgs[1:], times[1:], g, box, code_bins=1)
    binned, _ = exposure_consistency(imgs[1:], times[1:], g, box)
    assert flat > 0.004 and binned < 0.001
    # the frames did not move: phase correlation of their log radiance where both are well exposed (OpenCV, an
    # independent estimate) finds a shift of 0.01-0.04 px
    cv2 = pytest.importorskip("cv2")
    from facestats.acquire.response import hat_weights

    w = hat_weights(256)
    ok = np.all((w[imgs[1]] >= 0.2 * w.max()) & (w[imgs[2]] >= 0.2 * w.max()), axis=-1)
    logs = [(g[im, np.arange(3)] - np.log(t)).mean(-1) for im, t in zip(imgs[1:], times[1:])]
    a, b = (np.where(ok, x, x[ok].mean()).astype(np.float32) for x in logs)
    (dx, dy), _ = cv2.phaseCorrelate(a, b, cv2.createHanningWindow(a.shape[::-1], cv2.CV_32F))
    assert np.hypot(dx, dy) < 0.1


BAD = [("code_bins", 0), ("code_bins", 2.5), ("min_bin_count", -1), ("code_bins", True)]


@pytest.mark.parametrize("field, value", BAD)
def test_bad_bins_are_refused_by_name(field, value):
    from facestats.errors import ValidationError

    codes = np.zeros((4, 4, 3), np.uint16)
    with pytest.raises(ValidationError, match=rf"{field} must be a whole number >= 1, got {value!r}"):
        exposure_consistency([codes, codes], TIMES, _g(), (0, 0, 4, 4), **{field: value})
