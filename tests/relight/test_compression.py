"""D2: compressed relighting (clustered, solid-angle weighted PCA per colour row and light region): ratio, nested
error, bound, exact zeros, tiles, exactness, the colour rows."""

import numpy as np
import pytest

from facestats.errors import ValidationError
from facestats.relight import compression as cmp
from facestats.relight.field import light_table, open_field, write_field
from facestats.relight.lighting import resample_probe, sky_probe
from facestats.relight.relighting import relight
from tests.relight.fields import ts_lambert_field


@pytest.fixture(scope="module")
def field():
    f, _, _ = ts_lambert_field(14, 14, n_theta=32, n_phi=16)
    return f


def test_light_regions_split_hemispheres_and_azimuth_sectors():
    d = np.array([[0, 1, 0.1], [0, -1, 0.1], [1, 0.2, 0], [-1, 0.2, 0], [-0.1, 0.2, -1], [0, -0.2, 1]], float)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    # sector 0 starts at -z and turns through -x (atan2(x, z) + pi)
    assert cmp.light_regions(d, 4).tolist() == [2, 6, 3, 1, 0, 6]
    assert cmp.light_regions(d, 1).tolist() == [0, 1, 0, 0, 0, 1]
    with pytest.raises(ValidationError, match="directions"):
        cmp.light_regions(np.zeros((3, 2)))


