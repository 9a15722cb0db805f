"""Texture statistics and Heeger-Bergen texture transfer (Weyrich et al. 2006 §8)."""

import numpy as np
import pytest
from scipy import ndimage

from facestats.edit import (
    Histogram,
    TextureStatistics,
    decorrelating_basis,
    histogram_distance,
    region_statistics,
    transfer_colour,
    transfer_texture,
)
from facestats.errors import FormatError, ValidationError

SKIN = np.array([0.55, 0.34, 0.25])


def _skin(rng, n, amp, sigma):
    """Albedo with Gaussian-filtered noise of relative amplitude ``amp`` and scale ``sigma`` pixels."""
    g = np.stack([ndimage.gaussian_filter(rng.standard_normal((n, n)), sigma) for _ in range(3)], -1)
    g /= g.std()
    return np.clip(SKIN * (1 + amp * g), 0, 1).astype(np.float32)


def _freckled(rng, n, darken=0.6):
    """Pore-scale noise plus dark spots covering 10 % of the map."""
    img = _skin(rng, n, 0.05, 0.7)
    blobs = ndimage.gaussian_filter(rng.standard_normal((n, n)), 2.0)
    spots = blobs > np.quantile(blobs, 0.9)
    img[spots] *= np.array([darken, darken * 0.95, darken * 0.9], np.float32)
    return img


@pytest.fixture(scope="module")
def images():
    """A smooth source, a freckled target and a second, independent sample of the target texture."""
    rng = np.random.default_rng(7)
    return _skin(rng, 128, 0.03, 3.0), _freckled(rng, 128), _freckled(rng, 128)


def test_statistics_layout_23808():
    img = _freckled(np.random.default_rng(0), 512)
    st = TextureStatistics.from_image(img, levels=7, orientations=4, bins=256)
    v = st.to_vector()
    assert v.shape == (256 * 31 * 3,) == (23_808,)
    assert st.n_bands == 31 and len(st.band_names) == 31
    assert st.band_names[:3] == ["image", "highpass", "level0_orient0"] and st.band_names[-1] == "lowpass"
    blocks = v.reshape(3, 31, 256)
    np.testing.assert_allclose(blocks.sum(axis=-1), 1.0, rtol=1e-12)
    # Documented order: element (c * 31 + b) * 256 + k is bin k of band b of channel c.
    c, b = 2, 1 + 4 * 5 + 3  # channel 2, level 5 orientation 3
    np.testing.assert_array_equal(v[(c * 31 + b) * 256 : (c * 31 + b + 1) * 256], st.histogram(c, b).pdf)
    # Band 0 is the histogram of the decorrelated image itself (an independent computation).
    planes = st.basis.to_decorrelated(img)
    for ch in range(3):
        assert st.edges[ch, 0, 0] == planes[ch].min() and st.edges[ch, 0, -1] == planes[ch].max()
        counts, _ = np.histogram(planes[ch], bins=256, range=(float(planes[ch].min()), float(planes[ch].max())))
        np.testing.assert_array_equal(counts, st.counts[ch, 0])
        assert st.counts[ch, 0].sum() == 512 * 512
    # Pyramid band sizes: level i has (512 / 2**i)² coefficients, the low-pass residual 4².
    assert st.counts[0, 2 + 4 * 3].sum() == 64 * 64
    assert st.counts[0, -1].sum() == 4 * 4


def test_decorrelating_basis(images):
    _, tgt, _ = images
    basis = decorrelating_basis(tgt)
    planes = basis.to_decorrelated(tgt.astype(np.float64))
    cov = np.cov(planes.reshape(3, -1), bias=True)
    assert np.abs(cov - np.diag(np.diag(cov))).max() < 1e-12 * np.abs(cov).max()
    np.testing.assert_allclose(np.diag(cov), basis.variances, rtol=1e-10)
    assert np.all(np.diff(basis.variances) <= 0)
    np.testing.assert_allclose(basis.to_rgb(planes), tgt, atol=1e-12)


def test_a_texture_transferred_onto_itself_stays_almost_unchanged(images):
    """The target's own statistics are a fixed point up to the pyramid's and the histograms' resolution.

    Before the one-sided quantiles of ``match_flat`` the distance rose to 0.12 and texels moved by up to 0.038.
    """
    _, tgt, _ = images
    res = transfer_texture(tgt, TextureStatistics.from_image(tgt, levels=4), iterations=5, seed=1, noise=0)
    assert res.distance.max() < 0.05
    assert np.abs(res.albedo - tgt).max() < 0.003 and np.abs(res.albedo - tgt).mean() < 3e-4


