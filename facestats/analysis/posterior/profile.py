"""Posterior of (σ's, σa) of one contact-sensor profile, with σtr and ℓd (Weyrich et al. 2006 §5.4, with uncertainty).

Weyrich et al. fit the dipole of Jensen et al. 2001 to each contact-sensor
profile and report point values of σ's and σa (hence σtr = sqrt(3σa(σa + σ's)),
eq. 15, and ℓd = 1/σtr).  :func:`sigma_posterior` gives their posterior
distributions:

* **Model, likelihood, prior**: :mod:`facestats.analysis.posterior.likelihood`
  (dipole profile, Gaussian noise from the sensor's noise model, log-uniform
  prior; sampling in (ln σ's, ln σa)).
* **Sampler**: emcee's ensemble sampler (Foreman-Mackey et al. 2013) with the
  differential-evolution move (ter Braak 2006; Nelson et al. 2013), evaluated
  with ``vectorize=True``: one numpy call per half-ensemble computes every
  walker *and every channel*.  Channels are independent given their
  parameters, so each channel is an independent 2-parameter block:
  :class:`facestats.analysis.posterior.moves.BlockDEMove` proposes all blocks
  together and accepts or rejects each block on its own log-probability, which
  makes the run exactly one ensemble sampler per channel while sharing the
  likelihood calls.
* **Start**: walkers drawn around a weighted least-squares fit
  (:mod:`facestats.analysis.posterior.start`).
* **Convergence**: :mod:`facestats.analysis.posterior.chains`: sampling stops
  once the chain is at least ``min_tau`` (default 50) autocorrelation times τ
  long for every parameter, or at ``max_steps``, in which case a
  :class:`facestats.errors.ConvergenceWarning` names the unconverged channels.
  Per channel the first ``burn_in`` τ (default 3) steps are discarded and the
  chain is thinned by ⌊τ/2⌋.  Reported: acceptance fraction, τ, effective
  sample size, medians and equal-tailed credible intervals of σ's, σa and the
  derived σtr and ℓd.

:func:`site_sigma_posterior` applies it to one site of a subject Dataset and
:func:`store_sigma_posterior` to a subject of a store;
:class:`SigmaPosterior` holds the result, its JSON document and its summary.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, replace

import emcee
import numpy as np

from facestats.acquire.sensor import ContactSensor
from facestats.analysis.population import default_subject
from facestats.analysis.posterior.chains import block_chain, run_to_convergence
from facestats.analysis.posterior.credible import check_level, interval_quantiles
from facestats.analysis.posterior.likelihood import DERIVED, PARAMETERS, LogPosterior, prior_bounds, validate_profiles
from facestats.analysis.posterior.moves import BlockDEMove
from facestats.analysis.posterior.start import initial_walkers, least_squares_start
from facestats.analysis.serialize import json_ready
from facestats.core.conventions import CHANNELS
from facestats.core.published import ETA_SKIN
from facestats.core.validate import check_choice, check_seed
from facestats.errors import ConvergenceWarning, ValidationError
from facestats.model import dipole

__all__ = ["SigmaPosterior", "sigma_posterior", "site_sigma_posterior", "store_sigma_posterior", "DEFAULT_SITE"]

#: The site :func:`store_sigma_posterior` uses when none is named.
DEFAULT_SITE = "cheek"
#: Parameters of the reported summaries (sampled, then derived).
REPORTED = PARAMETERS + DERIVED
#: Point-fit parameters stored per site in a subject Dataset (``site_{p}``).
STORED_FIT = ("sigma_s_prime", "sigma_a", "sigma_tr")


@dataclass(frozen=True)
class SigmaPosterior:
    """Posterior samples and diagnostics of (σ's, σa) for one or more profiles (channels).

    Attributes
    ----------
    labels : tuple of str
        Channel (or profile) labels.
    samples : dict of str to pandas.DataFrame
        Per label, thinned post-burn-in samples with columns ``sigma_s_prime``,
        ``sigma_a``, ``sigma_tr`` (mm⁻¹) and ``ell_d`` (mm).
    summary : pandas.DataFrame
        Index (label, parameter); columns ``median``, ``mean``, ``std``, ``lo``,
        ``hi`` (equal-tailed credible interval at ``level``).
    diagnostics : pandas.DataFrame
        Per label: ``tau_sigma_s_prime``, ``tau_sigma_a`` (steps), ``acceptance``,
        ``burn_in``, ``thin``, ``n_samples``, ``ess_sigma_s_prime``,
        ``ess_sigma_a``, ``steps_over_tau``, ``converged`` and ``chi2_dof``
        (χ² per degree of freedom at the posterior median: ≈ 1 when the
        dipole and the noise model describe the data; much larger values mean
        a model mismatch, and intervals that are too narrow).
    least_squares : pandas.DataFrame
        The weighted least-squares start per label (``sigma_s_prime``, ``sigma_a``).
    level : float
    n_walkers, n_steps : int
    bounds : dict
    noise : str
        ``"sensor model"`` or ``"explicit std"``.
    seed : int
        Seed of the sampler.
    subject_id, site : str or None
        The subject and site of the profile (:func:`site_sigma_posterior`), else None.
    stored_fit : pandas.DataFrame or None
        :func:`site_sigma_posterior` only: per label the point fit stored with
        the subject (``sigma_s_prime``, ``sigma_a``, ``sigma_tr``; NaN if absent).
    """

    labels: tuple
    samples: dict
    summary: object
    diagnostics: object
    least_squares: object
    level: float
    n_walkers: int
    n_steps: int
    bounds: dict
    noise: str
    seed: int = 0
    subject_id: str | None = None
    site: str | None = None
    stored_fit: object = None

    @property
    def converged(self) -> bool:
        """True if every channel's chain is at least ``min_tau`` autocorrelation times long."""
        return bool(self.diagnostics["converged"].all())

    def median(self, parameter) -> np.ndarray:
        """Posterior median of a parameter per label.

        Parameters
        ----------
        parameter : str
            ``"sigma_s_prime"``, ``"sigma_a"``, ``"sigma_tr"`` (mm⁻¹) or ``"ell_d"`` (mm).

        Returns
        -------
        numpy.ndarray, shape (n_labels,)
            Medians in the order of ``labels``.

        Raises
        ------
        ValidationError
            An unknown ``parameter``.
        """
        check_choice(parameter, "parameter", REPORTED)
        return self.summary.xs(parameter, level="parameter")["median"].loc[list(self.labels)].to_numpy()

    def interval(self, parameter, level=None) -> np.ndarray:
        """Equal-tailed credible interval per label, shape (n_labels, 2) (default: ``self.level``).

        Parameters
        ----------
        parameter : str
            ``"sigma_s_prime"``, ``"sigma_a"``, ``"sigma_tr"`` (mm⁻¹) or ``"ell_d"`` (mm).
        level : float, optional
            Credible level in (0, 1); default the stored intervals at ``self.level``, otherwise quantiles of
            ``samples``.

        Returns
        -------
        numpy.ndarray, shape (n_labels, 2)
            (low, high) per label, in the order of ``labels``.

        Raises
        ------
        ValidationError
            An unknown ``parameter``, or ``level`` not a number in (0, 1).
        """
        check_choice(parameter, "parameter", REPORTED)
        if level is not None:
            level = check_level(level)
        if level is None:
            t = self.summary.xs(parameter, level="parameter").loc[list(self.labels)]
            return t[["lo", "hi"]].to_numpy()
        q = [(1 - level) / 2, (1 + level) / 2]
        return np.array([np.quantile(self.samples[lab][parameter].to_numpy(), q) for lab in self.labels])

    def channel_diagnostics(self):
        """Per label the condensed diagnostics: the worse of the two parameters where they differ.

        Returns
        -------
        pandas.DataFrame
            Index ``label``; columns ``tau`` (the larger τ), ``acceptance``,
            ``ess`` (the smaller effective sample size), ``steps_over_tau``,
            ``chi2_dof``, ``converged``.
        """
        import pandas as pd

        rows = []
        for lab in self.labels:
            d = self.diagnostics.loc[lab]
            rows.append(
                {
                    "label": lab,
                    "tau": max(d["tau_sigma_s_prime"], d["tau_sigma_a"]),
                    "acceptance": d["acceptance"],
                    "ess": min(d["ess_sigma_s_prime"], d["ess_sigma_a"]),
                    "steps_over_tau": d["steps_over_tau"],
                    "chi2_dof": d["chi2_dof"],
                    "converged": bool(d["converged"]),
                }
            )
        return pd.DataFrame.from_records(rows).set_index("label")

    def compare_published(self):
        """Posterior medians and credible intervals beside the point fit stored with the subject.

        The paper reports point fits of each profile; the store holds ours
        (:func:`site_sigma_posterior` results only, else NaN).

        Returns
        -------
        pandas.DataFrame
            Index (``label``, ``parameter``) for σ's, σa, σtr and ℓd; columns
            ``median``, ``lo``, ``hi`` and ``stored_fit`` (NaN for ℓd and where
            absent).
        """
        table = self.summary.loc[[(lab, p) for lab in self.labels for p in REPORTED], ["median", "lo", "hi"]]
        stored = [
            np.nan if self.stored_fit is None or p not in STORED_FIT else float(self.stored_fit.loc[lab, p])
            for lab, p in table.index
        ]
        return table.assign(stored_fit=stored)

    def to_dict(self) -> dict:
        """The JSON document of the posterior (``facestats analyze posterior`` writes it as ``posterior.json``).

        Keys (conventions: :mod:`facestats.analysis.serialize`): ``subject_id``,
        ``site``, ``seed``, ``noise``, ``level``, ``n_walkers``, ``n_steps``,
        ``converged``; ``channels``: by channel ``{sigma_s_prime, sigma_a,
        sigma_tr, ell_d: {median, mean, std, lo, hi}, diagnostics: {tau,
        acceptance, ess, steps_over_tau, chi2_dof, converged}, least_squares:
        {sigma_s_prime, sigma_a}, stored_fit: {sigma_s_prime, sigma_a,
        sigma_tr}}`` (``diagnostics``: :meth:`channel_diagnostics`;
        ``stored_fit``: the point fit in the store, ``null`` if absent).
        """
        diag = self.channel_diagnostics()
        channels = {}
        for lab in self.labels:
            entry = {p: self.summary.loc[(lab, p)].to_dict() for p in REPORTED}
            entry["diagnostics"] = diag.loc[lab].to_dict()
            entry["diagnostics"]["converged"] = bool(diag.loc[lab, "converged"])
            entry["least_squares"] = self.least_squares.loc[lab].to_dict()
            entry["stored_fit"] = None if self.stored_fit is None else self.stored_fit.loc[lab].to_dict()
            channels[lab] = entry
        doc = {
            "subject_id": self.subject_id,
            "site": self.site,
            "seed": self.seed,
            "noise": self.noise,
            "level": self.level,
            "n_walkers": self.n_walkers,
            "n_steps": self.n_steps,
            "converged": self.converged,
            "channels": channels,
        }
        return json_ready(doc)

    def to_text(self) -> str:
        """Medians and intervals per channel, diagnostics and the stored fit (``facestats analyze posterior``)."""
        what = "the profile" if self.subject_id is None else f"{self.subject_id}, {self.site} profile"
        lines = [
            f"Posterior of (sigma_s_prime, sigma_a) of {what} (Weyrich §5.4 with uncertainty): "
            f"median [{self.level:.0%} interval]",
            f"{'ch':<3}{'sigma_s_prime (1/mm)':>28}{'sigma_a (1/mm)':>28}{'sigma_tr (1/mm)':>28}{'l_d (mm)':>28}",
        ]
        for lab in self.labels:
            cells = []
            for p in REPORTED:
                s = self.summary.loc[(lab, p)]
                cells.append(f"{s['median']:#.4g} [{s['lo']:#.4g}, {s['hi']:#.4g}]".rjust(28))
            lines.append(f"{lab:<3}" + "".join(cells))
        diag = self.channel_diagnostics()
        lines.append(
            f"{self.n_steps} steps x {self.n_walkers} walkers; "
            + ", ".join(f"{lab}: tau {d['tau']:.1f}, chi2/dof {d['chi2_dof']:.2f}" for lab, d in diag.iterrows())
            + ("" if self.converged else "  (NOT CONVERGED)")
        )
        if self.stored_fit is not None and np.isfinite(self.stored_fit["sigma_tr"].to_numpy()).all():
            lines.append("stored point fit sigma_tr: " + " ".join(f"{v:.4g}" for v in self.stored_fit["sigma_tr"]))
        return "\n".join(lines)


def _check_labels(labels, k):
    """K labels as str (default R, G, B for three columns, else 0..K−1)."""
    if labels is None:
        labels = CHANNELS if k == 3 else tuple(str(i) for i in range(k))
    labels = tuple(str(lab) for lab in labels)
    if len(labels) != k:
        raise ValidationError(f"labels must have {k} entries (one per profile column), got {len(labels)}")
    return labels


def _check_walkers(n_walkers):
    """Raise unless ``n_walkers`` is even and at least 8."""
    if int(n_walkers) < 8 or int(n_walkers) % 2:
        raise ValidationError(f"n_walkers must be an even number >= 8, got {n_walkers!r}")


def _check_run_length(min_tau, burn_in, initial_steps, max_steps):
    """Raise unless min_tau > 0, burn_in >= 0, initial_steps >= 50 and max_steps >= initial_steps."""
    if min_tau <= 0 or burn_in < 0 or int(max_steps) < int(initial_steps) or int(initial_steps) < 50:
        raise ValidationError(
            f"need min_tau > 0, burn_in >= 0, initial_steps >= 50 and max_steps >= initial_steps, got "
            f"{min_tau}, {burn_in}, {initial_steps}, {max_steps}"
        )


def _summary_rows(lab, frame, q):
    """Median, mean, std and interval of every reported parameter of one label's samples."""
    rows = []
    for name in REPORTED:
        v = frame[name].to_numpy()
        lo_q, med, hi_q = np.quantile(v, q)
        rows.append(
            {
                "label": lab,
                "parameter": name,
                "median": med,
                "mean": v.mean(),
                "std": v.std(ddof=1),
                "lo": lo_q,
                "hi": hi_q,
            }
        )
    return rows


def _summarise_chain(chain, tau, steps, labels, acceptance, n_walkers, q, min_tau, burn_in):
    """Per label: samples with σtr and ℓd, summary rows, diagnostics rows, and the log posterior medians."""
    import pandas as pd

    samples, summary_rows, diag_rows = {}, [], []
    medians = np.empty((len(labels), 2))
    for j, lab in enumerate(labels):
        tau_j = tau[j]
        x, burn, thin, converged = block_chain(chain, j, tau_j, min_tau, burn_in)
        x = np.exp(x)
        sig_tr = dipole.transport_coefficient(x[:, 1], x[:, 0])  # σtr = sqrt(3σa(σa + σ's)), eq. 15; ℓd = 1/σtr
        frame = pd.DataFrame(
            {
                "sigma_s_prime": x[:, 0],
                "sigma_a": x[:, 1],
                "sigma_tr": sig_tr,
                "ell_d": dipole.diffuse_mean_free_path(sig_tr),
            }
        )
        samples[lab] = frame
        summary_rows += _summary_rows(lab, frame, q)
        n_after = (steps - burn) * int(n_walkers)
        medians[j] = np.log(np.median(x, axis=0))
        diag_rows.append(
            {
                "label": lab,
                "tau_sigma_s_prime": tau_j[0],
                "tau_sigma_a": tau_j[1],
                "acceptance": acceptance[j],
                "burn_in": burn,
                "thin": thin,
                "n_samples": len(frame),
                "ess_sigma_s_prime": n_after / tau_j[0],
                "ess_sigma_a": n_after / tau_j[1],
                "steps_over_tau": steps / tau_j.max(),
                "converged": converged,
            }
        )
    summary = pd.DataFrame.from_records(summary_rows).set_index(["label", "parameter"])
    return samples, summary, pd.DataFrame.from_records(diag_rows).set_index("label"), medians


def _warn_unconverged(diagnostics, min_tau, steps):
    """ConvergenceWarning for chains shorter than ``min_tau`` τ or with acceptance below 0.05 (for the caller)."""
    bad = diagnostics.index[~diagnostics["converged"]].tolist()
    if bad:
        warnings.warn(
            f"sigma_posterior: chains of {bad} are shorter than {min_tau:g} autocorrelation times after {steps} steps "
            f"(steps/tau = {diagnostics.loc[bad, 'steps_over_tau'].round(1).tolist()}); raise max_steps, and treat "
            "their intervals as unreliable",
            ConvergenceWarning,
            stacklevel=3,
        )
    low_acc = diagnostics.index[diagnostics["acceptance"] < 0.05].tolist()
    if low_acc:
        warnings.warn(
            f"sigma_posterior: acceptance fraction below 0.05 for {low_acc}; the chains hardly move",
            ConvergenceWarning,
            stacklevel=3,
        )


def sigma_posterior(
    r,
    profile,
    std=None,
    *,
    sensor=None,
    eta=ETA_SKIN,
    labels=None,
    bounds=None,
    n_walkers=16,
    min_tau=50.0,
    burn_in=3.0,
    max_steps=20000,
    initial_steps=500,
    level=0.9,
    seed=0,
):
    """Posterior of (σ's, σa) per channel of a contact-sensor profile, with σtr and ℓd (Weyrich 2006 §5.4, eq. 15).

    See the module docstring for the model, likelihood (sensor noise model,
    heteroscedastic with its log-determinant), prior (log-uniform), sampler
    (emcee, vectorised, channels as independent blocks) and convergence rules.

    Parameters
    ----------
    r : array_like, shape (F,)
        Fibre distances from the source in mm (``ContactSensor().fiber_distance``).
    profile : array_like, shape (F,) or (F, K)
        Measured R(r) in mm⁻² per channel (K = 3 for R, G, B); NaN marks a
        missing fibre.
    std : array_like, optional
        Standard deviation of ``profile`` (same shape, mm⁻²).  Default: the
        noise model of ``sensor`` evaluated at the model profile.
    sensor : ContactSensor, optional
        Sensor whose :meth:`~facestats.acquire.sensor.ContactSensor.profile_std`
        is the noise model (default ``ContactSensor()``).
    eta : float
        Relative index of refraction (1.38 for skin).
    labels : sequence of str, optional
        Labels of the K columns (default R, G, B for K = 3, else 0..K−1).
    bounds : dict, optional
        Prior bounds in mm⁻¹ overriding :data:`facestats.analysis.posterior.likelihood.DEFAULT_BOUNDS`.
    n_walkers : int
        Walkers (even, ≥ 8).
    min_tau : float
        Required chain length in autocorrelation times (≥ 50 recommended by emcee).
    burn_in : float
        Burn-in in autocorrelation times.
    max_steps : int
        Cap on the chain length; reaching it unconverged warns.
    initial_steps : int
        Steps before the first autocorrelation estimate.
    level : float
        Credible level of the reported intervals (0.9: 5 %-95 %).
    seed : int
        Seed of the sampler.

    Returns
    -------
    SigmaPosterior

    Warns
    -----
    ConvergenceWarning
        If a channel's chain is shorter than ``min_tau`` τ at ``max_steps``, or
        its acceptance fraction is below 0.05.
    """
    import pandas as pd

    r_a, y, s, mask = validate_profiles(r, profile, std)
    k = y.shape[1]
    labels = _check_labels(labels, k)
    _check_walkers(n_walkers)
    level = check_level(level)
    _check_run_length(min_tau, burn_in, initial_steps, max_steps)
    sensor = ContactSensor() if sensor is None else sensor
    b = prior_bounds(bounds)
    lo = np.log([b[p][0] for p in PARAMETERS])
    hi = np.log([b[p][1] for p in PARAMETERS])
    post = LogPosterior(r_a, y, s, mask, sensor, float(eta), lo, hi)
    std_fixed = s if s is not None else np.where(mask, sensor.profile_std(np.maximum(np.nan_to_num(y), 0.0)), 1.0)
    theta_ls, cov_ls = least_squares_start(post, np.where(mask, y, 0.0), std_fixed, mask)
    rng = np.random.default_rng(check_seed(seed))
    p0 = initial_walkers(post, theta_ls, cov_ls, int(n_walkers), rng)

    move = BlockDEMove(k, 2)
    sampler = emcee.EnsembleSampler(int(n_walkers), 2 * k, post, vectorize=True, moves=[move])
    sampler.random_state = np.random.RandomState(int(rng.integers(2**31 - 1))).get_state()
    steps, tau = run_to_convergence(sampler, p0, k, 2, min_tau, max_steps, initial_steps)

    chain = sampler.get_chain()  # (steps, walkers, 2K) in ln σ
    acceptance = move.accepted.mean(axis=0) / move.n_proposals
    q = interval_quantiles(level)
    samples, summary, diagnostics, medians = _summarise_chain(
        chain, tau, steps, labels, acceptance, n_walkers, q, min_tau, burn_in
    )
    diagnostics["chi2_dof"] = post.chi2(medians.reshape(1, -1))[0] / np.maximum(mask.sum(axis=0) - 2, 1)
    _warn_unconverged(diagnostics, min_tau, steps)
    ls = pd.DataFrame(np.exp(theta_ls), index=pd.Index(labels, name="label"), columns=list(PARAMETERS))
    return SigmaPosterior(
        labels,
        samples,
        summary,
        diagnostics,
        ls,
        float(level),
        int(n_walkers),
        int(steps),
        b,
        "sensor model" if s is None else "explicit std",
        seed=seed,
    )


def sensor_of(ds):
    """The ContactSensor recorded with a subject's sensor data, if any (else None)."""
    for attrs in (ds["sensor_profile"].attrs, ds.attrs):
        val = attrs.get("sensor")
        if val is None and "provenance" in attrs:
            try:
                val = json.loads(attrs["provenance"]).get("sensor") if isinstance(attrs["provenance"], str) else None
            except ValueError:
                val = None
        if isinstance(val, str):
            try:
                val = json.loads(val)
            except ValueError:
                val = None
        if isinstance(val, dict) and "fiber_distance_mm" in val:
            return ContactSensor.from_attrs(val)
    return None


def site_sigma_posterior(dataset, site, *, std="model", sensor=None, **kwargs):
    """:func:`sigma_posterior` of one measurement site of a subject Dataset (``store.subject(id)``).

    Parameters
    ----------
    dataset : xarray.Dataset
        A subject with ``sensor_profile`` (and ``sensor_profile_std``) on
        (site, fiber, channel) and the ``fiber_distance`` coordinate (mm).
    site : {"cheek", "forehead", "neck"}
    std : {"model", "stored"}
        ``"model"``: the sensor noise model at the model profile (default);
        ``"stored"``: the stored ``sensor_profile_std``.
    sensor : ContactSensor, optional
        Default: the sensor recorded with the data (``sensor`` attribute or
        provenance entry), else ``ContactSensor()``.
    **kwargs
        Passed to :func:`sigma_posterior`.

    Returns
    -------
    SigmaPosterior
        With ``subject_id``, ``site`` and ``stored_fit`` (the point fit of the
        profile stored with the subject).
    """
    check_choice(std, "std", ("model", "stored"))
    if "sensor_profile" not in dataset.data_vars:
        raise ValidationError(f"subject {dataset.attrs.get('subject_id', '?')!r} has no sensor_profile")
    sites = [str(x) for x in dataset["site"].values]
    check_choice(site, "site", sites)
    prof = dataset["sensor_profile"].sel(site=site).transpose("fiber", "channel")
    r = np.asarray(dataset["fiber_distance"].values, dtype=np.float64)
    s = None
    if std == "stored":
        s = dataset["sensor_profile_std"].sel(site=site).transpose("fiber", "channel").values
    sensor = sensor or sensor_of(dataset) or ContactSensor()
    labels = tuple(str(c) for c in prof["channel"].values)
    post = sigma_posterior(r, prof.values, s, sensor=sensor, labels=labels, **kwargs)
    subject_id = dataset.attrs.get("subject_id")
    return replace(
        post,
        subject_id=None if subject_id is None else str(subject_id),
        site=site,
        stored_fit=_stored_fit(dataset, site, labels),
    )


def _stored_fit(dataset, site, labels):
    """The point fit stored with the subject at ``site`` per label (NaN where a variable is absent)."""
    import pandas as pd

    stored = {}
    for p in STORED_FIT:
        var = f"site_{p}"
        stored[p] = dataset[var].sel(site=site).values if var in dataset.data_vars else np.full(len(labels), np.nan)
    return pd.DataFrame(stored, index=pd.Index(labels, name="label"))


def store_sigma_posterior(store, subject_id=None, site=None, **kwargs):
    """:func:`site_sigma_posterior` of a subject of a store (the default subject and site when not named).

    Parameters
    ----------
    store : parameter store
    subject_id : str, optional
        Default: :func:`facestats.analysis.population.default_subject` (the
        first subject measured under normal conditions).
    site : {"cheek", "forehead", "neck"}, optional
        Default :data:`DEFAULT_SITE` (cheek).
    **kwargs
        Passed to :func:`site_sigma_posterior` (``std``, ``seed``, ...).

    Returns
    -------
    SigmaPosterior
    """

    sid = subject_id or default_subject(store)
    return site_sigma_posterior(store.subject(sid), site or DEFAULT_SITE, **kwargs)
