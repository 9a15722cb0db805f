"""Kernel family and two-pass convolution of displacement maps (Nagano et al. 2015 eq. 1-6)."""

import numpy as np
import pytest
from scipy.ndimage import convolve1d

from facestats.errors import FacestatsError
from facestats.model.microstructure import convolve_displacement, kernel_taps
from facestats.model.microstructure.kernel import GAUSSIAN_RESPONSE_FLOOR, frequency_response, gaussian_taps

OMEGA = np.linspace(0, np.pi, 513)


@pytest.mark.parametrize("alpha", [-2.0, -1.0, 0.0, 0.5, 1.0])
@pytest.mark.parametrize("sigma_um", [1.0, 7.3, 25.0, 100.0])
def test_kernel_sums_to_one_and_alpha_zero_is_the_identity(alpha, sigma_um):
    k = kernel_taps(alpha, sigma_um, 10.0)
    assert abs(k.sum() - 1) < 1e-12
    assert len(k) % 2 == 1 and np.allclose(k, k[::-1], atol=0, rtol=0)
    if alpha == 0:
        assert np.array_equal(k, np.eye(1, len(k), len(k) // 2)[0])


@pytest.mark.parametrize("sigma_px", [0.3, 1.0, 2.5, 10.0, 40.0])
def test_frequency_response_bounds(sigma_px):
    g = frequency_response(gaussian_taps(sigma_px), OMEGA)
    assert abs(g[0] - 1) < 1e-12 and g.max() <= 1 + 1e-12 and g.min() >= -GAUSSIAN_RESPONSE_FLOOR
    for alpha in (0.25, 0.5, 1.0):  # blurs never amplify
        k = frequency_response(kernel_taps(alpha, 10 * sigma_px, 10.0), OMEGA)
        assert k.max() <= 1 + 1e-12 and k.min() >= 1 - alpha * (1 + GAUSSIAN_RESPONSE_FLOOR) - 1e-12
    for alpha in (-2.0, -0.5):  # sharpening gains at most 1 + |alpha|
        k = frequency_response(kernel_taps(alpha, 10 * sigma_px, 10.0), OMEGA)
        assert k.min() >= 1 - 1e-12 and k.max() <= 1 - alpha * (1 + GAUSSIAN_RESPONSE_FLOOR) + 1e-12
    # Where the Gaussian has cut off high frequencies, a full sharpening gains 1 - alpha.
    if sigma_px >= 2.5:
        assert abs(frequency_response(kernel_taps(-2.0, 10 * sigma_px, 10.0), np.pi)[()] - 3) < 1e-3


def _random_fields(rng, shape):
    theta = rng.uniform(0, np.pi, shape)
    return (
        np.stack([np.cos(theta), np.sin(theta)], -1),
        rng.uniform(-2, 1, shape),
        rng.uniform(1, 100, shape),
        rng.uniform(-2, 1, shape),
        rng.uniform(1, 100, shape),
    )


def test_blurring_obeys_the_maximum_principle():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(80, 90)).astype(np.float32)
    axis, _, s_s, _, s_t = _random_fields(rng, d.shape)
    out = convolve_displacement(d, axis, rng.uniform(0, 1, d.shape), s_s, rng.uniform(0, 1, d.shape), s_t, 8.0)
    assert out.min() >= d.min() - 1e-6 and out.max() <= d.max() + 1e-6
    sharp = convolve_displacement(d, axis, -1.0, 30.0, -1.0, 30.0, 8.0)  # sharpening overshoots
    assert sharp.max() > d.max() + 0.5


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_two_passes_along_u_equal_scipy_convolve1d(backend):
    rng = np.random.default_rng(1)
    d = rng.normal(size=(96, 120)).astype(np.float32)
    out = convolve_displacement(d, (1.0, 0.0), 0.6, 25.0, -0.7, 13.0, 10.0, backend=backend)
    k_s, k_t = kernel_taps(0.6, 25.0, 10.0), kernel_taps(-0.7, 13.0, 10.0)
    ref = convolve1d(convolve1d(d.astype(np.float64), k_s, axis=1), k_t, axis=0)
    m = len(k_s) // 2 + len(k_t) // 2 + 1  # away from the borders (renormalised there)
    assert np.abs(out - ref)[m:-m, m:-m].max() <= 1e-6
    # Per-axis texel sizes: sigma in texels is sigma_um / texel_um along each axis.
    out2 = convolve_displacement(d, (1.0, 0.0), 0.6, 50.0, -0.7, 13.0, (20.0, 10.0), backend=backend)
    assert np.abs(out2 - out)[m:-m, m:-m].max() <= 1e-6


def test_rotating_input_and_axes_by_90_degrees_rotates_the_output():
    rng = np.random.default_rng(2)
    d = rng.normal(size=(70, 50)).astype(np.float32)
    axis, a_s, s_s, a_t, s_t = _random_fields(rng, d.shape)
    out = convolve_displacement(d, axis, a_s, s_s, a_t, s_t, 10.0)
    # np.rot90: new[i, j] = old[j, W-1-i]; a vector (du, dv) becomes (dv, -du).
    rot_axis = np.rot90(np.stack([axis[..., 1], -axis[..., 0]], -1))
    rot = [np.ascontiguousarray(np.rot90(x)) for x in (d, a_s, s_s, a_t, s_t)]
    out90 = convolve_displacement(rot[0], np.ascontiguousarray(rot_axis), *rot[1:], 10.0)
    assert np.abs(np.rot90(out) - out90).max() <= 1e-5


def test_slope_variance_law_on_white_noise():
    """Var(∂x D') = s² Σ (k_x * d)² Σ k_y² for unit white noise D (d: the central difference stencil, s = 1/texel)."""
    rng = np.random.default_rng(3)
    d = rng.normal(size=(600, 600))
    texel = 10.0
    out = convolve_displacement(d, (1.0, 0.0), -0.8, 23.0, 0.7, 41.0, texel)
    gx = (out[:, 2:] - out[:, :-2]) / (2 * texel)
    k_x, k_y = kernel_taps(-0.8, 23.0, texel), kernel_taps(0.7, 41.0, texel)
    expected = np.sum(np.convolve(k_x, [0.5, 0, -0.5]) ** 2) * np.sum(k_y**2) / texel**2
    m = 20
    assert abs(gx[m:-m, m:-m].var() / expected - 1) < 0.02


def test_compiled_and_numpy_backends_agree_with_islands_and_borders():
    rng = np.random.default_rng(4)
    d = rng.normal(size=(60, 75))
    islands = np.ones(d.shape, int)
    islands[:, 40:] = 2
    islands[:, 37:40] = 0  # gutter
    islands[50:, :10] = 3
    fields = _random_fields(rng, d.shape)
    a = convolve_displacement(d, *fields, (9.0, 6.0), islands=islands, backend="numba")
    b = convolve_displacement(d, *fields, (9.0, 6.0), islands=islands, backend="numpy")
    assert np.abs(a - b).max() <= 1e-5
    assert np.array_equal(a[:, 37:40], d[:, 37:40])  # gutter copied
    # Nothing is read across the gutter: changing island 2 leaves island 1 unchanged.
    d2 = d.copy()
    d2[islands == 2] += 50
    a2 = convolve_displacement(d2, *fields, (9.0, 6.0), islands=islands)
    assert np.array_equal(a2[islands == 1], a[islands == 1])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"displacement": np.full((8, 8), np.nan, np.float32)}, "displacement must be finite"),
        ({"displacement": np.zeros((8, 8), np.int16)}, "displacement must be a float32 or float64 map"),
        ({"alpha_s": 1.5}, r"alpha_s must lie in \[-2, 1\]"),
        ({"alpha_t": np.full((8, 8), -2.5)}, r"alpha_t must lie in \[-2, 1\]"),
        ({"sigma_s": 0.5}, r"sigma_s must lie in \[1, 100\] um"),
        ({"sigma_t": 250.0}, r"sigma_t must lie in \[1, 100\] um"),
        ({"axis_s": (1.0, 1.0)}, "axis_s must hold unit vectors"),
        ({"texel_um": -3.0}, "texel_um must be > 0"),
        ({"alpha_s": np.zeros((4, 4))}, "alpha_s must be a scalar or a map of shape"),
    ],
)
def test_bad_input_names_the_argument(kwargs, match):
    args = dict(
        displacement=np.zeros((8, 8), np.float32),
        axis_s=(1.0, 0.0),
        alpha_s=0.5,
        sigma_s=10.0,
        alpha_t=0.0,
        sigma_t=10.0,
        texel_um=10.0,
    )
    args.update(kwargs)
    with pytest.raises(FacestatsError, match=match):
        convolve_displacement(**args)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_maps_up_to_the_limit_stay_finite_and_beyond_it_are_refused(backend, dtype):
    from facestats.model.microstructure.convolve import MAX_PASS_GAIN, displacement_limit

    limit = displacement_limit(dtype)
    assert limit * MAX_PASS_GAIN**2 <= np.finfo(dtype).max
    assert limit > {np.float32: 5e36, np.float64: 4e303}[dtype]  # not stricter than the docstring says
    rng = np.random.default_rng(4)
    d = np.where(rng.random((40, 40)) < 0.5, -limit, limit).astype(dtype)
    d[20] = -limit  # a row sharpened against its neighbours: the largest overshoot of the test
    d[20, 20] = limit
    args = dict(axis_s=(0.8, 0.6), alpha_s=-2.0, sigma_s=4.0, alpha_t=-2.0, sigma_t=4.0, texel_um=2.0)
    out = convolve_displacement(d, **args, backend=backend)
    assert np.isfinite(out).all() and np.abs(out).max() > 2 * limit  # sharpened well beyond the input
    # An eighth of the dtype's largest number: sharpened to inf before the limit (float32 maps of 3e38).
    over = (d * (np.finfo(dtype).max / limit / 8)).astype(dtype)
    with pytest.raises(FacestatsError, match=r"displacement must lie in \[-"):
        convolve_displacement(over, **args, backend=backend)


