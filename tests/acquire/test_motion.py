"""The head-motion statistic (:func:`facestats.acquire.photographs.exposure_consistency`): moved frames score, still
frames do not, and a camera's processing around clipped highlights is not taken for motion."""

import pathlib

import numpy as np
import pytest
from scipy import ndimage

from benchmarks.inputs import phase_shift_px
from facestats.acquire.photographs import exposure_consistency
from facestats.acquire.response import ResponseCurve
from facestats.errors import ValidationError
from tests.helpers import real_bracket_dir

UNIS = pathlib.Path(__file__).resolve().parents[1] / "data" / "unis-bracket"

TIMES = np.array([1 / 60, 1 / 8])  # the simulated dome's two exposures
BOX = (0, 0, 160, 160)


def _scene(rng, side=160, scale=1.2e5):
    """Electrons per second (H, W, 3) of a smooth shaded surface with blotches and sharp dark spots."""
    y, x = np.mgrid[0:side, 0:side] / side
    shade = 0.25 + 0.75 * np.exp(-((x - 0.5) ** 2 + (y - 0.5) ** 2) / 0.18)
    blotch = ndimage.gaussian_filter(rng.standard_normal((side, side)), 6)
    albedo = np.exp(0.15 * blotch / blotch.std())
    albedo[rng.random((side, side)) < 0.01] *= 0.35  # sharp dark spots, a pixel each
    rate = scale * shade * albedo  # 12 bits: the long exposure's green codes span 37-79 % of the range
    return np.stack([rate, 0.8 * rate, 0.6 * rate], axis=-1)


def _frame(rate, rng, camera, shift=0.0, encode=None):
    """Codes of the two exposures; the long one sees the scene moved by ``shift`` pixels (bilinear)."""
    moved = ndimage.shift(rate, (shift, 0.7 * shift, 0), order=1, mode="nearest") if shift else rate
    frames = [camera.encode(r * t, rng) for r, t in ((rate, TIMES[0]), (moved, TIMES[1]))]
    return [encode(f) for f in frames] if encode else frames


def _g(camera):
    return np.repeat(camera.log_exposure()[:, None], 3, axis=1)


CAMERA = ResponseCurve(12, 20000.0, 3.0)  # 12-bit codes, full well 20,000 e-, read noise 3 e-


def test_still_frames_score_zero_and_moved_frames_score(rng):
    rate = _scene(rng)
    still = exposure_consistency(_frame(rate, rng, CAMERA), TIMES, _g(CAMERA), BOX)
    assert still[0] == 0.0 and still[1] > 30000  # noise never reaches e^0.5
    for shift in (1.0, 2.0):  # the dark spots move (scores 1.1 % and 0.66 %; 0.5 px: 0.22 %)
        score, _ = exposure_consistency(_frame(rate, rng, CAMERA, shift), TIMES, _g(CAMERA), BOX)
        assert score > 0.001, shift  # the ingest's default threshold (MOTION_TOLERANCE)


def test_pixels_near_a_clipped_pixel_are_left_out_to_the_radius():
    """One clipped pixel at (20, 20) in the long exposure; disagreeing pixels at Chebyshev distances 4 and 5 from it:
    radius 4 leaves out the first, 5 both, 0 neither (the clipped pixel itself is never compared: its hat weight
    is 0)."""
    g = _g(CAMERA)
    short = np.full((40, 40, 3), 1000, np.uint16)
    long = np.full((40, 40, 3), 2000, np.uint16)
    times = np.array([1.0, np.exp(g[2000, 0] - g[1000, 0])])  # codes 1000 and 2000 agree at these times
    long[20, 20] = 4095  # clipped
    long[24, 18] = long[20, 25] = 3500  # disagree by more than e^0.5, at distances 4 and 5
    for radius, expected in ((4, 1), (0, 2), (5, 0)):
        score, n = exposure_consistency([short, long], times, g, (0, 0, 40, 40), clip_radius=radius)
        assert round(score * n / 3) == expected, radius
    # a clipped pixel outside the box excludes its neighbours inside it: the box starts at column 21
    score, n = exposure_consistency([short, long], times, g, (21, 0, 40, 40), clip_radius=5)
    assert score == 0 and n == 3 * (19 * 40 - 5 * 11)  # columns 21-25 of rows 15-25 are within 5 of (20, 20)


