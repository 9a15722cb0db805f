"""Histogram matching and interpolation of facestats.edit (Heeger & Bergen 1995; Matusik et al. 2005)."""

import numpy as np
import pytest

from facestats.edit import Histogram, histogram_distance, interpolate_histograms, match_histogram, match_values
from facestats.errors import ValidationError


def _bimodal(rng, n):
    return np.concatenate([rng.normal(0.2, 0.03, n // 3), rng.normal(0.45, 0.05, n - n // 3)])


def test_match_values_is_exact(rng):
    x = rng.gamma(2.0, 1.0, 5000)
    y = _bimodal(rng, 5000)
    out = match_values(x, y)
    # The matched data has the target's distribution: it is a permutation of the target values.
    np.testing.assert_array_equal(np.sort(out), np.sort(y))
    # ... and the map is increasing: ranks of the source are kept.
    np.testing.assert_array_equal(np.argsort(out, kind="stable"), np.argsort(x, kind="stable"))


def test_match_values_float32_and_other_size(rng):
    x = rng.uniform(0, 1, (40, 50)).astype(np.float32)
    y = rng.normal(3.0, 0.5, 20000)
    out = match_values(x, y)
    assert out.dtype == np.float32 and out.shape == x.shape
    u = (np.arange(out.size) + 0.5) / out.size
    # Hazen plotting positions: the target quantile at (rank + ½)/n.
    np.testing.assert_allclose(np.sort(out.ravel()), np.quantile(y, u, method="hazen"), rtol=1e-6)


def test_match_values_interpolation_endpoints_and_monotone(rng):
    x = rng.normal(0.3, 0.05, 3000)
    y = rng.normal(0.5, 0.02, 3000)
    np.testing.assert_array_equal(match_values(x, y, t=0.0), x)
    ts = np.linspace(0, 1, 11)
    outs = np.array([match_values(x, y, t=t) for t in ts])
    np.testing.assert_array_equal(outs[-1], match_values(x, y))
    d = np.diff(outs, axis=0)
    assert np.all((d >= -1e-15) == np.all(d >= -1e-15, axis=0))  # each value moves one way
    means = outs.mean(axis=1)
    np.testing.assert_allclose(means, (1 - ts) * x.mean() + ts * y.mean(), rtol=1e-12)
    q = np.quantile(outs, [0.05, 0.5, 0.95], axis=1)
    assert np.all(np.diff(q, axis=1) > 0)  # every quantile moves monotonically towards the target


def test_match_histogram_reproduces_target_histogram(rng):
    target = Histogram.from_data(_bimodal(rng, 400_000), bins=256)
    x = rng.exponential(1.0, 400_000).astype(np.float32)
    out = match_histogram(x, target)
    assert out.dtype == np.float32
    counts, _ = np.histogram(out, bins=target.edges)
    tv = 0.5 * np.abs(counts / out.size - target.pdf).sum()
    # Well below the sampling noise of a second 400k sample of the target (TV ~ 7e-3); the residual
    # comes from interpolating F_source linearly inside its 16384 bins.
    assert tv < 3e-3
    assert np.all(np.diff(out[np.argsort(x)]) >= 0)  # monotone map
    np.testing.assert_array_equal(match_histogram(x, target, t=0.0), x)


def test_match_histogram_partial_follows_interpolation(rng):
    h0 = Histogram.from_data(rng.normal(0.0, 1.0, 200_000), bins=256)
    h1 = Histogram.from_data(rng.normal(4.0, 2.0, 200_000), bins=256)
    x = rng.normal(0.0, 1.0, 200_000)
    out = match_histogram(x, h1, t=0.5)
    # Displacement interpolation of N(0, 1) and N(4, 2²) at t = 0.5 is N(2, 1.5²).
    assert out.mean() == pytest.approx(2.0, abs=0.02)
    assert out.std() == pytest.approx(1.5, rel=0.01)
    h = interpolate_histograms(h0, h1, 0.5)
    assert histogram_distance(Histogram.from_data(out, 512), h) < 0.01
    # Exactly (1 − t) x + t T(x), T the full match: within each source bin both ends interpolate alike
    full = match_histogram(x, h1, t=1.0)
    for t in (0.3, 0.5):
        assert np.abs(match_histogram(x, h1, t=t) - ((1 - t) * x + t * full)).max() < 1e-9


def test_constant_values_move_the_fraction_t_towards_the_target_mean():
    """Constant values have no distribution to match: they go to (1 - t) x + t mean(target) (match_histogram)."""
    target = Histogram([0.0, 1.0, 2.0, 3.0], [1.0, 2.0, 1.0])
    out = match_histogram(np.full((4, 5), 7.0), target, t=0.25)
    np.testing.assert_allclose(out, 0.75 * 7.0 + 0.25 * 1.5, rtol=1e-12)


def test_quantile_inverts_cdf_and_jumps_over_empty_bins():
    h = Histogram([0.0, 1.0, 2.0, 3.0, 4.0], [2.0, 0.0, 0.0, 2.0])
    np.testing.assert_allclose(h.cdf, [0.0, 0.5, 0.5, 0.5, 1.0])
    np.testing.assert_allclose(h.quantile([0.0, 0.25, 0.5, 0.75, 1.0]), [0.0, 0.5, 1.0, 3.5, 4.0])
    assert h.quantile(0.5 + 1e-9) == pytest.approx(3.0, abs=1e-6)
    assert h.quantile(0.5, side="right") == 3.0  # the other limit at the jump
    assert h.mean() == pytest.approx(2.0)


@pytest.mark.parametrize("n", [5, 16, 300])
def test_values_matched_to_their_own_histogram_stay_in_their_bins(rng, n):
    """Sparse samples (coarse pyramid bands, small regions): every value keeps its target bin.

    Evaluated at the source bin edges alone, Q jumped across runs of empty target bins inside a source bin,
    and the values of that bin were spread over the gap (0.5 of [0, .1, .5, .9, 1] went to 0.10).
    """
    x = rng.standard_normal(n)
    h = Histogram.from_data(x, 256)
    out = match_histogram(x, h)
    np.testing.assert_array_equal(np.histogram(out, bins=h.edges)[0], h.counts)
    assert np.abs(out - x).max() <= h.edges[1] - h.edges[0]
    five = np.array([0.0, 0.1, 0.5, 0.9, 1.0])
    np.testing.assert_allclose(match_histogram(five, Histogram.from_data(five, 256)), five, atol=1 / 256)


def test_interpolation_endpoints(rng):
    h0 = Histogram.from_data(rng.normal(0.2, 0.05, 10_000), bins=64)
    h1 = Histogram.from_data(rng.gamma(3.0, 0.1, 20_000), bins=64)
    a, b = interpolate_histograms(h0, h1, 0.0), interpolate_histograms(h0, h1, 1.0)
    np.testing.assert_allclose(a.edges, h0.edges, rtol=0, atol=0)
    np.testing.assert_allclose(a.counts, h0.counts, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(b.edges, h1.edges, rtol=0, atol=0)
    np.testing.assert_allclose(b.counts, h1.counts, rtol=1e-9, atol=1e-9)


def test_interpolation_monotone_in_t_and_moves_modes(rng):
    h0 = Histogram.from_data(rng.normal(0.0, 1.0, 100_000), bins=128)
    h1 = Histogram.from_data(rng.normal(6.0, 1.0, 100_000), bins=128)
    ts = np.linspace(0, 1, 21)
    hs = [interpolate_histograms(h0, h1, t) for t in ts]
    means = np.array([h.mean() for h in hs])
    assert np.all(np.diff(means) > 0)
    np.testing.assert_allclose(means, (1 - ts) * h0.mean() + ts * h1.mean(), atol=0.01)
    u = np.linspace(0.01, 0.99, 25)
    q = np.array([h.quantile(u) for h in hs])
    assert np.all(np.diff(q, axis=0) > 0)  # every quantile increases with t
    # Half-way the mode sits at 3 (a shifted bump), not at 0 and 6 (a mixture).
    mid = hs[10]
    centres = 0.5 * (mid.edges[1:] + mid.edges[:-1])
    assert centres[np.argmax(mid.counts)] == pytest.approx(3.0, abs=0.2)
    assert mid.quantile(0.5) == pytest.approx(3.0, abs=0.05)


def test_interpolation_with_different_bins(rng):
    h0 = Histogram.from_data(rng.uniform(0, 1, 10_000), bins=32)
    h1 = Histogram.from_data(rng.uniform(2, 4, 10_000), bins=100)
    h = interpolate_histograms(h0, h1, 0.25)
    assert h.bins == 100
    assert h.edges[0] == pytest.approx(0.5, abs=1e-3) and h.edges[-1] == pytest.approx(1.75, abs=1e-3)
    assert h.total == pytest.approx(10_000)


def test_histogram_distance():
    h = Histogram(np.linspace(0, 1, 11), np.ones(10))
    assert histogram_distance(h, h) == pytest.approx(0.0, abs=1e-15)
    far = Histogram(np.linspace(2, 3, 11), np.ones(10))
    assert histogram_distance(h, far) == pytest.approx(1.0)
    half = Histogram(np.linspace(0.5, 1.5, 11), np.ones(10))
    assert histogram_distance(h, half) == pytest.approx(0.5)


def test_validation():
    h = Histogram([0.0, 1.0], [1.0])
    with pytest.raises(ValidationError, match="t must lie in"):
        match_histogram([0.1, 0.2], h, t=1.5)
    with pytest.raises(ValidationError, match="strictly increasing"):
        Histogram([0.0, 0.0], [1.0])
    with pytest.raises(ValidationError, match="all be zero"):
        Histogram([0.0, 1.0], [0.0])
    with pytest.raises(ValidationError, match="finite"):
        match_values([np.nan], [1.0])
    with pytest.raises(ValidationError, match="Histogram"):
        interpolate_histograms(h, [1, 2], 0.5)


def test_explicit_edges_must_cover_the_interpolated_values():
    """Edges narrower than the interpolated distribution dropped its counts (a total of 1447 of 10000, found by an
    API red team); they are refused, and edges that cover it keep the documented total."""
    rng = np.random.default_rng(0)
    h0, h1 = Histogram.from_data(rng.normal(size=10000), 64), Histogram.from_data(rng.normal(1, 2, size=10000), 64)
    with pytest.raises(ValidationError, match=r"edges must cover the interpolated values \[-5.47.*got \[-1, 1\]"):
        interpolate_histograms(h0, h1, 0.5, edges=np.linspace(-1, 1, 9))
    assert interpolate_histograms(h0, h1, 0.5, edges=np.linspace(-10, 12, 9)).total == pytest.approx(10000)


def test_distance_floor_is_the_expected_distance_of_a_sample_of_the_target(rng):
    """de Moivre's binomial mean absolute deviation against direct counting: one draw from two equal bins always
    lies in one, TV = ½ (|1 − ½| + |0 − ½|) = ½; n draws of a normal against its own fine histogram, through the
    measuring code of the texture transfer (source_histogram, histogram_distance), over 400 samples."""
    from facestats.edit.histogram import SOURCE_BINS, distance_floor, source_histogram

    assert distance_floor(Histogram([0.0, 1.0, 2.0], [1.0, 1.0]), 1) == pytest.approx(0.5, abs=1e-12)
    # three equal bins, two draws: same bin (prob 1/3) TV = 2/3, different bins TV = 1/3 -> 4/9
    assert distance_floor(Histogram([0.0, 1.0, 2.0, 3.0], [1.0, 1.0, 1.0]), 2) == pytest.approx(4 / 9, abs=1e-12)
    target = Histogram.from_data(rng.normal(size=1_000_000), 256)
    for n in (64, 256, 1024):
        measured = np.mean(
            [histogram_distance(source_histogram(rng.normal(size=n), SOURCE_BINS)[0], target) for _ in range(400)]
        )
        assert distance_floor(target, n) == pytest.approx(measured, rel=0.03), n
    assert distance_floor(target, 4096) / distance_floor(target, 1024) == pytest.approx(0.5, rel=0.03)  # 1 / sqrt n
    # a target counted from m values: the noise of both samples, n m / (n + m)
    assert distance_floor(target, 256, reference=256) == pytest.approx(distance_floor(target, 128))
    with pytest.raises(ValidationError, match="n must be > 0, got 0.0"):
        distance_floor(target, 0)
