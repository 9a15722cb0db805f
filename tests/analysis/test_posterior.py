"""Bayesian posteriors of (σ's, σa) per sensor profile and of the mean σtr per skin type."""

from __future__ import annotations

import emcee
import numpy as np
import pytest
from scipy import stats

from facestats.acquire.sensor import ContactSensor
from facestats.analysis import population_sigma_tr, select_population, sigma_posterior, site_sigma_posterior
from facestats.analysis.posterior import BlockDEMove
from facestats.analysis.translucency import subject_sigma_tr
from facestats.errors import ConvergenceWarning, ValidationError
from facestats.model import dipole
from tests.helpers import make_population

SENSOR = ContactSensor()
R = SENSOR.fiber_distance


def simulate(n, rng):
    """Profiles (F, n) captured by the simulated sensor from plausible skin: σtr 0.4-2 mm⁻¹, albedo 0.1-0.7."""
    sigma_tr = rng.uniform(0.4, 2.0, n)
    albedo = rng.uniform(0.1, 0.7, n)
    sp, sa = dipole.scattering_from_albedo(albedo, sigma_tr)
    truth = dipole.dipole_profile(R[:, None], sp[None], sa[None])
    measured, std = SENSOR.capture(truth, rng)
    return measured, truth, sp, sa, sigma_tr


@pytest.mark.slow
def test_credible_intervals_are_calibrated():
    """90 % intervals of 200 simulated profiles (one channel each) cover the truth 85-95 % of the time."""
    measured, _, sp, sa, sigma_tr = simulate(200, np.random.default_rng(2024))
    post = sigma_posterior(R, measured, seed=7)
    d = post.diagnostics
    assert post.converged and (d["steps_over_tau"] >= 50).all()
    assert d["acceptance"].between(0.15, 0.7).all()
    # every chain found the global mode: χ²/dof at the median is that of the noise (26 dof per profile)
    assert 0.9 < d["chi2_dof"].mean() < 1.1 and d["chi2_dof"].max() < 2.5
    for name, truth in (("sigma_s_prime", sp), ("sigma_a", sa), ("sigma_tr", sigma_tr)):
        iv = post.interval(name)
        cover = np.mean((iv[:, 0] <= truth) & (truth <= iv[:, 1]))
        assert 0.85 <= cover <= 0.95, (name, cover)
        # both tails miss about equally often (no bias)
        assert abs(np.mean(truth < iv[:, 0]) - np.mean(truth > iv[:, 1])) < 0.05


def test_block_move_samples_independent_gaussians():
    """The block DE move reproduces the means and covariances of three independent 2-D Gaussians."""
    means = np.array([[1.0, -2.0], [0.0, 0.5], [3.0, 3.0]])
    covs = np.array([[[1.0, 0.9], [0.9, 1.0]], [[0.01, 0.0], [0.0, 4.0]], [[2.0, -1.2], [-1.2, 1.0]]])
    prec = np.linalg.inv(covs)

    def log_prob(theta):
        d = theta.reshape(-1, 3, 2) - means
        blocks = -0.5 * np.einsum("nki,kij,nkj->nk", d, prec, d)
        return np.concatenate([blocks.sum(1, keepdims=True), blocks], axis=1)

    rng = np.random.default_rng(0)
    move = BlockDEMove(3, 2)
    sampler = emcee.EnsembleSampler(16, 6, log_prob, vectorize=True, moves=[move])
    sampler.random_state = np.random.RandomState(1).get_state()
    sampler.run_mcmc(means.reshape(-1) + 0.1 * rng.standard_normal((16, 6)), 6000, skip_initial_state_check=True)
    tau = emcee.autocorr.integrated_time(sampler.get_chain(), quiet=True)
    assert tau.max() < 30
    x = sampler.get_chain(discard=300, thin=5, flat=True)
    ess = x.shape[0] * 5 / tau.max()
    for k in range(3):
        xb = x[:, 2 * k : 2 * k + 2]
        se = np.sqrt(np.diag(covs[k]) / ess)
        np.testing.assert_array_less(np.abs(xb.mean(0) - means[k]), 5 * se)
        np.testing.assert_allclose(
            np.cov(xb.T), covs[k], rtol=0.1, atol=0.05 * np.sqrt(np.outer(np.diag(covs[k]), np.diag(covs[k]))).max()
        )
    cross = np.corrcoef(x.T)[0:2, 2:6]
    assert np.abs(cross).max() < 0.1  # blocks do not talk to each other
    acc = move.accepted.mean(0) / move.n_proposals
    assert np.all((acc > 0.2) & (acc < 0.7))


