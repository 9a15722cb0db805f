"""Dipole fits of contact-sensor profiles (:func:`facestats.model.fitting.fit_translucency`)."""

import numpy as np

from facestats.model.dipole import dipole_profile
from facestats.model.fitting import fit_translucency

R_MM = np.linspace(0.3, 6.0, 16)


def _profiles(rng, n):
    """n noisy profiles of known (σ's, σa) in skin's range, with a 2 % + floor noise model."""
    sp = rng.uniform(0.8, 3.0, n)
    sa = rng.uniform(0.005, 0.3, n)
    clean = dipole_profile(R_MM[None, :], sp[:, None], sa[:, None])
    std = 0.02 * clean + 1e-6
    return sp, sa, clean + std * rng.standard_normal(clean.shape), std


def test_noisy_profiles_give_back_their_coefficients(rng):
    sp, sa, prof, std = _profiles(rng, 60)
    fit = fit_translucency(R_MM, prof, std)
    tr = np.sqrt(3 * sa * (sa + sp))
    # σtr is what the profile's decay pins down; its error bar covers the truth for most profiles
    assert np.median(np.abs(fit.sigma_tr / tr - 1)) < 0.02
    assert np.mean(np.abs(fit.sigma_tr - tr) <= 3 * fit.sigma_tr_std) >= 0.9
    assert np.median(np.abs(fit.sigma_s_prime / sp - 1)) < 0.1


def test_a_profile_s_fit_does_not_depend_on_the_profiles_fitted_with_it(rng):
    """Each profile stops iterating at its own convergence: one call for many subjects (the build's
    ``sensor_fits``) gives, bit for bit, what one call per profile gives."""
    _, _, prof, std = _profiles(rng, 24)
    together = fit_translucency(R_MM, prof, std)
    for i in range(0, 24, 5):
        alone = fit_translucency(R_MM, prof[i : i + 1], std[i : i + 1])
        for name, value in vars(alone).items():
            np.testing.assert_array_equal(value[0], getattr(together, name)[i], err_msg=name)