def test_a_real_bracket_still_pair_passes_and_its_shaken_pair_is_flagged():
    """The committed UNIS bracket (Olympus TG-4 JPEGs, CC0, tests/data/unis-bracket), whole frames, with the response
    recovered from it. 0 EV and +2 EV: the +2 EV frame's clipped window has the camera's processing along its edges,
    so 0.49 % of the samples disagreed with every pixel compared, above the 0.1 % threshold; 0.0006 % with the
    default radius. −2 EV and 0 EV: the camera moved 0.27 px between them (phase correlation; the disagreements
    line the railings and the horizon), and they still score 2.1 %."""
    pytest.importorskip("cv2")
    from facestats.acquire.response import recover_response
    from facestats.io.exif import read_exposure_time
    from facestats.io.images import read_integer_image

    files = [UNIS / f"UNIS_EV{ev}.jpg" for ev in ("-2", "0", "2")]
    imgs = [read_integer_image(f)[0] for f in files]
    times = np.array([read_exposure_time(f) for f in files])
    g = recover_response(imgs, times)
    box = (0, 0, imgs[0].shape[1], imgs[0].shape[0])
    still, shaken = (imgs[1], imgs[2]), (imgs[0], imgs[1])
    assert phase_shift_px(still, times[1:], g) < 0.15 and phase_shift_px(shaken, times[:2], g) > 0.2  # 0.096, 0.27 px
    every, _ = exposure_consistency(still, times[1:], g, box, clip_radius=0)
    kept, _ = exposure_consistency(still, times[1:], g, box)
    assert every > 0.004 and kept < 0.0001
    assert exposure_consistency(shaken, times[:2], g, box)[0] > 0.01


def test_a_real_still_bracket_is_not_flagged():
    """frobisher_001's JPEGs (a tripod; whole frame): around the 8 s frame's clipped window, colour checker and strap
    the camera's processing makes the 1 s and 8 s frames disagree (0.48 % of the samples with every pixel compared,
    above the 0.1 % threshold); with the default radius 0.0016 %. The 1/8 s and 1 s frames: 0.058 % and 0."""
    pytest.importorskip("cv2")
    from facestats.acquire.response import recover_response
    from facestats.io.images import read_integer_image

    d = real_bracket_dir()
    imgs = [read_integer_image(d / f"IMG_260{k}.jpg")[0] for k in (0, 1, 2)]
    times = np.array([0.125, 1.0, 8.0])
    g = recover_response(imgs, times)
    box = (0, 0, imgs[0].shape[1], imgs[0].shape[0])
    every, _ = exposure_consistency(imgs[1:], times[1:], g, box, clip_radius=0)
    kept, _ = exposure_consistency(imgs[1:], times[1:], g, box)
    assert every > 0.004 and kept < 0.0001
    assert exposure_consistency(imgs[:2], times[:2], g, box)[0] == 0.0
    assert phase_shift_px(imgs[1:], times[1:], g) < 0.1  # the frames did not move (0.04 px)


@pytest.mark.parametrize("value", [-1, 2.5, True, "4"])
def test_a_bad_clip_radius_is_refused_by_name(value):
    codes = np.zeros((4, 4, 3), np.uint16)
    with pytest.raises(ValidationError, match=rf"clip_radius must be a whole number of pixels >= 0, got {value!r}"):
        exposure_consistency([codes, codes], TIMES, _g(CAMERA), (0, 0, 4, 4), clip_radius=value)