def test_save_load_roundtrip(tmp_path, images):
    _, tgt, _ = images
    st = TextureStatistics.from_image(tgt, levels=4, bins=64)
    path = st.save(tmp_path / "freckles")
    assert path.name == "freckles.npz"
    back = TextureStatistics.load(path)
    np.testing.assert_array_equal(back.edges, st.edges)
    np.testing.assert_array_equal(back.counts, st.counts)
    np.testing.assert_array_equal(back.basis.axes, st.basis.axes)
    assert (back.levels, back.orientations, back.bins) == (4, 4, 64)
    np.savez(tmp_path / "other.npz", edges=st.edges)
    with pytest.raises(FormatError, match="not a facestats texture-statistics file"):
        TextureStatistics.load(tmp_path / "other.npz")


def test_load_reads_what_save_wrote_for_a_suffixless_name(tmp_path, images):
    _, tgt, _ = images
    st = TextureStatistics.from_image(tgt, levels=3, bins=32)
    st.save(tmp_path / "freckles")  # writes freckles.npz
    back = TextureStatistics.load(tmp_path / "freckles")
    np.testing.assert_array_equal(back.counts, st.counts)
    back = TextureStatistics.load(str(tmp_path / "freckles"))
    np.testing.assert_array_equal(back.edges, st.edges)
    with pytest.raises(FormatError, match=r"does not exist \(nor does '.*missing\.npz'\)"):
        TextureStatistics.load(tmp_path / "missing")


def test_transfer_moves_statistics_to_target(images):
    src, tgt, tgt2 = images
    target = TextureStatistics.from_image(tgt, levels=4)
    res = transfer_texture(src, target, iterations=5, seed=1)
    assert res.albedo.shape == src.shape and res.albedo.dtype == np.float32
    assert res.distance.shape == (6,) and res.band_distance.shape == (6, 3, 18)
    assert res.distance[-1] < 0.6 * res.distance[0]
    # Heeger-Bergen's iterations are not guaranteed to descend: it falls fast, then settles within a few per cent.
    assert np.all(np.diff(res.distance[:4]) < 0) and res.distance[1:].max() <= res.distance[1]

    # Measured independently on the fine bands (high-pass, levels 0-1; coarser bands hold too few
    # coefficients for 256 bins): the result is as close to the target as a second sample of the
    # target texture is, and far closer than the source.
    def fine_distance(img):
        st = TextureStatistics.from_image(img, levels=4, basis=target.basis)
        return np.mean(
            [histogram_distance(st.histogram(c, b), target.histogram(c, b)) for c in range(3) for b in range(1, 10)]
        )

    d_res, d_src, d_floor = fine_distance(res.albedo), fine_distance(src), fine_distance(tgt2)
    assert d_src > 0.5
    assert d_res < 1.5 * d_floor
    # The freckles arrive: the darkest pixels of the result are as dark as the target's.
    lum = lambda x: x.mean(axis=-1)  # noqa: E731
    assert np.quantile(lum(res.albedo), 0.05) == pytest.approx(np.quantile(lum(tgt), 0.05), rel=0.05)
    assert np.quantile(lum(src), 0.05) > 1.3 * np.quantile(lum(tgt), 0.05)


def test_transfer_is_deterministic_for_a_seed(images):
    src, tgt, _ = images
    st = TextureStatistics.from_image(tgt, levels=3)
    a = transfer_texture(src, st, iterations=2, seed=42)
    b = transfer_texture(src, st, iterations=2, seed=42)
    c = transfer_texture(src, st, iterations=2, seed=43)
    np.testing.assert_array_equal(a.albedo, b.albedo)
    np.testing.assert_array_equal(a.distance, b.distance)
    assert not np.array_equal(a.albedo, c.albedo)


def test_statistics_alone_equal_target_image(tmp_path, images):
    src, tgt, _ = images
    direct = transfer_texture(src, tgt, levels=3, iterations=2, seed=5)
    loaded = TextureStatistics.load(TextureStatistics.from_image(tgt, levels=3).save(tmp_path / "t.npz"))
    via_file = transfer_texture(src, loaded, iterations=2, seed=5)
    np.testing.assert_array_equal(direct.albedo, via_file.albedo)