def test_compiled_tap_positions_equal_the_exact_formula_of_the_numpy_twin():
    """The vectorised position loop of the compiled pass finds the texels and Lanczos rows of taps.tap_across."""
    compiled = pytest.importorskip("facestats.model.microstructure.compiled")
    if not compiled.HAVE_NUMBA:
        pytest.skip("numba is not available")
    import numba

    from facestats.model.microstructure.taps import LANCZOS_LOBES, LANCZOS_STEPS, major_axis, tap_across

    @numba.njit
    def positions(rad, along, across, stride, slope, bias):
        off, rows = np.empty(2 * rad, np.int64), np.empty(2 * rad, np.int64)
        compiled._tap_positions(rad, along, across, stride, slope, bias, LANCZOS_STEPS, 10, LANCZOS_LOBES, off, rows)
        return off, rows

    rng = np.random.default_rng(5)
    stride, along, across = 4099, 700, 900
    for rad in list(range(1, 40)) * 20:  # every remainder of the vector loop, random axes
        theta = rng.uniform(0, 2 * np.pi)
        _, slope, _ = major_axis(np.float32(np.cos(theta)), np.float32(np.sin(theta)))
        off, rows = positions(rad, along, across, stride, slope[()], float(rad + LANCZOS_LOBES))
        i = np.repeat(np.arange(1, rad + 1), 2) * np.tile([1, -1], rad)  # slots +1, -1, +2, -2, ...
        y0, t = tap_across(slope, i, rad + LANCZOS_LOBES)
        assert np.array_equal(rows, t)
        # tap -i is read with tap +i's row reversed: for a whole-texel position (row 0) its run starts one lower
        start = y0 + 1 - LANCZOS_LOBES - ((i < 0) & (t == 0))
        assert np.array_equal(off, (along + i) * stride + across + start)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_compiled_lanczos_pair_is_the_dot_product_of_both_taps(dtype):
    """The vector intrinsic of the interior path: tap +i's six texels weighed by its Lanczos row, tap -i's by the
    row reversed, the two lanes of weight 0 past each ignored, summed in the map's precision."""
    compiled = pytest.importorskip("facestats.model.microstructure.compiled")
    if not compiled.HAVE_NUMBA:
        pytest.skip("numba is not available")
    import numba

    @numba.njit
    def pair(flat, op, on, lanes, t):
        return compiled._lanczos_pair(flat, numba.uint64(op), numba.uint64(on), lanes, t)

    from facestats.model.microstructure.taps import LANCZOS

    lanes = compiled._lanczos_lanes(dtype)
    assert lanes.dtype == dtype and lanes.shape == (LANCZOS.shape[0], 16)
    rng = np.random.default_rng(11)
    flat = rng.normal(0.0, 100.0, 500).astype(dtype)
    eps = np.finfo(dtype).eps
    for _ in range(200):
        op, on = rng.integers(0, flat.size - 8, 2)
        t = int(rng.integers(0, LANCZOS.shape[0]))
        w = LANCZOS[t]
        fp, fn = flat[op : op + 6].astype(np.float64), flat[on : on + 6].astype(np.float64)
        want = w @ fp + w[::-1] @ fn
        scale = np.abs(w) @ np.abs(fp) + np.abs(w[::-1]) @ np.abs(fn)  # rounding of 12 products and 11 sums
        assert abs(pair(flat, op, on, lanes, t) - want) <= 16 * eps * scale, (op, on, t)
    flat[6:8] = np.nan  # the lanes of weight 0 must be texels of the map, and are: a NaN there would show
    assert np.isnan(pair(flat, 0, 100, lanes, 5))


