"""The frequency-domain steerable pyramid of facestats.edit (Weyrich et al. 2006 §8)."""

import numpy as np
import pytest

from facestats.edit.pyramid import SteerablePyramid, band_names, max_levels
from facestats.errors import ValidationError


@pytest.mark.parametrize(
    "shape,levels", [((64, 64), 4), ((64, 128), 3), ((96, 64), 2), ((256, 256), 6), ((40, 48), 3), ((48, 40), 3)]
)  # (40, 48) at 3 levels: a low-pass grid of 5 rows, whose spectrum's crop keeps frequencies 0, 1, 2 and -2, -1
def test_reconstruction_float64(rng, shape, levels):
    img = rng.standard_normal(shape)
    pyr = SteerablePyramid(shape, levels, 4, dtype=np.float64)
    rec = pyr.reconstruct(pyr.decompose(img))
    assert np.abs(rec - img).max() / np.abs(img).max() < 1e-12


@pytest.mark.parametrize("orientations", [1, 2, 3, 5, 6, 7])
def test_reconstruction_for_any_number_of_orientations(rng, orientations):
    """A fixed factor i made the bands of odd K anti-Hermitian: their f_x = 0 column was lost and a smooth 256²
    image came back with a relative error of 0.34 (an audit); (−i)^(K−1) keeps every band real and exact."""
    yy, xx = np.mgrid[:128, :128] / 128
    smooth = np.sin(2 * np.pi * yy) + 0.5 * np.cos(6 * np.pi * xx * yy)
    for img in (smooth, rng.standard_normal((128, 128))):
        pyr = SteerablePyramid(img.shape, 4, orientations, dtype=np.float64)
        rec = pyr.reconstruct(pyr.decompose(img))
        assert np.abs(rec - img).max() / np.abs(img).max() < 1e-12


def test_reconstruction_float32_within_1e6(rng):
    img = rng.uniform(0.1, 0.6, (256, 256)).astype(np.float32)
    pyr = SteerablePyramid(img.shape, 6, 4, dtype=np.float32)
    bands = pyr.decompose(img)
    assert all(b.dtype == np.float32 for b in bands)
    rec = pyr.reconstruct(bands)
    assert rec.dtype == np.float32
    assert np.abs(rec - img).max() / np.abs(img).max() < 1e-6


def test_layout_seven_levels_four_orientations():
    # §8: 7 levels x 4 orientations + high-pass + low-pass = 30 bands, down-sampled by 2 per level.
    pyr = SteerablePyramid((512, 512), 7, 4, dtype=np.float32)
    bands = pyr.decompose(np.zeros((512, 512), np.float32))
    assert len(bands) == pyr.n_bands == 30 == len(band_names(7, 4))
    assert [b.shape for b in bands] == pyr.band_shapes
    assert bands[0].shape == (512, 512)
    assert [bands[1 + 4 * i].shape for i in range(7)] == [(512 >> i, 512 >> i) for i in range(7)]
    assert bands[-1].shape == (4, 4)
    assert band_names(7, 4)[0] == "highpass" and band_names(7, 4)[-1] == "lowpass"
    assert band_names(7, 4)[1 + 4 * 3 + 2] == "level3_orient2"
    assert max_levels((2048, 2048)) == 9 and max_levels((512, 512)) == 7


def test_tight_frame_energy(rng):
    # L0² + H0² = 1 and Σ_b A_b² = 1: mean square energy is conserved band by band.
    img = rng.standard_normal((128, 128))
    bands = SteerablePyramid(img.shape, 4, 4, dtype=np.float64).decompose(img)
    assert sum(np.mean(b**2) for b in bands) == pytest.approx(np.mean(img**2), rel=1e-12)


def test_constant_image_goes_to_lowpass_in_image_units():
    img = np.full((64, 64), 0.37)
    bands = SteerablePyramid(img.shape, 3, 4, dtype=np.float64).decompose(img)
    np.testing.assert_allclose(bands[-1], 0.37, rtol=1e-12)
    assert max(np.abs(b).max() for b in bands[:-1]) < 1e-14


