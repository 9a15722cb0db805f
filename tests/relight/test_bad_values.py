"""Values no format or float type can hold: clear errors, never a silent NaN, inf or zero (issue: reflectance
fields, bad input)."""

import math

import numpy as np
import pytest

from facestats.core.validate import as_float
from facestats.errors import ValidationError
from facestats.io.probes import read_light_probe, write_light_probe
from facestats.model import sphere
from facestats.relight import compress, lighting, relight
from facestats.relight.field import FieldStore, write_field
from tests.relight.fields import lambertian_field


@pytest.fixture(scope="module")
def small():
    f, _, _ = lambertian_field(4, 4, n_theta=16, n_phi=8)
    return f


def _with_nan(f):
    v = f.reflectance.values.copy()
    v[3, 5, 1, 2, 0] = np.nan
    g = f.copy()
    g["reflectance"] = (f.reflectance.dims, v)
    return g


def test_a_nan_in_the_field_is_reported_at_its_pixel(small, tmp_path):
    bad = _with_nan(small)
    with pytest.raises(ValidationError, match=r"pixel \(y=1, x=2\), light 53 .*channel 0"):
        compress(bad, ratio=3)
    with pytest.raises(ValidationError, match=r"relight: the relit value at pixel \(y=1, x=2\), channel 0 is nan"):
        relight(bad, np.ones((8, 16, 3)))
    with pytest.raises(ValidationError, match="must be finite"):
        write_field(tmp_path / "f.zarr", bad)
    assert not any(tmp_path.iterdir())  # nothing written


def test_lighting_beyond_float32_is_refused_not_turned_into_inf(small):
    with pytest.raises(ValidationError, match=r"lighting must be within the float32 range .*got 1e\+39"):
        relight(small, np.full((128, 3), 1e39))
    comp = compress(small, ratio=3)
    with pytest.raises(ValidationError, match="float32 range"):
        comp.relight(np.full((128, 3), 3e38))  # fits float32, not once divided by √δA
    # finite lighting that overflows in the product: named, not a silent inf image
    with pytest.raises(ValidationError, match="exceeds the float32 range"):
        relight(small, np.full((128, 3), 3e38))


def test_as_float_names_a_finite_value_that_a_narrower_type_cannot_hold():
    with pytest.raises(ValidationError, match=r"x must be within the float16 range .*got 100000.0 at index \(1,\)"):
        as_float(np.array([1.0, 1e5]), "x", np.float16)
    assert np.isinf(as_float(np.array([np.inf]), "x", np.float32)[0])  # inf stays inf: check_finite's job


def test_probe_writers_refuse_what_their_format_cannot_store(tmp_path):
    p = np.ones((4, 8, 3), np.float32)
    p[0, 0] = 2e38  # ≥ 2^127: RGBE's exponent byte would wrap to 0 and the light would read back as black
    with pytest.raises(ValidationError, match=r"below 2\^127 .*row 0, column 0"):
        write_light_probe(tmp_path / "v.hdr", p)
    p[0, 0] = 1.6e38  # the largest RGBE values still round-trip
    write_light_probe(tmp_path / "ok.hdr", p)
    assert read_light_probe(tmp_path / "ok.hdr")[0, 0, 0] == pytest.approx(1.6e38, rel=2e-2)
    q = np.ones((4, 8, 3), np.float32)
    q[1, 2] = 1e5
    with pytest.raises(ValidationError, match="float16 range"):
        write_light_probe(tmp_path / "h.exr", q, half=True)  # half floats end at 65504
    assert sorted(x.name for x in tmp_path.iterdir()) == ["ok.hdr"]
    with pytest.raises(ValidationError, match="its directory .* does not exist"):
        write_light_probe(tmp_path / "missing" / "x.pfm", q)