def _wave(shape, direction, omega, phase=0.3):
    y, x = np.indices(shape, dtype=np.float64)
    return np.cos(omega * (direction[0] * x + direction[1] * y) + phase)


def _gain(out, wave, margin):
    """Amplitude the convolution kept of a plane wave (least squares, interior)."""
    o, w = out[margin:-margin, margin:-margin].ravel(), wave[margin:-margin, margin:-margin].ravel()
    return float(o @ w / (w @ w))


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_a_pass_along_s_leaves_a_wave_across_s_at_every_angle(backend):
    """Eq. 3 samples D on the line through the texel along s: a wave that is constant along s passes a pass along s
    unchanged, whatever the angle.  Bilinear taps kept 0.81-0.84 of it at omega = pi/2 off the grid (a red team:
    compression then blurred instead of sharpening); Lanczos-3 taps across the major direction keep 1.00-1.02."""
    n, texel = (96, 96) if backend == "numpy" else (160, 160), 6.0
    for deg in (0.0, 10.0, 22.5, 26.57, 35.0, 45.0, 60.0, 80.0, 100.0, 135.0, 170.0):
        th = np.radians(deg)
        axis = (np.cos(th), np.sin(th))
        d = _wave(n, (-axis[1], axis[0]), np.pi / 2)
        out = convolve_displacement(d, axis, 1.0, 57.5, 0.0, 1.0, texel, backend=backend)  # r = 2.2 (FOREHEAD)
        assert abs(_gain(out, d, 35) - 1) < 0.02, deg


