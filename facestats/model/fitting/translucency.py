"""Stages 6-7 of the fit: the dipole fitted to contact-sensor profiles, and scattering from albedo.

Stage 6 (Weyrich et al. 2006 §5.4): "We fit the analytic BSSRDF model of Jensen et
al. [2001] to the data points of each subsurface measurement, providing us with
the reduced scattering coefficient σ's and absorption coefficient σa", then
σtr = sqrt(3 σa (σa + σ's)) ≈ 1/ℓd (eq. 15).  With the readings' standard
deviations s_k (the sensor's noise model,
:meth:`facestats.acquire.sensor.ContactSensor.profile_std`) the fit is the
Gaussian maximum-likelihood fit

    Σ_k [(R_meas(r_k) − R_d(r_k; σ's, σa)) / s_k]²,

which uses every reading, including those at the noise floor; without them it is
the log-space fit of Suzuki, Mukaigawa & Yagi (eq. 36),
Σ_k [ln R_meas(r_k) − ln R_d(r_k)]², over the positive readings.  (A log-space
fit weighted by relative errors would be biased by readings near the noise
floor, whose logarithm is dominated by noise.)  Non-finite readings are left out.
The cost has a narrow curved valley in (σ's, σa) but is nearly axis-aligned in
(ln σtr, logit α') (σtr sets the decay, α' the level), so the solve is a
Levenberg-Marquardt iteration in those coordinates, vectorised over all profiles
(sites × channels × subjects; each profile stops at its own convergence, so its
result does not depend on the others in the call), with σ's ∈ [0.02, 50] and σa ∈ [10⁻⁴, 20] mm⁻¹.
It starts from the far-field decay rate (the slope of ln R + 2 ln r against r
over the clear readings beyond 1.5 mm): for each of three bands of α' the best
of 18 starts (6 decay rates × 3 levels) is iterated, and the best of the three
results wins.  Standard errors come from (JᵀWJ)⁻¹ in (ln σ's, ln σa) and
propagate to σtr by the delta method.

σtrAvg (§5.4) "is the mean over all subjects of the measurements for the
forehead and cheek, ignoring the neck".

Stage 7 (§5.4): α_avg is the mean of the albedo map; σ's and σa follow from α_avg
and σtrAvg by inverting eq. 16 (:func:`facestats.model.dipole.scattering_from_albedo`);
the modulation texture is M = α/α_avg (eq. 7,
:func:`facestats.model.skin.modulation_texture`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_finite, as_float, check_integer, check_shape
from facestats.errors import ValidationError
from facestats.model.dipole import check_dipole_eta, dipole_profile_unchecked, scattering_from_albedo
from facestats.model.skin import modulation_texture

__all__ = ["TranslucencyFit", "fit_translucency", "population_sigma_tr_avg", "scattering_parameters"]

_BOUNDS = ((0.02, 50.0), (1e-4, 20.0))  # σ's, σa in mm⁻¹


@dataclass
class TranslucencyFit:
    """Dipole parameters fitted to profiles (arrays of the profiles' leading shape).

    Attributes
    ----------
    sigma_s_prime, sigma_a : ndarray
        Reduced scattering and absorption coefficients in mm⁻¹.
    sigma_s_prime_std, sigma_a_std : ndarray
        Their standard errors in mm⁻¹.
    sigma_tr : ndarray
        σtr in mm⁻¹.
    sigma_tr_std : ndarray
        Its standard error in mm⁻¹ (delta method).
    chi2 : ndarray
        The final cost (weighted squared residuals; in ln R without std).
    n_points : ndarray of int
        The readings used per profile.
    at_bound : ndarray of bool or None
        True where the fit ended on a limit of its search (σtr 0.02 or 20 mm⁻¹, α' 0.0067 or
        0.99988, σ's 0.02 or 50 mm⁻¹, σa 1e-4 or 20 mm⁻¹): the data ask for a
        medium outside skin's range, typically distances not in mm or a profile not
        in mm⁻² (e.g. distances in metres gave σ's = 0.02, the lower limit, without a
        word before ``at_bound``).  :func:`fit_translucency` always sets it; None by default.
    """

    sigma_s_prime: np.ndarray
    sigma_a: np.ndarray
    sigma_s_prime_std: np.ndarray
    sigma_a_std: np.ndarray
    sigma_tr: np.ndarray
    sigma_tr_std: np.ndarray
    chi2: np.ndarray
    n_points: np.ndarray
    at_bound: np.ndarray | None = None

    @property
    def ell_d(self):
        """Diffuse mean free path ℓd = 1/σtr, mm."""
        return 1 / self.sigma_tr


def _model(log_s, log_a, r, eta):
    """R_d(r) (mm⁻²) for log-coefficients of the profiles' leading shape, r on a new last axis."""
    return dipole_profile_unchecked(r, np.exp(log_s)[..., None], np.exp(log_a)[..., None], eta)


#: The iteration's coordinates (ln σtr, logit α') are kept in these ranges (module docstring):
#: σtr in [0.02, 20] mm⁻¹, α' in [0.0067, 0.99988].
_LN_SIGMA_TR_RANGE = (np.log(0.02), np.log(20.0))
_LOGIT_ALBEDO_RANGE = (-5.0, 9.0)
#: Central-difference step of the Jacobians.
_H = 1e-6
#: Levels of α' of the three start bands, and the factors on the far-field decay rate.
_START_BANDS = ((0.3, 0.6, 0.8), (0.88, 0.93, 0.96), (0.98, 0.99, 0.997))
_START_FACTORS = (0.5, 0.7, 0.85, 1.0, 1.2, 1.5)


class _Profiles:
    """The least-squares problem of :func:`fit_translucency` on flat profiles (P, F)."""

    def __init__(self, r, p, std, eta):
        self.r, self.p, self.eta = r, p, eta
        use = np.isfinite(p)
        self.linear = std is not None
        if self.linear:  # Gaussian likelihood of R with the readings' std
            use &= np.isfinite(std) & (std > 0)
            self.wgt = np.where(use, 1 / np.where(use, std, 1.0) ** 2, 0)
            self.obs = np.where(use, p, 0.0)
            self.snr_scale = np.where(use, std, np.inf)
        else:  # log-space fit (Suzuki eq. 36)
            use &= p > 0
            self.wgt = use.astype(np.float64)
            self.obs = np.log(np.where(use, p, 1.0))
            self.snr_scale = 1e-3 * np.abs(p) + 1e-300
        self.use = use

    def subset(self, rows):
        """The same problem restricted to the profiles ``rows`` (an index array)."""
        if rows.size == self.p.shape[0]:
            return self
        sub = object.__new__(_Profiles)
        sub.r, sub.eta, sub.linear = self.r, self.eta, self.linear
        for name in ("p", "wgt", "obs", "snr_scale", "use"):
            setattr(sub, name, getattr(self, name)[rows])
        return sub

    def transform(self, x):
        """The observation space: R itself (with std) or ln R."""
        return x if self.linear else np.log(x)

    def predict(self, ls, la):
        """The model in observation space for log-coefficients (ln σ's, ln σa)."""
        return self.transform(_model(ls, la, self.r, self.eta))

    def cost(self, ls, la):
        """(weighted squared error per profile, residuals) at (ln σ's, ln σa)."""
        d = np.where(self.use, self.obs - self.predict(ls, la), 0)
        return np.sum(self.wgt * d * d, axis=-1), d

    @staticmethod
    def to_coeffs(u, v):
        """(ln σ's, ln σa) from (ln σtr, logit α'), clipped to the bounds of σ's and σa."""
        (s_lo, s_hi), (a_lo, a_hi) = _BOUNDS
        tr = np.exp(u)
        al = 1 / (1 + np.exp(-v))
        st = tr / np.sqrt(3 * (1 - al))
        return np.log(np.clip(al * st, s_lo, s_hi)), np.log(np.clip((1 - al) * st, a_lo, a_hi))

    def cost_uv(self, u, v):
        return self.cost(*self.to_coeffs(u, v))

    def far_field_decay(self):
        """σtr estimate per profile: the slope of ln R + 2 ln r against r over the clear readings beyond 1.5 mm.

        Far from the source (r ≫ z_v) both terms of the dipole profile (Jensen et al. 2001; Suzuki
        eq. 3) tend to R_d ≈ α'/(4π) (z_r + z_v) σtr (1 + 1/(σtr r)) e^(−σtr r)/r², so ln R + 2 ln r
        falls with slope −σtr, plus the slowly varying ln(1 + 1/(σtr r)), which makes the slope read
        σtr somewhat low where σtr r is near 1.  Only a starting point for the fit; r in mm, σtr in
        mm⁻¹; 1.0 where fewer than three readings qualify or the slope is not negative.
        """
        p, rr, use = self.p, self.r, self.use
        with np.errstate(invalid="ignore", divide="ignore"):
            snr = np.where(use, p / self.snr_scale, 0)
            tail = use & (p > 0) & (snr > 5) & (rr[None, :] >= 1.5)
            yy = np.where(tail, np.log(np.where(tail, p, 1)) + 2 * np.log(rr)[None, :], 0)
            nt = tail.sum(1)
            mr = np.where(tail, rr, 0).sum(1) / nt
            my = yy.sum(1) / nt
            slope = (np.where(tail, (rr - mr[:, None]) * (yy - my[:, None]), 0)).sum(1) / np.where(
                tail, (rr - mr[:, None]) ** 2, 0
            ).sum(1)
        return np.where((nt >= 3) & (slope < 0), -np.nan_to_num(slope), 1.0)

    def best_start(self, tr0, band):
        """The best of the starts (decay rates around ``tr0`` × the α' levels of ``band``) of each profile."""
        st_lo, st_hi = _LN_SIGMA_TR_RANGE
        n = self.p.shape[0]
        bu = bv = None
        bc = np.full(n, np.inf)
        for f in _START_FACTORS:
            for a0 in band:
                uu = np.clip(np.log(np.maximum(tr0 * f, 1e-3)), st_lo, st_hi)
                vv = np.full(n, np.log(a0 / (1 - a0)))
                c, _ = self.cost_uv(uu, vv)
                better = c < bc
                bc = np.where(better, c, bc)
                bu = uu if bu is None else np.where(better, uu, bu)
                bv = vv if bv is None else np.where(better, vv, bv)
        return bu, bv

    def jacobian_uv(self, u, v):
        """Central-difference derivatives of the model in observation space with respect to u and v."""
        h = _H
        ju = (self.predict(*self.to_coeffs(u + h, v)) - self.predict(*self.to_coeffs(u - h, v))) / (2 * h)
        jv = (self.predict(*self.to_coeffs(u, v + h)) - self.predict(*self.to_coeffs(u, v - h))) / (2 * h)
        return np.where(self.use, ju, 0), np.where(self.use, jv, 0)

    def levenberg_marquardt(self, u, v, max_iter):
        """Levenberg-Marquardt iterations in (ln σtr, logit α'), vectorised over profiles.

        Each profile stops at its own convergence (cost change ≤ 1e-12 relative on an
        accepted step, steps below 1e-10, or damping above 1e10) and is not touched
        after, so its result does not depend on which other profiles share the call:
        fitting many subjects at once gives, bit for bit, what fitting each alone gives.
        """
        (st_lo, st_hi), (al_lo, al_hi) = _LN_SIGMA_TR_RANGE, _LOGIT_ALBEDO_RANGE
        u, v = np.array(u, np.float64), np.array(v, np.float64)
        lam = np.full(u.shape, 1e-2)
        live = np.arange(u.size)  # profiles still iterating
        for _ in range(int(max_iter)):
            sub = self.subset(live)
            uu, vv, ll = u[live], v[live], lam[live]
            c0, d0 = sub.cost_uv(uu, vv)
            ju, jv = sub.jacobian_uv(uu, vv)
            wgt = sub.wgt
            a00, a01, a11 = np.sum(wgt * ju * ju, -1), np.sum(wgt * ju * jv, -1), np.sum(wgt * jv * jv, -1)
            g0, g1 = np.sum(wgt * ju * d0, -1), np.sum(wgt * jv * d0, -1)
            m00, m11 = a00 * (1 + ll) + 1e-300, a11 * (1 + ll) + 1e-300
            det = m00 * m11 - a01 * a01
            with np.errstate(invalid="ignore", divide="ignore"):
                du = np.nan_to_num((m11 * g0 - a01 * g1) / det)
                dv = np.nan_to_num((m00 * g1 - a01 * g0) / det)
            u1, v1 = np.clip(uu + du, st_lo, st_hi), np.clip(vv + dv, al_lo, al_hi)
            c1, _ = sub.cost_uv(u1, v1)
            acc = c1 < c0
            u[live], v[live] = np.where(acc, u1, uu), np.where(acc, v1, vv)
            lam[live] = ll = np.where(acc, ll / 3, ll * 4)
            small = (np.abs(du) < 1e-10) & (np.abs(dv) < 1e-10)
            live = live[~((acc & (np.abs(c0 - c1) <= 1e-12 * (1 + c0))) | small | (ll > 1e10))]
            if live.size == 0:
                break
        return u, v, self.cost_uv(u, v)[0]

    def result(self, u, v) -> TranslucencyFit:
        """Coefficients at (u, v) with standard errors from (JᵀWJ)⁻¹ in (ln σ's, ln σa), σtr by the delta method."""
        h, wgt = _H, self.wgt
        ls, la = self.to_coeffs(u, v)
        c, _ = self.cost(ls, la)
        js = (self.predict(ls + h, la) - self.predict(ls - h, la)) / (2 * h)
        ja = (self.predict(ls, la + h) - self.predict(ls, la - h)) / (2 * h)
        js, ja = np.where(self.use, js, 0), np.where(self.use, ja, 0)
        a00, a01, a11 = np.sum(wgt * js * js, -1), np.sum(wgt * js * ja, -1), np.sum(wgt * ja * ja, -1)
        det = a00 * a11 - a01 * a01
        n = self.use.sum(1)
        with np.errstate(invalid="ignore", divide="ignore"):
            # Without a noise model the weights are 1 in ln R: the residual variance χ²/(n − 2) estimates
            # the readings' variance (fit_translucency's docstring); with one, χ² is already in units of it.
            scale = 1.0 if self.linear else np.where(n > 2, c / (n - 2), np.nan)
            v_ls, v_la, c_sa = scale * a11 / det, scale * a00 / det, -scale * a01 / det  # cov of (ln σ's, ln σa)
        sp, sa = np.exp(ls), np.exp(la)
        tr = np.sqrt(3 * sa * (sa + sp))
        # Delta method: ∂σtr/∂ln σ's = 3 σa σ's/(2σtr), ∂σtr/∂ln σa = 3 σa (2σa + σ's)/(2σtr).
        gs_, ga_ = 3 * sa * sp / (2 * tr), 3 * sa * (2 * sa + sp) / (2 * tr)
        var_tr = gs_ * gs_ * v_ls + ga_ * ga_ * v_la + 2 * gs_ * ga_ * c_sa
        return TranslucencyFit(
            sigma_s_prime=sp,
            sigma_a=sa,
            sigma_s_prime_std=sp * np.sqrt(v_ls),
            sigma_a_std=sa * np.sqrt(v_la),
            sigma_tr=tr,
            sigma_tr_std=np.sqrt(np.maximum(var_tr, 0)),
            chi2=c,
            n_points=n,
        )


def fit_translucency(r, profile, std=None, *, eta=ETA_SKIN, max_iter=60):
    """Fit the dipole (σ's, σa) to diffuse reflectance profiles R(r) (module docstring).

    Parameters
    ----------
    r : array_like, shape (F,)
        Distances from the source, mm.
    profile : array_like, shape (..., F)
        Measured R(r) in mm⁻² (any leading shape: sites, channels, subjects).
    std : array_like, shape (..., F), optional
        Standard deviation of each reading (the sensor's noise model), mm⁻²;
        readings with a non-positive or non-finite std are left out.
    eta : float
        Relative index of refraction, in [1, 3].
    max_iter : int
        Levenberg-Marquardt iterations per start band (≥ 1).

    Returns
    -------
    TranslucencyFit
        Arrays of the leading shape of ``profile``.  Without ``std`` the standard
        errors are those of a least-squares fit in ln R with the readings' variance
        estimated from the fit's own residuals, σ̂² = χ²/(n − 2) (n usable readings,
        2 parameters; NaN for n = 2): absolute errors, as with ``std``, on the
        assumption that every reading has the same relative noise.  Before 2026-12-06
        they took σ̂ = 1 in ln R and came out 49 times the actual spread of σtr over
        300 profiles with 2 % noise (``tests/model/fitting/test_translucency.py``).
    """
    rr = check_shape(as_finite(r, "r", 0, None, unit="mm", dtype=np.float64), "r", (None,))
    p = as_float(profile, "profile", np.float64)
    if p.ndim < 1 or p.shape[-1] != rr.shape[0]:
        raise ValidationError(f"profile must have {rr.shape[0]} distances on its last axis, got shape {p.shape}")
    check_dipole_eta(eta)
    check_integer(max_iter, "max_iter", 1)
    lead = p.shape[:-1]
    s = None
    if std is not None:
        s = as_float(std, "std", np.float64)
        if s.shape != lead + rr.shape:
            raise ValidationError(f"std must have the shape of profile, {lead + rr.shape}, got {s.shape}")
        s = s.reshape(-1, rr.shape[0])
    prob = _Profiles(rr, p.reshape(-1, rr.shape[0]), s, eta)
    if np.any(prob.use.sum(1) < 3):
        raise ValidationError(
            "profile must have at least 3 usable (finite; positive without std) readings per profile "
            "to fit 2 parameters"
        )
    # Starts: decay rates around the far-field estimate × levels of α'; the iteration
    # runs from the best start of each α' band (low, middle, high), the best result wins.
    tr0 = prob.far_field_decay()
    u = v = best = None
    for band in _START_BANDS:  # loop over three start bands, vectorised over profiles
        fu, fv, fc = prob.levenberg_marquardt(*prob.best_start(tr0, band), max_iter)
        if best is None:
            u, v, best = fu, fv, fc
        else:
            better = fc < best
            u, v, best = np.where(better, fu, u), np.where(better, fv, v), np.where(better, fc, best)
    out = prob.result(u, v)
    tol = 1e-6  # the iteration clips its coordinates to the ranges: a fit there ended on a limit
    (s_lo, s_hi), (a_lo, a_hi) = _BOUNDS
    sp, sa = np.asarray(out.sigma_s_prime), np.asarray(out.sigma_a)
    out.at_bound = (
        (u <= _LN_SIGMA_TR_RANGE[0] + tol)
        | (u >= _LN_SIGMA_TR_RANGE[1] - tol)
        | (v <= _LOGIT_ALBEDO_RANGE[0] + tol)
        | (v >= _LOGIT_ALBEDO_RANGE[1] - tol)
        | (sp <= s_lo * (1 + tol))
        | (sp >= s_hi * (1 - tol))
        | (sa <= a_lo * (1 + tol))
        | (sa >= a_hi * (1 - tol))
    )
    for k, val in vars(out).items():
        setattr(out, k, np.asarray(val).reshape(lead))
    return out


def population_sigma_tr_avg(site_sigma_tr, sites, use_sites=("cheek", "forehead")):
    """σtrAvg: mean over subjects of the cheek and forehead σtr, neck excluded (§5.4).

    Parameters
    ----------
    site_sigma_tr : array_like, shape (subjects, sites, 3)
        Fitted σtr per subject, site and channel, mm⁻¹.
    sites : sequence of str
        Names of the site axis.
    use_sites : sequence of str
        Sites that enter the mean (those present in ``sites``).

    Returns
    -------
    ndarray, shape (3,)
        σtrAvg in mm⁻¹, over the subjects whose values at ``use_sites`` are all finite.
    """
    t = as_float(site_sigma_tr, "site_sigma_tr", np.float64)
    sites = list(sites)
    idx = [sites.index(s) for s in use_sites if s in sites]
    if t.ndim != 3 or t.shape[1] != len(sites) or t.shape[-1] != 3 or not idx:
        raise ValidationError(
            f"site_sigma_tr must have shape (subjects, sites, 3) with sites {use_sites}, got {t.shape} and {sites}"
        )
    vals = t[:, idx, :]
    ok = np.all(np.isfinite(vals), axis=(1, 2))
    if not ok.any():
        raise ValidationError(f"site_sigma_tr has no subject with finite values at the sites {[sites[i] for i in idx]}")
    return vals[ok].mean(axis=(0, 1))


def scattering_parameters(albedo, mask, sigma_tr_avg, eta=ETA_SKIN):
    """Stage 7: α_avg, (σ's, σa) from α_avg and σtrAvg (§5.4), and the modulation texture M (eq. 7).

    Parameters
    ----------
    albedo : array_like, shape (..., 3)
        Albedo map, in [0, 1].
    mask : array_like of bool
        Face texels (shape of ``albedo`` without the channel axis).
    sigma_tr_avg : array_like, shape (3,)
        The population's σtrAvg, mm⁻¹ (> 0).
    eta : float
        Relative index of refraction.

    Returns
    -------
    albedo_avg : ndarray, shape (3,)
    sigma_s_prime, sigma_a : ndarray, shape (3,)
        mm⁻¹ (inverse of Weyrich eq. 16, :func:`facestats.model.dipole.scattering_from_albedo`).
    modulation : ndarray, shape of ``albedo``
    """
    check_shape(np.asarray(sigma_tr_avg), "sigma_tr_avg", (3,))
    mod, avg = modulation_texture(albedo, mask)
    sp, sa = scattering_from_albedo(avg.astype(np.float64), np.asarray(sigma_tr_avg, np.float64), eta)
    return avg, sp, sa, mod
