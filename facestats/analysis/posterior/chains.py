"""Running an emcee sampler to convergence and cutting its chain (autocorrelation diagnostics).

* **Convergence**: the integrated autocorrelation time τ of every parameter
  (:func:`emcee.autocorr.integrated_time`) is re-estimated as the chain grows;
  sampling stops once the chain is at least ``min_tau`` τ long for every
  parameter, or at ``max_steps`` (:func:`run_to_convergence`).
* **Burn-in and thinning**: per block of parameters the first ``burn_in`` τ
  steps (of the block's largest τ) are discarded and the chain is thinned by
  ⌊τ/2⌋ (:func:`block_chain`).  The effective sample size is
  n_walkers · (steps − burn-in)/τ.

Sources: the affine-invariant ensemble sampler of Goodman & Weare 2010 (Comm. App. Math. Comp.
Sci. 5(1)) as implemented by emcee (Foreman-Mackey et al. 2013, PASP 125); τ by Sokal's
automatic windowing (Sokal 1997, "Monte Carlo methods in statistical mechanics", §3), as in
:func:`emcee.autocorr.integrated_time`.  A chain of length N then holds about N/τ independent
samples per walker (Sokal 1997 §3), hence the effective sample size above.  The rules "at least
``min_tau`` τ long", "burn-in of a few τ" and "thin by about τ/2" follow emcee's documentation
(autocorrelation analysis); they are conventions, not derived bounds.
"""

from __future__ import annotations

import emcee
import numpy as np

__all__ = ["run_to_convergence", "block_chain"]


def run_to_convergence(sampler, start, n_blocks, block_dim, min_tau, max_steps, initial_steps):
    """Run ``sampler`` from ``start`` until the chain is ``min_tau`` τ long or ``max_steps`` long.

    The chain grows in chunks: ``initial_steps`` first, then to 1.1 times the
    length τ asks for (at least 100 steps more, at most ``max_steps`` in all).

    Parameters
    ----------
    sampler : emcee.EnsembleSampler
        A fresh sampler (no steps yet) over ``n_blocks · block_dim`` parameters; it is advanced in place.
    start : ndarray, shape (n_walkers, n_blocks · block_dim)
        Initial walker positions.
    n_blocks, block_dim : int
        Number of parameter blocks and parameters per block (the shape ``tau`` is reported in).
    min_tau : float
        Required chain length in autocorrelation times (of the largest τ).
    max_steps : int
        Cap on the chain length.
    initial_steps : int
        Steps before the first autocorrelation estimate.

    Returns
    -------
    steps : int
        Chain length.
    tau : ndarray, shape (n_blocks, block_dim)
        Integrated autocorrelation time per parameter (steps; inf where it
        cannot be estimated).
    """
    state, steps, chunk = start, 0, int(initial_steps)
    while True:
        state = sampler.run_mcmc(state, chunk, progress=False, skip_initial_state_check=True)
        steps += chunk
        tau = emcee.autocorr.integrated_time(sampler.get_chain(), tol=0, quiet=True).reshape(n_blocks, block_dim)
        tau = np.where(np.isfinite(tau), tau, np.inf)
        need = min_tau * tau.max()
        if steps >= need or steps >= int(max_steps):
            break
        chunk = int(min(int(max_steps) - steps, max(100, np.ceil(1.1 * need) - steps)))
    return steps, tau


def block_chain(chain, j, tau_j, min_tau, burn_in):
    """Samples of parameter block ``j`` after burn-in and thinning, with its diagnostics.

    Parameters
    ----------
    chain : ndarray, shape (steps, n_walkers, n_blocks · d)
    j : int
        Block index.
    tau_j : ndarray, shape (d,)
        Autocorrelation times of the block's parameters.
    min_tau, burn_in : float
        Required chain length and burn-in, in autocorrelation times.

    Returns
    -------
    samples : ndarray, shape (n, d)
    burn : int
        Steps discarded (half the chain when τ is not finite).
    thin : int
    converged : bool
        Whether the chain is at least ``min_tau`` times the block's largest τ.
    """
    steps, d = chain.shape[0], tau_j.size
    tmax = tau_j.max()
    converged = bool(np.isfinite(tmax) and steps >= min_tau * tmax)
    if np.isfinite(tmax):
        burn = int(np.ceil(burn_in * tmax))
        thin = max(1, int(tmax / 2))
    else:
        burn, thin = steps // 2, 1
    burn = min(burn, steps - 1)
    return chain[burn::thin, :, d * j : d * j + d].reshape(-1, d), burn, thin, converged