def test_compression_across_a_diagonal_stretch_sharpens_as_eq6_says():
    """Both passes (stretch r_s = 2.2 along s, compression r_t = 0.65 across: FOREHEAD's kernels) on a wave across s
    at omega = pi/2: eq. 6 gives K_t = 2.02.  Every angle within 9 % of it (bilinear taps: 1.65-1.72, 15-18 % low).
    At 45 degrees the taps of the narrow compression kernel (sigma 0.76 texel) are a diagonal sqrt 2 apart, and its
    discrete Gaussian is coarser there: 1.85."""
    texel, omega = 6.0, np.pi / 2
    (a_s, s_s), (a_t, s_t) = (1.0, 57.54), (-2.0, 4.565)
    expected = frequency_response(kernel_taps(a_t, s_t, texel), omega)[()]
    assert abs(expected - 2.018) < 1e-3
    gains = []
    for deg in (0.0, 10.0, 22.5, 35.0, 45.0, 60.0, 80.0):
        th = np.radians(deg)
        axis = (np.cos(th), np.sin(th))
        d = _wave((192, 192), (-axis[1], axis[0]), omega)
        gains.append(_gain(convolve_displacement(d, axis, a_s, s_s, a_t, s_t, texel), d, 40))
    assert abs(gains[0] - expected) < 1e-3
    assert all(abs(g / expected - 1) < 0.09 for g in gains), gains


