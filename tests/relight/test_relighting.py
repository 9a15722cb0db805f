"""D1: relighting (Debevec et al. 2000 eq. 2-4): white furnace, linearity, rotation, tiles, clothing tint."""

import numpy as np
import pytest

from facestats.errors import ValidationError
from facestats.relight import field as fld
from facestats.relight.lighting import resample_probe, rotate_probe, sky_probe, uniform_probe
from facestats.relight.relighting import indirect_field, lighting_for, relight, relight_frames, tint_indirect
from tests.relight.fields import lambertian_field


def test_constant_environment_relights_a_lambertian_field_to_its_albedo():
    albedo = np.array([0.6, 0.4, 0.3])
    f, _, inside = lambertian_field(8, 8, albedo)
    img = relight(f, probe=uniform_probe(32))
    assert np.abs(img[inside] - albedo).max() <= 2e-3 * albedo.max()


def test_relighting_is_linear_in_the_lighting_and_equals_the_sum_of_eq4(rng):
    f, _, _ = lambertian_field(5, 5)
    l1, l2 = resample_probe(sky_probe(32)), resample_probe(rng.random((16, 32, 3)))
    a, b = 0.7, 2.5
    assert np.allclose(relight(f, a * l1 + b * l2), a * relight(f, l1) + b * relight(f, l2), rtol=1e-5, atol=1e-7)
    ref = np.einsum("abyxc,abc->yxc", f["reflectance"].values.astype(np.float64), l1)
    assert np.allclose(relight(f, l1), ref, rtol=1e-5, atol=1e-8)
    grey = relight(f, l1[..., 1])
    assert np.allclose(grey[..., 0] / f["reflectance"].values[..., 0].sum() * f["reflectance"].values[..., 1].sum(),
                       grey[..., 1], rtol=1e-5, atol=1e-8)  # fmt: skip


def test_rotating_the_environment_one_column_rolls_the_light_axis(rng):
    f, _, _ = lambertian_field(4, 4)
    probe = rng.gamma(0.7, 1.0, (32, 64, 3)).astype(np.float32)
    rotated = relight(f, probe=probe, rotate=2 * np.pi / 64)
    rolled = f.copy()
    rolled["reflectance"] = f["reflectance"].roll(light_theta=1)
    assert np.allclose(rotated, relight(rolled, probe=probe), rtol=1e-5, atol=1e-8)
    assert np.allclose(relight(f, probe=probe, rotate=2 * np.pi), relight(f, probe=probe), rtol=1e-5)
    assert np.allclose(rotate_probe(probe, 2 * np.pi / 64), np.roll(probe, -1, axis=1))


def test_fields_on_disk_are_relit_tile_by_tile_identically(tmp_path):
    f, _, _ = lambertian_field(9, 7)
    path = fld.write_field(tmp_path / "f.zarr", f, tile=4)
    g = fld.open_field(path)
    assert g["reflectance"].chunks is not None
    lw = lighting_for(f, sky_probe(16))
    # Same sums over the lights in float32; the BLAS kernel's order depends on the block width, so tiles and
    # the whole agree to rounding (≤ L·u ≈ 1e-4 relative in the worst case; 2e-6 observed), not bit for bit.
    assert np.allclose(relight(g, lw), relight(f, lw), rtol=1e-5, atol=1e-9)


def test_frames_relit_in_one_pass_equal_single_relights(tmp_path, monkeypatch):
    """relight_frames (a turntable's frames in one pass over the field) gives each lighting's relight: in memory, on
    disk tile by tile, and an in-memory field cut into tiles when the frames' product would be large."""
    import facestats.relight.relighting as relighting

    f, _, _ = lambertian_field(9, 7, albedo=(0.7, 0.2, 0.4))
    g = fld.open_field(fld.write_field(tmp_path / "f.zarr", f, tile=4))
    probe = sky_probe(16, sun_direction=(0.6, 0.3, 0.7))
    lights = [lighting_for(f, probe, rotate=a) for a in (0.0, 1.1, 2.5, 4.0)] + [np.ones((32, 64))]  # grey too
    for field in (f, g):
        frames = relight_frames(field, lights)
        assert frames.shape == (5, 9, 7, 3) and frames.dtype == np.float32
        for k, lw in enumerate(lights):
            assert np.allclose(frames[k], relight(field, lw), rtol=1e-5, atol=1e-9)
        assert not np.allclose(frames[0], frames[2])  # the frames differ: not one lighting repeated
    monkeypatch.setattr(relighting, "_PRODUCT_BYTES", 36 * 4 * 12)  # 4 frames: tiles of 3 x 3 pixels
    tiled = relight_frames(f, np.stack(lights[:4]))  # an (F, light dims..., 3) array
    assert np.allclose(tiled, frames[:4], rtol=1e-5, atol=1e-9)
    with pytest.raises(ValidationError, match="lightings must hold at least one lighting, got none"):
        relight_frames(f, [])
    with pytest.raises(ValidationError, match=r"lightings must hold one lighting per frame, shape \(F, L, 3\)"):
        relight_frames(f, np.ones(3))
    with pytest.raises(ValidationError, match="lighting must hold L·δA per light of the field"):
        relight_frames(f, [lights[0], np.ones((10, 3))])
    bad = np.array(lights[:2])
    bad[1, 3, 4, 0] = np.inf
    with pytest.raises(ValidationError, match="finite"):
        relight_frames(f, bad)


def test_clothing_tint_is_an_additive_linear_term():
    black, _, _ = lambertian_field(4, 4, (0.5, 0.4, 0.3))
    white, _, _ = lambertian_field(4, 4, (0.6, 0.55, 0.5))
    lw = resample_probe(sky_probe(16))
    ib, iw = relight(black, lw), relight(white, lw)
    assert np.allclose(tint_indirect(ib, iw, [1, 1, 1]), iw) and np.allclose(tint_indirect(ib, iw, [0, 0, 0]), ib)
    green = [0.1, 0.8, 0.2]
    ind = indirect_field(white, black)
    assert np.allclose(relight(black, lw, indirect=(ind, green)), tint_indirect(ib, iw, green), rtol=1e-5, atol=1e-7)
    with pytest.raises(ValidationError, match="same shape"):
        tint_indirect(ib, iw[:2], green)


def test_bad_lighting_is_refused():
    f, _, _ = lambertian_field(3, 3)
    with pytest.raises(ValidationError, match="one of lighting"):
        relight(f)
    with pytest.raises(ValidationError, match="L·δA per light"):
        relight(f, np.ones((10, 3)))
    with pytest.raises(ValidationError, match="finite"):
        relight(f, np.full((32, 64, 3), np.nan))
    with pytest.raises(ValidationError, match="rotate"):
        relight(f, np.ones((32, 64, 3)), rotate=0.1)