def test_one_profile_three_channels():
    rng = np.random.default_rng(11)
    sp, sa = dipole.scattering_from_albedo(np.array([0.55, 0.32, 0.24]), np.array([0.55, 0.98, 1.55]))
    truth = np.stack([dipole.dipole_profile(R, sp[c], sa[c]) for c in range(3)], -1)
    measured, _ = SENSOR.capture(truth, rng)
    post = sigma_posterior(R, measured, seed=3)
    assert post.labels == ("R", "G", "B") and post.noise == "sensor model"
    d = post.diagnostics
    tau = d[["tau_sigma_s_prime", "tau_sigma_a"]].max(axis=1)
    assert (post.n_steps >= 50 * tau).all() and d["converged"].all()
    assert (d["burn_in"] >= 3 * tau).all() and (d["thin"] == np.maximum(1, (tau / 2).astype(int))).all()
    np.testing.assert_allclose(d["ess_sigma_a"], post.n_walkers * (post.n_steps - d["burn_in"]) / d["tau_sigma_a"])
    for c, ch in enumerate("RGB"):
        s = post.samples[ch]
        np.testing.assert_allclose(
            s["sigma_tr"], np.sqrt(3 * s["sigma_a"] * (s["sigma_a"] + s["sigma_s_prime"])), rtol=1e-12
        )
        np.testing.assert_allclose(s["ell_d"] * s["sigma_tr"], 1.0, rtol=1e-12)
        row = post.summary.loc[(ch, "sigma_s_prime")]
        assert row["lo"] < row["median"] < row["hi"]
        assert abs(row["median"] - sp[c]) < 4 * row["std"]
        assert abs(post.summary.loc[(ch, "sigma_a"), "median"] - sa[c]) < 4 * post.summary.loc[(ch, "sigma_a"), "std"]
        # the posterior is narrow (0.5 % noise per fibre) and centred near the least-squares fit
        assert row["std"] / row["median"] < 0.02
        assert abs(post.least_squares.loc[ch, "sigma_s_prime"] - row["median"]) < row["std"]
    np.testing.assert_allclose(post.median("sigma_tr"), [0.55, 0.98, 1.55], rtol=0.01)

    # an explicit std (the noise model at the truth) gives the same posterior within its width
    explicit = sigma_posterior(R, measured, SENSOR.profile_std(truth), seed=3)
    assert explicit.noise == "explicit std"
    for ch in "RGB":
        a, b = post.summary.loc[(ch, "sigma_a")], explicit.summary.loc[(ch, "sigma_a")]
        assert abs(a["median"] - b["median"]) < 0.5 * a["std"]
        assert b["std"] == pytest.approx(a["std"], rel=0.2)
    # a wider interval at a higher level, from the same samples
    wide = post.interval("sigma_a", level=0.99)
    narrow = post.interval("sigma_a")
    assert np.all(wide[:, 0] < narrow[:, 0]) and np.all(wide[:, 1] > narrow[:, 1])


def test_log_posterior_is_the_gaussian_likelihood_of_the_noise_model():
    """The sampled density equals Σ log N(y | R(θ), s(R(θ))) from scipy, up to the constant F/2 ln 2π."""
    from facestats.analysis.posterior.likelihood import LogPosterior as _LogPosterior

    rng = np.random.default_rng(9)
    measured, *_ = simulate(2, rng)
    measured[[3, 4], 1] = np.nan
    mask = np.isfinite(measured)
    lo, hi = np.log([0.01, 1e-5]), np.log([100.0, 10.0])
    post = _LogPosterior(R, measured, None, mask, SENSOR, 1.38, lo, hi)
    theta = np.log(rng.uniform([0.5, 0.01, 0.5, 0.01], [3.0, 0.5, 3.0, 0.5], size=(6, 4)))
    theta[5, 3] = np.log(20.0)  # σa above its prior bound
    got = post.blocks(theta)
    for i in range(6):
        for k in range(2):
            s, a = np.exp(theta[i, 2 * k : 2 * k + 2])
            mu = dipole.dipole_profile(R, s, a)
            m = mask[:, k]
            want = stats.norm.logpdf(measured[m, k], mu[m], SENSOR.profile_std(mu)[m]).sum() + 0.5 * m.sum() * np.log(
                2 * np.pi
            )
            if i == 5 and k == 1:
                assert got[i, k] == -np.inf
            else:
                assert got[i, k] == pytest.approx(want, rel=1e-12, abs=1e-9)
    np.testing.assert_allclose(post(theta)[:5, 0], got[:5].sum(1))


