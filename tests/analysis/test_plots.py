"""The analysis figures (Weyrich Fig. 14-16, Table 1, conditions, posteriors) are produced and show their data."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.collections import PathCollection
from matplotlib.figure import Figure
from matplotlib.image import AxesImage
from matplotlib.patches import Ellipse, Rectangle

from facestats import analysis as fa
from facestats.acquire.sensor import ContactSensor
from facestats.analysis import plots
from facestats.model import dipole
from tests.helpers import make_population


@pytest.fixture(scope="module")
def store():
    return make_population(n=40, seed=2)


def _save(fig, path):
    assert isinstance(fig, Figure)
    fig.savefig(path, dpi=60)
    assert path.stat().st_size > 5000  # a real PNG with content
    return fig


def _points(ax):
    return sum(len(c.get_offsets()) for c in ax.collections if isinstance(c, PathCollection))


def test_skin_type_colours_run_from_light_to_black():
    colors = plots.skin_type_color(np.arange(1, 7))
    lum = colors.sum(1)
    assert np.all(np.diff(lum[1:]) < 0) and lum[0] == lum[1]  # I and II share the lightest colour
    np.testing.assert_allclose(colors[-1], 0.0)


def test_region_pca_figure(store, tmp_path):
    res = fa.region_pca(store)
    fig = _save(plots.plot_region_pca(res, k=2.0), tmp_path / "fig15.png")
    ax = fig.axes[0]
    ellipses = [p for p in ax.patches if isinstance(p, Ellipse)]
    assert len(ellipses) == len(res.regions) == 10
    for e, (r, reg) in zip(ellipses, res.regions.items()):
        np.testing.assert_allclose(e.center, reg.mean)
        np.testing.assert_allclose([e.width, e.height], 4 * np.sqrt(reg.eigenvalues))  # k = 2: half-axes 2σ
        assert e.angle == pytest.approx(np.degrees(reg.angle))
    assert "2σ" in ax.get_title()


def test_cca_figure(store, tmp_path):
    res = fa.brdf_cca(store, n_permutations=0)
    fig = _save(plots.plot_cca(res), tmp_path / "fig16.png")
    ax = fig.axes[0]
    assert _points(ax) == res.n
    # markers: diamonds for women, circles for men, as in the paper
    n_f = int(res.y_data["gender"].sum())
    sizes = [len(c.get_offsets()) for c in ax.collections]
    assert sorted(sizes) == sorted([n_f, res.n - n_f])
    np.testing.assert_allclose(
        np.sort(np.concatenate([c.get_offsets()[:, 0] for c in ax.collections])), np.sort(res.projections[:, 0])
    )
    assert f"{res.correlations[0]:.3f}" in ax.get_xlabel()
    # brdf_cca pools types I and II (the store has type I subjects): the legend says so, as the posterior does
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "type I-II" in labels and "type II" not in labels and "type III" in labels
    # a single-dimension CCA plots X against Y variate
    one = fa.cca(res.projections[:, :2], res.y_data[["skin_type"]])
    _save(plots.plot_cca(one), tmp_path / "cca1.png")


def test_absorption_scattering_figure(store, tmp_path):
    res = fa.absorption_scattering(store)
    fig = _save(plots.plot_absorption_scattering(res), tmp_path / "fig14.png")
    axes = fig.axes
    assert len(axes) == 3
    n = res.data["subject_id"].nunique()
    for ax, ch in zip(axes, "RGB"):
        assert _points(ax) == n
        ys = np.sort(np.concatenate([c.get_offsets()[:, 1] for c in ax.collections]))
        np.testing.assert_allclose(ys, np.sort(res.data.query("channel == @ch")["sigma_a"]))


def test_translucency_figure(store, tmp_path):
    t = fa.translucency_table(store)
    fig = _save(plots.plot_translucency(t), tmp_path / "table1.png")
    ax = fig.axes[0]
    bars = [p for p in ax.patches if isinstance(p, Rectangle)]
    assert len(bars) == 9
    heights = sorted(b.get_height() for b in bars)
    want = sorted(t.table.xs("mean", axis=1, level="statistic").to_numpy().ravel())
    np.testing.assert_allclose(heights, want)


def test_conditions_figure(store, tmp_path):
    res = fa.condition_differences(store)
    fig = _save(plots.plot_conditions(res), tmp_path / "conditions.png")
    images = [im for ax in fig.axes for im in ax.get_images() if isinstance(im, AxesImage)]
    assert len(images) == 3
    d_rho = images[0].get_array()
    want = res.differences["d_rho_s"].unstack("region").loc[list(res.conditions[1:])].to_numpy()
    np.testing.assert_allclose(d_rho, want)
    np.testing.assert_allclose(images[2].get_array(), res.distance.to_numpy())
    assert not any(t.get_text() == "n/a" for ax in fig.axes for t in ax.texts)
    assert "pooled within-region sd" in fig.axes[2].get_title()  # the distance's axes (the colour bars follow)


def test_conditions_figure_marks_a_region_without_texels(store, tmp_path):
    """A 16² store has no mustache texels: the heat maps showed a blank column for region 1, unexplained."""
    idx = store.subjects().copy()
    rows = idx.index[idx["person_id"] == "P-cond"]
    idx.loc[rows, [c for c in idx.columns if c.endswith("_r1") and c.startswith("ts_")]] = np.nan
    idx.loc[rows, "n_ts_r1"] = 0
    res = fa.condition_differences(idx)
    fig = _save(plots.plot_conditions(res), tmp_path / "conditions.png")
    for ax in fig.axes[:2]:  # the two heat maps of differences (the colour bars follow the three axes)
        hatched = [p for p in ax.patches if isinstance(p, Rectangle) and p.get_hatch()]
        assert len(hatched) == 1 and hatched[0].get_x() == pytest.approx(-0.5)  # column 0: region 1
        assert [t.get_text() for t in ax.texts] == ["n/a"]
    assert "left out: region 1 mustache (no texels)" in fig._suptitle.get_text()


@pytest.mark.slow
def test_posterior_figures(store, tmp_path):
    sensor = ContactSensor()
    sp, sa = dipole.scattering_from_albedo(np.array([0.5, 0.3, 0.2]), np.array([0.6, 1.0, 1.6]))
    truth = np.stack([dipole.dipole_profile(sensor.fiber_distance, sp[c], sa[c]) for c in range(3)], -1)
    measured, _ = sensor.capture(truth, np.random.default_rng(0))
    post = fa.sigma_posterior(sensor.fiber_distance, measured)
    fig = _save(plots.plot_sigma_posterior(post, truth={"R": {"sigma_a": sa[0]}}), tmp_path / "posterior.png")
    visible = [ax for ax in fig.axes if ax.get_visible()]
    assert len(visible) == 3 * 6  # three lower-triangular 3 × 3 corners
    one = plots.plot_sigma_posterior(post, labels=["G"], parameters=("sigma_s_prime", "sigma_a"))
    assert len([ax for ax in one.axes if ax.get_visible()]) == 3
    pop = fa.population_sigma_tr(store, n_draws=2000)
    fig = _save(plots.plot_population_sigma_tr(pop), tmp_path / "population.png")
    assert len(fig.axes) == 3
    assert [t.get_text() for t in fig.axes[0].get_xticklabels()] == ["I-II", "III", "IV", "V", "VI"]  # I, II pooled