def test_a_45_degree_axis_reads_whole_texels_on_the_diagonal():
    """At 45 degrees every tap is a texel (slope 1): the pass is the 1-D kernel of taps sqrt 2 apart on the diagonal."""
    rng = np.random.default_rng(11)
    d = rng.normal(size=(90, 90))
    texel, alpha, sigma = 5.0, 0.75, 20.0  # alpha exact in float32, as the map-level API holds it
    out = convolve_displacement(d, (np.sqrt(0.5), np.sqrt(0.5)), alpha, sigma, 0.0, 1.0, texel)
    s = np.float64(np.float32(sigma) / np.float32(texel)) * np.float64(np.float32(np.sqrt(0.5)))  # sigma in taps
    n = int(np.ceil(3 * s))
    i = np.arange(-n, n + 1)
    g = np.exp(-(i * i) / (2 * s * s))
    g /= g.sum()
    ref = np.zeros_like(d)
    for k, gk in zip(i, g):
        ref += gk * np.roll(d, (-k, -k), axis=(0, 1))
    ref = (1 - alpha) * d + alpha * ref
    m = n + 1
    assert np.abs(out - ref)[m:-m, m:-m].max() < 1e-12


def test_the_fit_stencil_is_the_pass_applied_to_an_impulse():
    """fit.gaussian_stencil (the fit's forward model) and the compiled pass read the same texels with the same
    weights."""
    from facestats.model.microstructure.fit import gaussian_stencil

    for axis in ((1.0, 0.0), (0.6, 0.8), (np.cos(0.3), -np.sin(0.3)), (-0.28, 0.96)):
        st, half = gaussian_stencil(axis, 2.75)  # 27.5 um at 10 um a texel, exact in float32
        size = 4 * half + 9
        d = np.zeros((size, size))
        c = size // 2
        d[c, c] = 1.0
        out = convolve_displacement(d, axis, 1.0, 27.5, 0.0, 1.0, 10.0)  # gather: out[x] = K[x - c]
        # The pass gathers out[x] = sum_y K[y - x] d[y]; the stencil is the kernel as a convolution, K reversed.
        got = out[c - half : c + half + 1, c - half : c + half + 1][::-1, ::-1]
        assert np.abs(got - st).max() < 1e-12, axis
        assert abs(st.sum() - 1) < 1e-12


def test_row_layout_does_not_change_the_result():
    """Maps whose row stride aliases in the caches (a multiple of 1 KiB) are read through padded rows;
    contiguous maps, padded maps and views of wider maps give the same bits."""
    from facestats.model.microstructure.compiled import padded_empty

    rng = np.random.default_rng(7)
    d = rng.normal(size=(90, 256)).astype(np.float32)  # 1 KiB rows: padded internally
    fields = _random_fields(rng, d.shape)
    ref = convolve_displacement(d, *fields, 10.0)
    wide = np.zeros((90, 300), np.float32)
    wide[:, :256] = d
    padded = padded_empty(d.shape, np.float32)
    padded[...] = d
    assert padded.strides[0] % 1024 != 0 and padded.base.shape[1] > 256
    for layout in (wide[:, :256], padded, np.asfortranarray(d)):
        np.testing.assert_array_equal(convolve_displacement(layout, *fields, 10.0), ref)
    assert np.abs(convolve_displacement(d, *fields, 10.0, backend="numpy") - ref).max() <= 1e-5