def test_missing_fibres_short_chains_and_validation():
    rng = np.random.default_rng(5)
    measured, _, sp, sa, _ = simulate(1, rng)
    holed = measured.copy()
    holed[[0, 5, 9], 0] = np.nan  # clipped fibres are left out
    post = sigma_posterior(R, holed[:, 0], seed=1)
    assert post.labels == ("0",)
    assert abs(post.median("sigma_a")[0] - sa[0]) < 4 * post.summary.loc[("0", "sigma_a"), "std"]
    with pytest.warns(ConvergenceWarning, match="autocorrelation times"):
        short = sigma_posterior(R, measured, initial_steps=50, max_steps=50)
    assert not short.converged
    with pytest.raises(ValidationError, match="shape"):
        sigma_posterior(R[:-1], measured)
    with pytest.raises(ValidationError, match="at least 3 valid fibres"):
        sigma_posterior(R, np.full(R.shape, np.nan))
    with pytest.raises(ValidationError, match="std"):
        sigma_posterior(R, measured, -np.ones_like(measured))
    with pytest.raises(ValidationError, match="n_walkers"):
        sigma_posterior(R, measured, n_walkers=7)
    with pytest.raises(ValidationError, match="bounds"):
        sigma_posterior(R, measured, bounds={"sigma_a": (1.0, 0.1)})
    with pytest.raises(ValidationError, match=r"bounds\['sigma_a'\] \(low, high\) must have shape"):
        sigma_posterior(R, measured, bounds={"sigma_a": (0.1,)})
    with pytest.raises(ValidationError, match=r"bounds\['sigma_a'\] must be numeric"):
        sigma_posterior(R, measured, bounds={"sigma_a": ("low", "high")})


def test_interval_and_median_refuse_a_bad_level_or_parameter_by_name():
    """level 1.5 gave quantiles (-0.25, 1.25) (numpy's bare ValueError); an unknown parameter was pandas' KeyError."""
    measured, *_ = simulate(1, np.random.default_rng(5))
    with pytest.warns(ConvergenceWarning):
        post = sigma_posterior(R, measured[:, 0], initial_steps=50, max_steps=50)
    assert post.interval("sigma_a", level=0.5).shape == (1, 2)
    for bad in (0, 1, 1.5, -0.2, np.nan, "0.9", [0.9]):
        with pytest.raises(ValidationError, match="level"):
            post.interval("sigma_a", level=bad)
    with pytest.raises(ValidationError, match=r"level must lie in \(0, 1\).*got 1.5"):
        post.interval("sigma_a", level=1.5)
    with pytest.raises(ValidationError, match=r"parameter must be one of .*'sigma_tr'.*got 'sigma_s'"):
        post.interval("sigma_s")
    with pytest.raises(ValidationError, match=r"parameter must be one of .*got 'albedo'"):
        post.median("albedo")


def test_site_posterior_of_a_stored_subject():
    store = make_population(n=3, conditions=False)
    ds = store.subject("S001")
    post = site_sigma_posterior(ds, "forehead", std="stored", seed=2)
    truth_s = ds["site_sigma_s_prime"].sel(site="forehead").values
    truth_a = ds["site_sigma_a"].sel(site="forehead").values
    for c, ch in enumerate("RGB"):
        row_s, row_a = post.summary.loc[(ch, "sigma_s_prime")], post.summary.loc[(ch, "sigma_a")]
        assert abs(row_s["median"] - truth_s[c]) < row_s["std"]  # the stored profile is noise-free
        assert abs(row_a["median"] - truth_a[c]) < row_a["std"]
    with pytest.raises(ValidationError, match="site"):
        site_sigma_posterior(ds, "elbow")


def _groups(rng, sizes=(14, 67, 48, 15, 5), means=(0.52, 0.55, 0.57, 0.60, 0.66), sd=0.12):
    return [m + sd * rng.standard_normal(n) for n, m in zip(sizes, means)]