def test_ratio_counts_every_stored_value(field):
    c = cmp.compress(field, ratio=8, clusters=2)
    p, n = int(field["mask"].sum()), 32 * 16
    # label + 24 or 48 mask bits + the diffuse colour (3)
    assert cmp.per_pixel_values(8) == 5 and cmp.per_pixel_values(16) == 6
    # per block with components: its basis on its support, its coefficients, its number of components, the
    # support's 32-bit mask unless it is the whole region; per pixel: the label, 3 colour rows x 8 regions x 2
    # parts zero bits and d; once: the light colour
    stored = sum(b.basis.shape[0] * int(b.support.sum()) + b.coefficients.size + 1
                 + (0 if b.support.all() else -(-b.support.size // 32))
                 for b in c.blocks.values() if b.basis.shape[0]) + 6 * p + 3  # fmt: skip
    assert c.parts == 2 and c.stored == stored and c.ratio == pytest.approx(3 * n * p / stored) and c.ratio >= 8
    for (r, k, q, i), b in c.blocks.items():  # bases vanish off their supports; a block's parts split its region
        assert np.all(b.basis[:, ~b.support] == 0) and b.support.size == c.regions[r].size
        other = c.blocks.get((r, k, q, 1 - i))
        assert other is None or not np.any(other.support & b.support)
    assert not all(b.support.all() for b in c.blocks.values())
    assert c.components == sum(b.basis.shape[0] for b in c.blocks.values()) == c.kept
    with pytest.raises(ValidationError, match="leaves 0 values"):
        cmp.compress(field, ratio=1e6)
    with pytest.raises(ValidationError, match="first component"):
        c.truncate(1e6)  # truncation refuses what compression refuses
    for bad in (-1, [1, 2], np.inf):
        with pytest.raises(ValidationError, match="ratio"):
            cmp.compress(field, ratio=bad)
    with pytest.raises(ValidationError, match="seed"):
        cmp.compress(field, seed=-1)
    with pytest.raises(ValidationError, match="rotate"):
        c.relight(np.ones((16, 32, 3)), rotate=1.0)
    grey = np.linspace(0, 1, 16 * 32).reshape(16, 32)
    assert np.array_equal(c.relight(grey), c.relight(np.repeat(grey[..., None], 3, -1)))


def test_zero_rows_of_a_region_come_back_exactly_zero(field):
    c = cmp.compress(field, ratio=20, clusters=2)
    rec = c.reconstruct()
    dense = field["reflectance"].values.reshape(rec.shape)
    m = field["mask"].values
    directions, _, _ = light_table(field)
    regions = cmp.light_regions(directions)
    zeros = 0
    for r in np.unique(regions):  # a (pixel, channel) row that is zero over a region stays exactly zero there
        sub = dense[regions == r][:, m]  # (L_r, P, 3)
        zero = np.all(sub == 0, axis=0)
        assert np.all(rec[regions == r][:, m][:, zero] == 0)
        zeros += int(zero.sum())
    assert zeros > 0.1 * 8 * 3 * m.sum()  # regions wholly below the horizon: 15 % of the rows here
    # lit from one region only, the pixels it cannot reach relight to exactly 0 (a bright source behind them)
    r0 = np.argmax([np.all(dense[regions == r][:, m] == 0, axis=(0, 2)).sum() for r in np.unique(regions)])
    dark = np.all(dense[regions == r0][:, m] == 0, axis=(0, 2))
    lw = np.zeros((32 * 16, 3))
    lw[regions == r0] = 1e6
    assert dark.sum() > 10 and np.all(c.relight(lw)[m][dark] == 0)
    # so does a colour row that is zero over one part of its block and not over the whole region: here the
    # samples whose channels are all zero (its colour rows are all zero there)
    d_rows = dense.reshape(512, -1, 3)[:, c.pixels]
    mu_hat = np.zeros((3, c.pixels.size, 512), np.float32)  # the colour rows as stored
    for (r, _, q, _), b in c.blocks.items():
        mu_hat[q, b.rows[:, None], c.regions[r][None, :]] += b.coefficients @ b.basis
    part_zeros = 0
    for (r, k, q, _), b in c.blocks.items():
        lights, mine = c.regions[r][b.support], np.flatnonzero(c.labels == k)
        zero = np.all(d_rows[lights][:, mine] == 0, axis=(0, 2))  # (pixels of the cluster,)
        assert np.all(mu_hat[q][np.ix_(mine[zero], lights)] == 0)
        part_zeros += int((zero & np.any(d_rows[c.regions[r]][:, mine] != 0, axis=(0, 2))).sum())
    assert part_zeros > 0.5 * m.sum()


def test_error_is_non_increasing_in_kept_coefficients_and_bounded(field):
    lw = resample_probe(sky_probe(32), field["direction"].values)
    dense = relight(field, lw)
    m = field["mask"].values
    full = cmp.compress(field, ratio=0.5, clusters=3)  # every component: exact
    assert full.kept == len(full.order)
    prev_res, errs = None, []
    for r in (30, 12, 4, 1.5, full.ratio):
        c = full.truncate(r)
        assert c.ratio >= r * (1 - 1e-12)
        res = c.residual.astype(np.float64)
        if prev_res is not None:
            assert np.all(res <= prev_res * (1 + 1e-5) + 1e-9)  # nested components: residuals never grow
        prev_res = res
        err = np.abs(c.relight(lw) - dense)[m]  # only the mask's pixels are stored
        assert np.all(err <= c.error_bound(lw)[m] * (1 + 1e-4) + 1e-7)  # Cauchy-Schwarz bound
        errs.append(float((err / dense[m]).max()))
    assert errs[-1] < errs[0] and errs[-1] < 1e-4
    # the residual is what the reconstruction leaves, row by row in the colour coordinates mu = A^-1 R
    c = full.truncate(4)
    sw = full.sqrt_solid_angle[:, None, None]
    rec = c.reconstruct()[:, m] * sw
    ref = field["reflectance"].values.reshape((512,) + m.shape + (3,))[:, m] * sw
    inv = np.linalg.inv(c.mix)
    mu = np.einsum("pqc,lpc->lpq", inv, rec - ref)
    assert np.allclose(np.linalg.norm(mu, axis=0), c.residual, rtol=1e-3, atol=1e-6)


def test_exact_at_full_rank_and_identical_from_zarr_tiles(field, tmp_path):
    lw = resample_probe(sky_probe(32), field["direction"].values)
    m = field["mask"].values
    exact = cmp.compress(field, ratio=0.5, clusters=1)
    assert np.allclose(exact.relight(lw)[m], relight(field, lw)[m], rtol=1e-4, atol=1e-7)
    assert np.allclose(exact.relight(lw, backend="numpy")[m], relight(field, lw)[m], rtol=1e-4, atol=1e-7)
    rec = exact.reconstruct()[:, m]
    assert np.allclose(rec, field["reflectance"].values.reshape(512, 14, 14, 3)[:, m], atol=1e-6)
    write_field(tmp_path / "f.zarr", field, tile=5)
    a = cmp.compress(field, ratio=6, clusters=3, seed=2)
    b = cmp.compress(open_field(tmp_path / "f.zarr"), ratio=6, clusters=3, seed=2)
    # Gram matrices and products sum in an order that depends on the tiles, so tiles and the whole differ by
    # rounding; a misplaced tile or weight would differ by O(1).
    assert a.components == b.components
    ya, yb = a.relight(lw), b.relight(lw)
    assert np.allclose(ya, yb, rtol=1e-4, atol=1e-5 * np.abs(ya).max())
    assert np.allclose(a.relight(probe=sky_probe(32)), a.relight(lw), rtol=1e-6)


def test_compiled_and_numpy_relights_agree_and_values_are_stored_once(field):
    pytest.importorskip("numba")
    lw = resample_probe(sky_probe(32), field["direction"].values)
    rng = np.random.default_rng(4)
    coloured = lw * rng.uniform(0.2, 3, lw.shape)  # every channel and light weighted differently
    m = field["mask"].values
    for c in (cmp.compress(field, ratio=6, clusters=3), cmp.compress(field, ratio=6, clusters=3).truncate(15)):
        for w in (lw, coloured):
            a, b = c.relight(w, backend="numpy"), c.relight(w, backend="numba")
            assert np.allclose(a, b, rtol=1e-5, atol=1e-6 * np.abs(a).max())
            assert np.all(a[~m] == 0) and np.all(b[~m] == 0)
        # the blocks' coefficients are views of one flat array, their bases of one stack per region (no copies)
        stored = [b.coefficients for b in c.blocks.values() if b.coefficients.size]
        assert all(cf.base is not None for cf in stored) and len({id(cf.base) for cf in stored}) == 1
        assert len({id(b.basis.base) for b in c.blocks.values()}) == len({key[0] for key in c.blocks})
    with pytest.raises(ValidationError, match="backend"):
        c.relight(lw, backend="cuda")
    # a light region without any block (every row zero there) between regions with blocks; exact at full rank
    directions, _, _ = light_table(field)
    dark = cmp.light_regions(directions) == 1
    f = field.copy(deep=True)
    f["reflectance"].values[dark.reshape(f["reflectance"].shape[:2])] = 0
    full = cmp.compress(f, ratio=0.5, clusters=3)
    assert 1 not in {key[0] for key in full.blocks} and {0, 2} <= {key[0] for key in full.blocks}
    dense = relight(f, coloured)
    for backend in ("numpy", "numba"):
        assert np.allclose(full.relight(coloured, backend=backend)[m], dense[m], rtol=1e-4, atol=1e-6 * dense.max())


def test_region_parts_are_scaled_by_their_values_under_uniform_light(field):
    # s_r of a (pixel, channel) row is its relit value under unit radiance from region r alone (eq. 4 with
    # L = 1 on r): checked against the dense relight, an independent path; the floor lifts small parts to floor · s
    directions, sa, _ = light_table(field)
    m = field["mask"].values
    regions = cmp.light_regions(directions).reshape(-1)
    lights = [np.flatnonzero(regions == r) for r in np.unique(regions)]
    sw = np.sqrt(sa.reshape(-1))
    rows = np.moveaxis(field["reflectance"].values.reshape(sw.size, 14, 14, 3)[:, m], 0, -1) * sw  # (P, 3, L)
    uniform = [relight(field, np.where(regions == r, sa.reshape(-1), 0.0).reshape(16, 32))[m]
               for r in np.unique(regions)]  # fmt: skip
    total = np.sum(uniform, axis=0)
    assert total.min() > 0
    one_row_per_channel = np.broadcast_to(np.eye(3), (len(rows), 3, 3))  # A = I: the colour rows are R, G, B
    for floor in (0.0, 0.3, 1.0):
        scales = cmp._region_scales(rows, lights, sw, floor, one_row_per_channel)
        for s_r, u in zip(scales, uniform):
            t = np.maximum(u, floor * total)
            assert np.allclose(s_r, np.where(t > 0, t, 1), rtol=1e-5, atol=1e-9)  # a zero part is not scaled
    # absolute values: a field with negative noise still gets positive scales
    first = cmp._region_scales(-rows, lights, sw, 0.0, one_row_per_channel)[0]
    assert np.allclose(first, np.where(uniform[0] > 0, uniform[0], 1), rtol=1e-5, atol=1e-9)
    # a colour row is scaled by the worst relative error it makes in a channel: min_c t_c / |A_cq|
    mix = np.broadcast_to(np.array([[0.8, 0.5, 0.0], [0.5, 0.5, 0.0], [0.3, 0.5, 1.0]]), (len(rows), 3, 3))
    t = np.maximum(uniform[0], 0.3 * total)
    expected = np.stack([np.min(t / mix[:, :, 0], 1), np.min(t / mix[:, :, 1], 1), t[:, 2]], 1)
    assert np.allclose(cmp._region_scales(rows, lights, sw, 0.3, mix)[0], expected, rtol=1e-5, atol=1e-9)
    for bad in (-0.1, 1.5, np.nan, [0.1, 0.2]):
        with pytest.raises(ValidationError, match="floor"):
            cmp.compress(field, floor=bad)


def test_colour_rows_are_the_coordinates_of_section_4_2(field):
    # d is the most saturated lit sample: for Lambertian colour + white Torrance-Sparrow it is the albedo's
    # direction up to the lobe's tail (every lit sample of a pixel holds some specular light: 9e-5 here)
    albedo = np.array([0.5, 0.3, 0.2])
    d = cmp.diffuse_colours(np.moveaxis(field["reflectance"].values.reshape(512, 14, 14, 3)[:, field["mask"].values],
                                        0, -1))  # fmt: skip
    assert np.allclose(d, albedo / np.linalg.norm(albedo), atol=2e-4)
    c = cmp.compress(field, ratio=0.5, clusters=2)
    assert np.allclose(c.colours, d, atol=2e-4)  # from the √δA-weighted rows (another lit set: 5 % of the max)
    assert c.specular == pytest.approx(np.full(3, 1 / np.sqrt(3)))
    # a rank-two field stores no off-plane row; its residual is rounding
    assert not any(key[2] == 2 for key in c.blocks) and c.residual[:, 2].max() < 1e-6
    # grey samples (d within 5 degrees of s) and a zero pixel: a unit d orthogonal to s, no NaN
    grey = np.ones((2, 3, 8), np.float32)
    grey[1] = 0
    dg = cmp.diffuse_colours(grey)
    assert np.allclose(np.linalg.norm(dg, axis=1), 1) and np.allclose(dg @ np.ones(3), 0, atol=1e-12)
    with pytest.raises(ValidationError, match="rows"):
        cmp.diffuse_colours(np.ones((2, 4, 8)))


def test_off_plane_rows_are_stored_when_they_matter(field):
    # a third colour outside the plane of the albedo and white (an inter-reflection off a green shirt, say)
    m = field["mask"].values
    f = field.copy(deep=True)
    below = np.clip(-field["direction"].values[..., 1], 0, None)  # (16, 32): light from below
    green = below[..., None, None, None] * np.array([0.0, 0.02, 0.0])
    f["reflectance"].values[...] += np.where(m[None, None, :, :, None], green, 0)
    lw = resample_probe(sky_probe(32), f["direction"].values)
    dense = relight(f, lw)
    exact = cmp.compress(f, ratio=0.5, clusters=2)
    assert any(key[2] == 2 for key in exact.blocks)  # the off-plane rows are stored ...
    assert np.allclose(exact.relight(lw)[m], dense[m], rtol=1e-4, atol=1e-7)  # ... and everything is exact
    # told to leave them out, their norm is the row's residual and the error bound still holds
    flat = cmp.compress(f, ratio=0.5, clusters=2, off_plane=1.0)
    assert not any(key[2] == 2 for key in flat.blocks) and flat.residual[:, 2].max() > 1e-3
    err = np.abs(flat.relight(lw) - dense)[m]
    assert err.max() > 1e-4 and np.all(err <= flat.error_bound(lw)[m] * (1 + 1e-4) + 1e-7)
    bad_args = [([1, 1], "specular"), ([0, 0, 0], "specular"), ([-1, -1, -1], "specular"), ([1, -1, 0], "specular")]
    bad_args += [(2.0, "off_plane"), (np.nan, "off_plane"), (True, "ratio")]
    for bad, name in bad_args:
        with pytest.raises(ValidationError, match=name):
            cmp.compress(field, **{name: bad})
    with pytest.raises(ValidationError, match="specular"):
        cmp.diffuse_colours(np.ones((2, 3, 4)), specular=np.ones((2, 3)))
    with pytest.raises(ValidationError, match="at least one light"):
        cmp.diffuse_colours(np.ones((2, 3, 0)))


def test_scale_does_not_change_the_compression(field):
    # every step is linear in the field: a field 1e25 times brighter (beyond float32's square root range, where
    # norms of float32 rows overflow) compresses to the same relight, scaled; a dark channel made only by a faint
    # specular tail (no blue in the albedo) keeps its precision
    lw = resample_probe(sky_probe(32), field["direction"].values)
    m = field["mask"].values
    bright = field.copy(deep=True)
    bright["reflectance"].values[...] *= np.float32(1e25)
    a = cmp.compress(field, ratio=0.5, clusters=2).relight(lw)
    b = cmp.compress(bright, ratio=0.5, clusters=2).relight(lw)
    assert np.allclose(b[m] / 1e25, a[m], rtol=1e-5)
    f, _, _ = ts_lambert_field(14, 14, albedo=(0.5, 0.3, 0.0), rho_s=1e-4, n_theta=32, n_phi=16)
    dense = relight(f, lw)[f["mask"].values]
    full = cmp.compress(f, ratio=0.5, clusters=2)
    got = full.relight(lw)[f["mask"].values]
    assert np.max(np.abs(got - dense)[:, 2] / dense[:, 2]) < 1e-2  # 0.5 % (15 % when rounding was snapped to 0)
    assert np.all(np.abs(got - dense) <= full.error_bound(lw)[f["mask"].values] * (1 + 1e-4) + 1e-6 * np.abs(dense))


def test_a_compressed_relight_is_never_negative_and_clamping_only_helps():
    """Under a single light the truncated bases ring below 0 (here down to -0.0032; 314 pixels of a default
    subject's 32 x 64 field, -19 % of the maximum, found by an API red team): radiance is returned clamped at 0,
    which moves no value away from the dense relight (lighting >= 0 on reflectance >= 0 relights to >= 0)."""
    f = ts_lambert_field(24, 24, m=0.2)[0]
    comp = cmp.compress(f, ratio=20)
    light = np.zeros((32, 64, 3))
    light[5, 10] = 1.0
    img, ref = (x.reshape(-1, 3)[comp.pixels] for x in (comp.relight(lighting=light), relight(f, light)))
    assert img.min() == 0  # was -0.0032
    assert np.all(np.abs(img - ref) <= comp.error_bound(light).reshape(-1, 3)[comp.pixels] + 1e-6)


def test_a_field_of_differences_keeps_its_negative_relights():
    """indirect_field's white − black holds negative values, and its dense relight may be negative; the clamp at 0
    (for fields of radiance) must not apply there (an audit: at full rank 84 % of pixels differed)."""
    f = ts_lambert_field(16, 16, m=0.3)[0]
    diff = f.copy(deep=True)
    diff["reflectance"].values[..., ::2] *= np.float32(-0.5)  # a signed field: some lights subtract
    comp = cmp.compress(diff, ratio=1.0, clusters=1)
    assert not comp.nonnegative and cmp.compress(f, ratio=1.0, clusters=1).nonnegative
    light = resample_probe(sky_probe(32), f["direction"].values)
    got, ref = comp.relight(light), relight(diff, light)
    m = f["mask"].values
    assert ref[m].min() < 0 and got[m].min() < 0
    np.testing.assert_allclose(got[m], ref[m], atol=1e-4 * np.abs(ref[m]).max())
    # A field of radiance with a little negative noise keeps the clamp (one value of -1e-9 turned it off); a
    # field that says it holds differences (indirect_field) does not.
    noisy = f.copy(deep=True)
    noisy["reflectance"].values[0, 0, 8, 8, 0] = -1e-9
    assert cmp.compress(noisy, ratio=1.0, clusters=1).nonnegative
    noisy.attrs["signed"] = True
    assert not cmp.compress(noisy, ratio=1.0, clusters=1).nonnegative


def test_relative_errors_measure_a_reference_darker_than_the_floor_against_the_floor():
    """|image − reference| / max(reference, floor) per channel; with no floor a 0 reference counts as 1e-30."""
    from facestats.relight.compression import relative_errors

    ref = np.array([[[2.0, 0.0, 1.0], [0.5, 4.0, 0.0]]])
    img = np.array([[[2.2, 0.1, 1.0], [0.5, 3.0, 0.0]]])
    got = relative_errors(img, ref, floor=[1.0, 0.5, 2.0])
    assert np.allclose(got, [0.1, 0.2, 0.0, 0.0, 0.25, 0.0])
    assert np.isclose(relative_errors(img, ref)[1], 0.1 / 1e-30)
    for bad in (-1.0, np.nan, [1.0, 2.0]):
        with pytest.raises(ValidationError, match="floor"):
            relative_errors(img, ref, floor=bad)