def test_statistics_are_not_saved_beside_a_folder_named_as_the_output(tmp_path, images):
    _, tgt, _ = images
    (tmp_path / "out").mkdir()
    with pytest.raises(ValidationError, match="path must be a file.*folder"):
        TextureStatistics.from_image(tgt, levels=3).save(tmp_path / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no sibling out.npz


def test_mask_leaves_outside_bit_identical(images):
    src, tgt, _ = images
    v, u = np.mgrid[0:128, 0:128]
    mask = (u - 60) ** 2 + (v - 70) ** 2 < 35**2
    res = transfer_texture(src, tgt, mask, levels=3, iterations=2, seed=0, feather=3.0)
    np.testing.assert_array_equal(res.albedo[~mask], src[~mask])
    core = ndimage.binary_erosion(mask, iterations=4)
    assert np.abs(res.albedo[core] - src[core]).mean() > 0.01
    # Feathering: one pixel inside the edge the change is a third of the way (w = d / feather = 1/3).
    edge = mask & ~ndimage.binary_erosion(mask)
    assert np.abs(res.albedo[edge] - src[edge]).mean() < 0.6 * np.abs(res.albedo[core] - src[core]).mean()


def test_a_feather_wider_than_the_mask_warns_and_one_wider_than_the_image_is_refused(images):
    """A red team: feather 1000 on a 48² map kept 0.04 % of the edit, 1e300 none of it, exit 0, without a word."""
    import warnings

    from facestats.edit import transfer_colour
    from facestats.edit.masks import feather_weights
    from facestats.errors import FacestatsWarning

    src, tgt, _ = images
    mask = np.zeros(src.shape[:2], bool)
    mask[40:60, 30:90] = True  # depth 10 pixels (the middle rows are 10 from the edge)
    depth = ndimage.distance_transform_edt(mask).max()
    assert depth == 10
    with warnings.catch_warnings():
        warnings.simplefilter("error", FacestatsWarning)
        w = feather_weights(mask, 10.0)  # reaches the whole edit in the middle: no warning
    assert w.max() == 1.0
    with pytest.warns(FacestatsWarning, match=r"feather 40 pixels exceeds the depth of the mask, 10 pixels.*25%"):
        assert feather_weights(mask, 40.0).max() == pytest.approx(0.25)
    for call in (lambda f: transfer_texture(src, tgt, mask, levels=3, iterations=1, seed=0, feather=f),
                 lambda f: transfer_colour(src, tgt, mask, feather=f)):  # fmt: skip
        for f in (129.0, 1e300):  # refused before any work
            with pytest.raises(ValidationError, match=r"feather must be at most the image's size, 128 pixels"):
                call(f)


def test_float64_source_keeps_dtype_and_outside(images):
    src, tgt, _ = images
    src64 = src.astype(np.float64) + 1e-9  # values a float32 cannot hold
    mask = np.zeros(src.shape[:2], bool)
    mask[30:100, 20:110] = True
    res = transfer_texture(src64, tgt, mask, levels=3, iterations=1, seed=0)
    assert res.albedo.dtype == np.float64
    np.testing.assert_array_equal(res.albedo[~mask], src64[~mask])


def test_label_regions_and_odd_shape(images):
    src, tgt, _ = images
    src, tgt = src[:100, :90], tgt[:100, :90]  # not multiples of 2**levels: mirrored padding
    labels = np.zeros((100, 90), np.int16)
    labels[10:50, 10:80] = 2
    labels[55:95, 10:80] = 7
    stats = region_statistics(tgt, labels, levels=3)
    assert set(stats) == {2, 7}
    assert stats[2].basis is stats[7].basis
    res = transfer_texture(src, stats, labels, iterations=2, seed=3)
    out = labels == 0
    np.testing.assert_array_equal(res.albedo[out], src[out])
    assert res.band_distance.shape == (3, 3, 14)
    with pytest.raises(ValidationError, match="missing"):
        transfer_texture(src, {2: stats[2]}, labels, iterations=1)


def test_own_statistics_are_nearly_a_fixed_point(images):
    src, _, _ = images
    st = TextureStatistics.from_image(src, levels=4)
    res = transfer_texture(src, st, iterations=2, noise=0.0, seed=0)
    assert np.abs(res.albedo - src).max() < 0.02
    assert np.abs(res.albedo - src).mean() < 2e-3


def test_transfer_colour_changes_skin_type(images):
    rng = np.random.default_rng(3)
    src, _, _ = images
    dark = np.clip(np.array([0.28, 0.16, 0.11]) * (1 + 0.05 * rng.standard_normal((64, 64, 3))), 0, 1)
    out = transfer_colour(src, dark)
    np.testing.assert_allclose(out.reshape(-1, 3).mean(0), dark.reshape(-1, 3).mean(0), rtol=0.01)
    np.testing.assert_allclose(out.reshape(-1, 3).std(0), dark.reshape(-1, 3).std(0), rtol=0.05)
    np.testing.assert_array_equal(transfer_colour(src, dark, t=0.0), src)
    half = transfer_colour(src, dark, t=0.5)
    np.testing.assert_allclose(
        half.reshape(-1, 3).mean(0), 0.5 * (src.reshape(-1, 3).mean(0) + dark.reshape(-1, 3).mean(0)), rtol=0.01
    )
    mask = np.zeros(src.shape[:2], bool)
    mask[20:90, 30:100] = True
    part = transfer_colour(src, dark, mask)
    np.testing.assert_array_equal(part[~mask], src[~mask])
    # A target given by its statistics: the image histograms and colour basis are used (statistics are
    # computed in float32, so a few values land in a neighbouring bin: far below a bin width of ~3e-4).
    via_stats = transfer_colour(src, TextureStatistics.from_image(dark, levels=2))
    np.testing.assert_allclose(via_stats, out, atol=5e-5)


def test_validation(images):
    src, tgt, _ = images
    with pytest.raises(ValidationError, match="levels must be at most"):
        transfer_texture(src, tgt, levels=7)
    with pytest.raises(ValidationError, match=r"iterations must be an integer in \[0, 100\], got 100000000"):
        transfer_texture(src, tgt, levels=3, iterations=10**8)  # refused before allocating 31 GiB
    with pytest.raises(ValidationError, match="levels must match"):
        transfer_texture(src, TextureStatistics.from_image(tgt, levels=3), levels=4)
    with pytest.raises(ValidationError, match="source_albedo must have shape"):
        transfer_texture(src[..., 0], tgt)
    with pytest.raises(ValidationError, match="mask must have shape"):
        transfer_texture(src, tgt, np.ones((3, 3), bool), levels=3)


def test_plot_texture_transfer(tmp_path, images):
    from facestats.edit.plots import plot_histogram_interpolation, plot_texture_transfer

    src, tgt, _ = images
    res = transfer_texture(src, tgt, levels=4, iterations=3, seed=0)
    fig = plot_texture_transfer(res, target=tgt)
    assert len(fig.axes) == 4
    fig.savefig(tmp_path / "texture.png", dpi=60)
    assert (tmp_path / "texture.png").stat().st_size > 1000
    rng = np.random.default_rng(0)
    h0 = Histogram.from_data(rng.normal(0.3, 0.03, 5000), 64)
    h1 = Histogram.from_data(rng.normal(0.2, 0.02, 5000), 64)
    fig2 = plot_histogram_interpolation(h0, h1, labels=("normal", "lotion"), xlabel="m")
    assert len(fig2.axes[0].patches) == 5


def test_a_flat_source_takes_the_target_s_variation(images):
    """The start noise scaled with the source's spread alone, so a constant source got none and came out constant
    (an audit): it now takes the target's spread where that is larger, and the texture arrives."""
    _, tgt, _ = images
    flat = np.full_like(tgt, 0.5)
    res = transfer_texture(flat, TextureStatistics.from_image(tgt, levels=4), iterations=5, seed=3)
    ratio = res.albedo.reshape(-1, 3).std(0) / tgt.reshape(-1, 3).std(0)
    assert np.all((ratio > 0.7) & (ratio < 1.3)), ratio


def test_histogram_std_of_a_piecewise_uniform_distribution(rng):
    x = rng.gamma(3.0, 0.1, 100_000)
    assert Histogram.from_data(x, bins=512).std() == pytest.approx(x.std(), rel=2e-3)
    assert Histogram([0.0, 1.0], [5.0]).std() == pytest.approx(np.sqrt(1 / 12), rel=1e-12)


def test_distances_are_averaged_over_regions():
    """Two identical halves (the pyramid is circular: their coefficients are equal at every level) labelled as two
    regions give the distances of the whole map as one region: the mean over regions, not their sum."""
    rng = np.random.default_rng(7)
    half = _skin(rng, 64, 0.03, 3.0)
    src = np.concatenate([half, half], 1)
    labels = np.ones((64, 128), np.int32)
    labels[:, 64:] = 2
    stats = TextureStatistics.from_image(_freckled(rng, 128), levels=3)
    one = transfer_texture(src, stats, None, noise=0.0, iterations=1, feather=0.0)
    two = transfer_texture(src, stats, labels, noise=0.0, iterations=1, feather=0.0)
    assert one.distance[0] > 0.3
    np.testing.assert_allclose(two.distance, one.distance, rtol=1e-6)
    np.testing.assert_allclose(two.band_distance, one.band_distance, rtol=1e-6, atol=1e-9)


def test_bands_with_fewer_coefficients_than_bins_are_named_with_what_helps():
    """A band histogram of n coefficients that follow the target exactly still lies about 0.3 sqrt(bins / n) from
    it (the sampling floor): a second realisation of a texture against the first's statistics shows that
    distance, which ``floor`` predicts to 20 % (binomial counts of independent coefficients; the target's own
    noise folded in by an equal-variance sample size).  Bands under
    one coefficient a bin are named in a warning with the levels that keep every band above it."""
    import warnings

    from facestats.edit.texture import MIN_COEFFICIENTS_PER_BIN
    from facestats.errors import FacestatsWarning

    assert MIN_COEFFICIENTS_PER_BIN == 1.0
    first, second = (_skin(np.random.default_rng(s), 128, 0.05, 0.7) for s in (1, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error", FacestatsWarning)  # 128² at 3 levels: the low-pass holds 16² = 256
        same = transfer_texture(second, TextureStatistics.from_image(first, levels=3), noise=0.0, iterations=0)
    assert same.coefficients[1] == [16384, 16384] + [16384] * 4 + [4096] * 4 + [1024] * 4 + [256]
    measured, floor = same.band_distance[0].mean(0), same.band_floor.mean(0)
    assert np.all(np.abs(measured / floor - 1) < 0.2), measured / floor
    assert floor[0] < 0.07 and floor[-1] > 0.3  # 16384 coefficients against 256: about 0.3 sqrt(bins / n)
    assert same.floor == pytest.approx(float(same.band_floor.mean()))
    # statistics of weights, not counts (here probabilities): they say nothing of the coefficients behind them
    stats = TextureStatistics.from_image(first, levels=3)
    weights = TextureStatistics(stats.edges, stats.counts / 16384.0, stats.basis, 3, 4)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FacestatsWarning)
        res = transfer_texture(second, weights, noise=0.0, iterations=0)
    assert res.coefficients == same.coefficients and np.all(res.band_floor < same.band_floor)  # an exact target
    with pytest.warns(FacestatsWarning) as record:  # 4 levels: the low-pass residual on grid 4 holds 64
        transfer_texture(second, TextureStatistics.from_image(first, levels=4), noise=0.0, iterations=0)
    text = str(record[0].message)
    assert "1 of 19 band histograms (over regions) hold fewer coefficients than their 256 bins" in text
    assert "the map (16384 texels of the 128 x 128 map): grid 4 holds 64 coefficients" in text
    assert "Levels <= 3 (--levels 3; saved statistics fix their own: edit stats --levels 3)" in text
    labels = np.zeros((128, 128), np.int32)
    labels[:10, :10], labels[40:, :] = 1, 2  # region 1: 100 texels, fewer than 256 even at full resolution
    with pytest.warns(FacestatsWarning) as record:
        res = transfer_texture(second, TextureStatistics.from_image(first, levels=2), labels, iterations=1)
    text = str(record[0].message)
    assert "region 1 (100 texels of the 128 x 128 map): grids 0-2 hold 8-100 coefficients" in text
    assert "region 2" not in text and "Even the finest bands of region(s) 1 hold fewer" in text
    assert "--store texture-sample" in text and "(--regions)" in text and "(--bins; edit stats --bins)" in text
    assert res.coefficients[1][0] == 100 and res.floor > 0.3