def _frame(groups):
    import pandas as pd

    rows = []
    for st, g in zip(range(2, 7), groups):
        for i, v in enumerate(g):
            row = {"subject_id": f"{st}-{i}", "age": 30, "gender": "M", "skin_type": st, "condition": "normal"}
            for ch, f in zip("RGB", (1.0, 1.8, 2.8)):
                row[f"site_sigma_tr_cheek_{ch}"] = row[f"site_sigma_tr_forehead_{ch}"] = v * f
            rows.append(row)
    return pd.DataFrame(rows).set_index("subject_id")


def test_population_independent_model_is_student_t():
    groups = _groups(np.random.default_rng(3))
    res = population_sigma_tr(_frame(groups), model="independent", n_draws=40000, seed=1)
    for st, g in zip(range(2, 7), groups):
        lo, hi = stats.t.interval(0.9, g.size - 1, loc=g.mean(), scale=g.std(ddof=1) / np.sqrt(g.size))
        row = res.summary.loc[(st, "R")]
        assert row["n"] == g.size and row["sample_mean"] == pytest.approx(g.mean())
        assert row["lo"] == pytest.approx(lo, abs=0.03 * (hi - lo))
        assert row["hi"] == pytest.approx(hi, abs=0.03 * (hi - lo))
    assert res.hyper is None


def test_population_hierarchical_model_against_mcmc_of_the_full_joint():
    """Closed-form + grid draws agree with emcee on p(θ, μ, log τ | ȳ) (θ not integrated out)."""
    groups = _groups(np.random.default_rng(4))
    res = population_sigma_tr(_frame(groups), n_draws=40000, seed=2)
    n = np.array([g.size for g in groups])
    ybar = np.array([g.mean() for g in groups])
    s_w2 = sum(((g - g.mean()) ** 2).sum() for g in groups) / (n.sum() - len(groups))
    assert res.hyper.loc["R", "sigma_w"] == pytest.approx(np.sqrt(s_w2), rel=1e-10)
    var = s_w2 / n

    def log_prob(p):
        theta, mu, log_tau = p[:, :5], p[:, 5], p[:, 6]
        tau = np.exp(log_tau)
        lp = -0.5 * np.sum((ybar - theta) ** 2 / var, axis=1)
        lp += -0.5 * np.sum((theta - mu[:, None]) ** 2, axis=1) / tau**2 - 5 * log_tau
        return lp + log_tau  # flat prior on τ: Jacobian of τ = exp(log τ)

    rng = np.random.default_rng(0)
    start = np.c_[
        ybar + 0.01 * rng.standard_normal((48, 5)),
        ybar.mean() + 0.01 * rng.standard_normal(48),
        np.log(0.05) + 0.1 * rng.standard_normal(48),
    ]
    sampler = emcee.EnsembleSampler(48, 7, log_prob, vectorize=True)
    sampler.random_state = np.random.RandomState(3).get_state()
    sampler.run_mcmc(start, 6000)
    x = sampler.get_chain(discard=1000, flat=True)
    for j, st in enumerate(range(2, 7)):
        q = np.quantile(x[:, j], [0.05, 0.5, 0.95])
        row = res.summary.loc[(st, "R")]
        width = row["hi"] - row["lo"]
        np.testing.assert_allclose([row["lo"], row["median"], row["hi"]], q, atol=0.06 * width)
    # partial pooling: every type's mean is pulled from its sample mean towards the population mean
    mu = res.hyper.loc["R", "mu_median"]
    med = res.summary.xs("R", level="channel")["median"].to_numpy()
    assert np.all(np.abs(med - mu) < np.abs(ybar - mu))
    shrink = 1 - (med - mu) / (ybar - mu)
    assert shrink[4] == shrink.max()  # the 5 subjects of type VI borrow the most