def test_kernels_beyond_the_tap_limit_or_below_a_texel_are_refused_or_an_impulse():
    """A huge sigma overflowed the radius's int64 cast; a sigma whose square underflows gave NaN taps; a texel size
    that rounds to 0 in float32 divided by zero in the compiled pass (a red team)."""
    with pytest.raises(FacestatsError, match="taps, more than the 8193 allowed"):
        kernel_taps(0.5, 1e20, 1.0)
    np.testing.assert_array_equal(kernel_taps(0.5, 1e-200, 1.0), [0.0, 1.0, 0.0])
    d = np.random.default_rng(0).normal(size=(8, 8)).astype(np.float32)
    for backend in ("numpy", "numba"):
        for texel in (1e-300, 1e-40, 1e-3, 0.005):  # 0.005: 4096 taps reach 2 sigma, short of the 3 needed
            with pytest.raises(FacestatsError, match="texel_um must be at least 0.00732 um for sigma up to 10 um"):
                convolve_displacement(d, [1.0, 0.0], 0.5, 10.0, 0.5, 10.0, texel, backend=backend)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_texels_next_to_a_border_are_filtered_at_every_angle(backend):
    """A tap whose six Lanczos texels leave the island or the map is read linearly between its two nearest texels
    (as the bilinear taps read it) instead of ending that side: the first version stopped both sides at tap 1 within
    two texels of a border parallel to an axis a degree off the grid, and copied those texels unfiltered (the
    review of 2026-12-07)."""
    rng = np.random.default_rng(0)
    d = rng.standard_normal((40, 200))
    islands = np.ones(d.shape, np.int32)
    islands[20:, :] = 2
    for deg in (0.0, 1.0, 10.0, 30.0):
        th = np.radians(deg)
        out = convolve_displacement(d, (np.cos(th), np.sin(th)), 1.0, 30.0, 0.0, 1.0, 6.0, islands=islands,
                                    backend=backend)  # fmt: skip
        for row in (0, 1, 18, 19, 20, 21, 38, 39):  # next to the island border and the map's edges
            changed = np.abs(out[row, 40:160] - d[row, 40:160])
            assert changed.min() > 0 and np.median(changed) > 0.1, (deg, row)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_a_linear_ramp_passes_unchanged_at_any_angle(backend):
    """Each kernel is symmetric: tap -i is tap i mirrored through the texel, rounded alike, with the Lanczos row
    reversed (taps.tap_across; the table is mirror-symmetric).  So a linear ramp, whose value at a point is the mean
    of its values at two mirrored points, passes a blur unchanged in the interior, for axes off the grid too."""
    y, x = np.indices((110, 130), dtype=np.float64)
    ramp = 0.37 * x - 0.81 * y + 3.0
    for deg in (7.0, 22.5, 33.3, 61.0, 118.0):
        th = np.radians(deg)
        out = convolve_displacement(ramp, (np.cos(th), np.sin(th)), 1.0, 40.0, 1.0, 25.0, 6.0, backend=backend)
        m = 2 * (20 + 3) + 1  # both passes' reach (20 taps, 3 texels across): one-sided kernels nearer the edges
        assert np.abs(out - ramp)[m:-m, m:-m].max() < 1e-9, deg


def test_gaussian_taps_refuses_a_sigma_that_is_not_one_number_by_name():
    """float(sigma_px) took the string "1.0" and raised a bare ValueError for "x"."""
    for bad in ("1.0", "x", [1.0], -1.0, np.nan):
        with pytest.raises(FacestatsError, match="sigma_px must"):
            gaussian_taps(bad)
    np.testing.assert_array_equal(gaussian_taps(np.float32(0.0)), [1.0])


def test_island_reach_counts_the_border_whatever_the_labels():
    """The map was padded with label −1 for the outside, so an island labelled −1 hid the border (a reviewer)."""
    from facestats.model.microstructure.convolve import island_reach

    pos = np.ones((12, 16), np.int64)
    pos[:, 10:] = 2
    expected = island_reach(pos)
    assert expected[0, 0] == 0 and expected[5, 5] == 4  # 5 texels from the top row, the nearest boundary texels
    assert expected[2, 5] == 2 and expected[9, 5] == 2  # the top and bottom rows count as boundary (4 from column 9)
    for labels in ((-1, 2), (-1, -2), (0, 7)):
        np.testing.assert_array_equal(island_reach(np.where(pos == 1, *labels)), expected)