def test_probe_paths_and_values_of_the_wrong_kind(tmp_path):
    for path in (None, 3):
        with pytest.raises(ValidationError, match="must be a str or path-like"):
            read_light_probe(path)
    (tmp_path / "d.hdr").mkdir()
    with pytest.raises(ValidationError, match="is a directory, not a file"):
        read_light_probe(tmp_path / "d.hdr")
    for value in (np.full((2, 4, 3), "a"), np.full((2, 4, 3), None), np.ones((2, 4, 3), complex)):
        with pytest.raises(ValidationError, match="radiance must be numeric"):
            sphere.check_probe(value)


def test_rotation_by_a_huge_angle_is_the_rotation_by_its_remainder(rng):
    p = rng.random((8, 16, 3)).astype(np.float32)
    big = 3.0 + 2 * math.pi * 1e6
    assert np.allclose(lighting.rotate_probe(p, big), lighting.rotate_probe(p, math.fmod(big, 2 * math.pi)))
    lighting.rotate_probe(p, 1e308)  # no OverflowError
    with pytest.raises(ValidationError, match="angle must be one number"):
        lighting.rotate_probe(p, [0.1, 0.2])


def test_voronoi_resampling_goes_band_by_band_with_the_same_result(rng, monkeypatch):
    d = rng.normal(size=(40, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    p = rng.gamma(0.5, 1.0, size=(24, 48, 3)).astype(np.float32)
    whole = lighting.resample_probe(p, d)
    monkeypatch.setattr(lighting, "_BAND_SAMPLES", 48 * 16 * 5)  # bands of 5 probe rows, the last of 4
    banded = lighting.resample_probe(p, d)
    assert np.allclose(banded, whole, rtol=1e-12, atol=0)
    total = (p.astype(np.float64) * sphere.latlong_solid_angles(24, 48)[..., None]).sum((0, 1))
    assert np.allclose(banded.sum(0), total, rtol=1e-12)
    rows = lighting.probe_samples(p, supersample=2, rows=slice(3, 7))[0]
    assert np.array_equal(rows, lighting.probe_samples(p, supersample=2)[0][3 * 2 * 2 * 48 : 7 * 2 * 2 * 48])
    assert np.array_equal(sphere.latlong_directions(12, 24, rows=slice(2, 5)), sphere.latlong_directions(12, 24)[2:5])


def test_field_store_blocks_are_checked(tmp_path, small):
    from facestats.relight.field import light_table

    directions = light_table(small)[0].reshape(8, 16, 3)
    store = FieldStore(tmp_path / "s.zarr", directions, (2, 2), dtype="float16")
    with pytest.raises(ValidationError, match=r"field block \[y 0:2, x 0:2\] must be within the float16 range"):
        store.write(slice(0, 2), slice(0, 2), np.full((8, 16, 2, 2, 3), 1e5))  # float64 input too
    with pytest.raises(ValidationError, match="must be finite"):
        store.write(slice(0, 2), slice(0, 2), np.full((8, 16, 2, 2, 3), np.nan, np.float32))


def test_indirect_must_be_a_field_and_tint_of_the_same_image(small):
    other, _, _ = lambertian_field(3, 3, n_theta=16, n_phi=8)
    with pytest.raises(ValidationError, match="indirect must be a tuple of two, .*, got Dataset"):
        relight(small, np.ones((8, 16, 3)), indirect=small)
    with pytest.raises(ValidationError, match="got a tuple of 1"):  # was "must be a tuple ..., got tuple"
        relight(small, np.ones((8, 16, 3)), indirect=(small,))
    with pytest.raises(ValidationError, match="image size 4 x 4, got 3 x 3"):
        relight(small, np.ones((8, 16, 3)), indirect=(other, [1, 1, 1]))


def test_angular_probes_are_resampled_band_by_band_too(rng, monkeypatch):
    d = rng.normal(size=(30, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    p = rng.gamma(0.5, 1.0, size=(16, 16, 3)).astype(np.float32)
    whole = lighting.resample_probe(p, d, layout="angular")
    monkeypatch.setattr(lighting, "_BAND_SAMPLES", 16 * 16 * 16 * 3)  # angular bands of 3 probe rows
    assert np.allclose(lighting.resample_probe(p, d, layout="angular"), whole, rtol=1e-12, atol=0)
    sa = sphere.angular_solid_angles(12)
    assert np.array_equal(sphere.angular_solid_angles(12, rows=slice(4, 9)), sa[4:9])
    assert np.array_equal(sphere.angular_directions(12, rows=slice(4, 9))[1], sphere.angular_directions(12)[1][4:9])
    with pytest.raises(ValidationError, match="rows must be a slice of consecutive rows"):
        sphere.angular_directions(12, rows=slice(0, 8, 2))


def test_separation_shadows_and_photometric_stereo_check_their_parameters():
    from facestats.relight import photometric, separate, shadows
    from facestats.relight.novel import novel_view_field
    from tests.relight.fields import ts_lambert_field

    f, *_ = ts_lambert_field(4, 4, n_theta=16, n_phi=8)
    for kwargs, message in (
        ({"mirror_deg": 500}, r"mirror_deg must lie in \[0, 90\] deg"),
        ({"shadow_threshold": float("nan")}, "shadow_threshold must be finite"),
        ({"max_condition": -1}, "max_condition must lie in"),
        ({"view": [0, 0, 2.0]}, "view must hold unit vectors"),
        ({"view": np.tile([0, 0, 1.0], (3, 3, 1))}, "view must have shape"),
    ):
        with pytest.raises(ValidationError, match=message):
            separate.separate_field(f, [1, 1, 1], **kwargs)
    sep = separate.separate_field(f, [1, 1, 1])
    sep["view"] = f["view"]  # as the notebook carries it over
    with pytest.raises(ValidationError, match="view_new must hold unit vectors"):
        novel_view_field(sep, [0, 0, 0])
    with pytest.raises(ValidationError, match="eta must lie in"):
        novel_view_field(sep, [0, 0, 1.0], eta=-1)
    with pytest.raises(ValidationError, match="shadow must have shape"):
        novel_view_field(sep, [0, 0, 1.0], shadow=np.ones((8, 16, 2, 2), bool))
    with pytest.raises(ValidationError, match="field values must be finite"):
        shadows.threshold_shadow_maps(np.full((8, 16, 2, 2, 3), np.nan))
    with pytest.raises(ValidationError, match="one or two light dims"):
        shadows.threshold_shadow_maps(np.ones((8, 3)))
    with pytest.raises(ValidationError, match=r"visibility=True\), missing \['visibility'\]"):
        shadows.disagreement_causes(f)
    with pytest.raises(ValidationError, match="mask must have shape"):
        photometric.photometric_stereo(f, mask=np.ones((2, 2), bool))


def test_negative_lighting_and_images_of_other_channel_counts_are_refused(small):
    """L·δA is radiance times solid angle: never negative (render_subject refused it; relight did not). An image
    to reproject has three channels (six were reshaped into twice the pixels)."""
    from facestats.relight.novel import reproject

    w = np.ones((8, 16, 3))
    w[2, 3, 1] = -1.0
    with pytest.raises(ValidationError, match="lighting must lie in"):
        relight(small, w)
    with pytest.raises(ValidationError, match="lighting must lie in"):
        compress(small, ratio=3).relight(w)
    pos = np.zeros((4, 4, 3))
    mask = np.ones((4, 4), bool)
    for shape in ((4, 4, 6), (4, 4), (4, 4, 2)):
        with pytest.raises(ValidationError, match=r"image must have shape \(n, n, 3\)"):
            reproject(np.ones(shape), pos, mask, None)


def test_resample_probe_checks_its_arguments_first():
    p = lighting.uniform_probe(8)
    with pytest.raises(ValidationError, match=r"supersample must be an integer in \[1, 16\], got 0"):
        lighting.resample_probe(p, supersample=0)
    with pytest.raises(ValidationError, match="rotate must be one angle"):
        lighting.resample_probe(p, rotate=np.array([0.1, 0.2]))
    with pytest.raises(ValidationError, match="directions must hold at least one light"):
        lighting.resample_probe(p, np.zeros((0, 3)))
    total = lighting.resample_probe(p).sum(axis=(0, 1))
    np.testing.assert_allclose(lighting.resample_probe(p, rotate=0.3).sum(axis=(0, 1)), total)  # energy kept


def test_synthetic_probes_cameras_plots_and_angles_check_their_arguments():
    from facestats.relight.camera import stage_camera
    from facestats.relight.photometric import angular_error_deg
    from facestats.relight.plots import plot_relit

    with pytest.raises(ValidationError, match="sun_radiance"):
        lighting.sky_probe(8, sun_radiance=-1.0)
    with pytest.raises(ValidationError, match="sky must be finite"):
        lighting.sky_probe(8, sky=(0.3, np.nan, 0.8))
    with pytest.raises(ValidationError, match=r"ground must have shape \(3\)"):
        lighting.sky_probe(8, ground=(0.1, 0.1))
    sky = lighting.sky_probe(8, sun_radiance=7.0)
    assert sky.max() == 7.0 and np.all(sky >= 0)
    with pytest.raises(ValidationError, match=r"radiance of shape \(2,\) does not broadcast"):
        lighting.uniform_probe(4, radiance=(1.0, 2.0))
    assert lighting.uniform_probe(2, radiance=(1.0, 2.0, 3.0))[1, 3].tolist() == [1.0, 2.0, 3.0]
    with pytest.raises(ValidationError, match=r"target must have shape \(3\), got shape \(2,\)"):
        stage_camera(target=(0.0, 40.0))
    n = np.tile([0.0, 0.0, 1.0], (2, 3, 1))
    with pytest.raises(ValidationError, match=r"mask must have shape \(2, 3\), got shape \(3, 2\)"):
        angular_error_deg(n, n, np.ones((3, 2), bool))
    assert angular_error_deg(n, n, np.eye(2, 3, dtype=bool)).tolist() == [0.0, 0.0]
    with pytest.raises(ValidationError, match="at least one relit image"):
        plot_relit({})
    with pytest.raises(ValidationError, match="ncols"):
        plot_relit({"a": np.ones((2, 2, 3))}, ncols=0)


def test_the_preview_exposure_refuses_a_mask_that_selects_nothing_or_does_not_fit():
    """An empty mask (a mesh the camera missed) gave "PNG exposure x1" beside a NaN mean; a mask of another shape
    raised numpy's IndexError (a one-row mask was broadcast)."""
    from facestats.relight.display import exposure_scale

    img = np.zeros((4, 5, 3))
    img[1, 2] = (0.2, 0.4, 0.6)
    mask = np.zeros((4, 5), bool)
    mask[1, 2] = True
    assert exposure_scale(img, mask) == pytest.approx(0.9 / 0.4)
    assert exposure_scale(np.zeros((4, 5, 3)), mask) == 1.0  # a black subject: documented
    with pytest.raises(ValidationError, match="mask must select at least one pixel to choose an exposure over"):
        exposure_scale(img, np.zeros((4, 5), bool))
    for bad in (np.ones((5, 4), bool), np.ones((1, 5), bool)):
        with pytest.raises(ValidationError, match=r"mask must have the image's pixel shape \(4, 5\), got"):
            exposure_scale(img, bad)
    with pytest.raises(ValidationError, match="image must have at least 3 channels"):
        exposure_scale(np.ones((4, 5, 2)))
    with pytest.raises(ValidationError, match="too small for a finite exposure scale"):
        exposure_scale(np.full((2, 2, 3), 5e-324))