def test_orientation_selectivity():
    # A grating varying along u (axis 1) at 1/8 cycle per pixel: |f| = 1/8 lies in level 1's pass-band
    # (r = 2|f| = 1/4 on grid 0, 1/2 on grid 1) and at θ = 0, where A_0 = α cos³(0) is largest and
    # A_2 = α cos³(π/2) = 0.
    u = np.arange(128)
    img = np.cos(2 * np.pi * u / 8)[None, :].repeat(128, axis=0)
    pyr = SteerablePyramid(img.shape, 4, 4, dtype=np.float64)
    bands = pyr.decompose(img)
    energy = np.array([np.mean(b**2) for b in bands])
    level1 = energy[1 + 4 * 1 : 1 + 4 * 2]
    assert np.argmax(energy) == 1 + 4 * 1  # level 1, orientation 0
    assert level1[2] < 1e-20 * level1[0]
    # The two diagonal filters see cos⁶(π/4) = 1/8 of the energy of orientation 0.
    assert level1[1] == pytest.approx(level1[0] / 8, rel=1e-9)
    assert level1[3] == pytest.approx(level1[0] / 8, rel=1e-9)


def test_agrees_with_pyrtools(rng):
    pt = pytest.importorskip("pyrtools")
    img = rng.standard_normal((64, 96))
    levels = 3
    ours = SteerablePyramid(img.shape, levels, 4, dtype=np.float64).decompose(img)
    ref = pt.pyramids.SteerablePyramidFreq(img, height=levels, order=3).pyr_coeffs
    # pyrtools does not rescale after down-sampling: level i is 4**i times ours.
    expected = [ref["residual_highpass"]]
    expected += [ref[(i, b)] / 4.0**i for i in range(levels) for b in range(4)]
    expected.append(ref["residual_lowpass"] / 4.0**levels)
    for k, (a, e) in enumerate(zip(ours, expected)):
        # pyrtools interpolates tabulated masks (error ~5e-6); ours are closed forms.
        assert np.abs(a - e).max() <= 2e-5 * np.abs(e).max(), band_names(levels, 4)[k]


def test_validation():
    with pytest.raises(ValidationError, match="divisible"):
        SteerablePyramid((100, 128), 3)
    with pytest.raises(ValidationError, match="levels must be at most"):
        SteerablePyramid((64, 64), 5)
    with pytest.raises(ValidationError, match="orientations"):
        SteerablePyramid((64, 64), 2, 0)
    bad_shapes = [("ab", r"shape must be \(rows, columns\)"), (64, "shape must be"), ((6.5, 64), "an integer")]
    for shape, match in bad_shapes:
        with pytest.raises(ValidationError, match=match):  # int("a") was a bare ValueError (an API red team)
            SteerablePyramid(shape, 1)
    pyr = SteerablePyramid((64, 64), 2)
    with pytest.raises(ValidationError, match="image must have shape"):
        pyr.decompose(np.zeros((32, 32)))
    with pytest.raises(ValidationError, match="finite"):
        pyr.decompose(np.full((64, 64), np.nan))
    with pytest.raises(ValidationError, match="bands must hold"):
        pyr.reconstruct([np.zeros((64, 64))])


def test_band_level_names_each_band_s_grid_and_refuses_an_index_out_of_range():
    pyr = SteerablePyramid((64, 64), 2, 4)
    assert [pyr.band_level(i) for i in range(pyr.n_bands)] == [0, 0, 0, 0, 0, 1, 1, 1, 1, 2]
    for bad in (-1, 10, 2.0, True):  # -1 and 10 gave levels -1 and 2 (a band that does not exist)
        with pytest.raises(ValidationError, match="index must be an integer"):
            pyr.band_level(bad)
    with pytest.raises(ValidationError, match=r"index must be an integer in \[0, 9\], got 10"):
        pyr.band_level(10)