def test_hierarchical_tau_keeps_its_heavy_tail_with_three_types():
    """With a flat prior and J = 3 the posterior of τ falls as τ⁻²: a grid cut at 100 s put the 95 % quantile
    14 % low (a red team). Reference: the same density (BDA3 eq. 5.21) by trapezoid to 10⁸ s, a grid 10⁴ times
    longer than the sampler's, whose missing mass is then about 10⁻⁸."""
    from facestats.analysis.posterior.hierarchical import hierarchical_draws

    ybar, var = np.array([0.55, 0.60, 0.52]), np.array([1e-4, 4e-4, 1e-3])
    scale = float(np.sqrt(np.var(ybar) + np.max(var)))
    t = np.concatenate([[0.0], np.geomspace(1e-4 * scale, 1e8 * scale, 400000)])
    tot = var + t[:, None] ** 2
    v_mu = 1 / np.sum(1 / tot, 1)
    mu_hat = v_mu * np.sum(ybar / tot, 1)
    logp = 0.5 * np.log(v_mu) - 0.5 * np.sum(np.log(tot) + (ybar - mu_hat[:, None]) ** 2 / tot, 1)
    d = np.exp(logp - logp.max())
    cdf = np.concatenate([[0], np.cumsum(0.5 * (d[1:] + d[:-1]) * np.diff(t))])
    want = np.interp([0.05, 0.5, 0.95, 0.99], cdf / cdf[-1], t)
    _, _, tau = hierarchical_draws(ybar, var, 400000, np.random.default_rng(0))
    # Monte Carlo: the 99 % quantile's standard error is about 1.5 % here (density 0.0026 at 3.9)
    got = np.quantile(tau, [0.05, 0.5, 0.95, 0.99])
    assert np.all(np.abs(got / want - 1) <= [0.02, 0.02, 0.02, 0.05]), (got, want)
    assert want[2] > 0.75  # the cut grid gave 0.669
    with pytest.raises(ValidationError, match=">= 3 groups"):
        hierarchical_draws(ybar[:2], var[:2], 10, np.random.default_rng(0))
    with pytest.raises(ValidationError, match="var finite and > 0"):
        hierarchical_draws(ybar, var * 0, 10, np.random.default_rng(0))


def test_hierarchical_model_without_spread_within_types_is_refused_by_name():
    """Every subject of a type alike: a raw numpy error (all alike) or silent NaN summaries (types apart)."""
    alike = [np.full(n, 0.55) for n in (14, 67, 48, 15, 5)]
    apart = [np.full(n, m) for n, m in zip((14, 67, 48, 15, 5), (0.52, 0.55, 0.57, 0.60, 0.66))]
    for groups in (alike, apart):
        with pytest.raises(ValidationError, match="within-type variance of 0 .*independent"):
            population_sigma_tr(_frame(groups), n_draws=100)
        res = population_sigma_tr(_frame(groups), model="independent", n_draws=100)
        np.testing.assert_allclose(res.summary["median"], res.summary["sample_mean"], rtol=1e-12)


def test_population_on_store_and_errors():
    store = make_population(n=40, seed=8)
    res = population_sigma_tr(store, n_draws=4000)
    assert res.skin_types == (2, 3, 4, 5, 6)  # type I grouped with II
    assert "type I-II " in res.to_text() and res.to_dict()["grouped_i_ii"] is True  # not "type II" (a red team)
    assert res.type_label(2) == "I-II" and res.type_label(3) == "III"
    doc = res.to_dict()  # one label everywhere: the JSON said "II" for the pooled group
    assert doc["skin_types"] == ["I-II", "III", "IV", "V", "VI"] and doc["skin_type_numbers"] == [2, 3, 4, 5, 6]
    assert {row["skin_type"] for row in doc["summary"]} == set(doc["skin_types"])
    assert res.draws.shape == (4000, 5, 3) and np.isfinite(res.draws).all()
    frame = select_population(store)
    sig = subject_sigma_tr(frame)
    types = frame["skin_type"].clip(lower=2)
    for st in res.skin_types:
        assert res.summary.loc[(st, "G"), "sample_mean"] == pytest.approx(sig.loc[types == st, "G"].mean())
    assert (res.summary["lo"] < res.summary["hi"]).all()
    two_types = frame[frame["skin_type"].isin([3, 4])]
    with pytest.raises(ValidationError, match="3 skin types"):
        population_sigma_tr(two_types)
    apart = population_sigma_tr(two_types, model="independent", group_i_ii=False)
    assert apart.summary.shape[0] == 6 and apart.type_label(2) == "II" and apart.to_dict()["grouped_i_ii"] is False
    assert apart.to_dict()["skin_types"] == ["III", "IV"]
    with pytest.raises(ValidationError, match="model"):
        population_sigma_tr(store, model="pooled")
