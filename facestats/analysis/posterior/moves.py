"""A differential-evolution emcee move for independent parameter blocks (ter Braak 2006; Nelson et al. 2013).

:class:`BlockDEMove` lets one emcee ensemble sample several independent
posteriors (one per colour channel of a contact-sensor profile) while sharing
their vectorised likelihood calls: each block is accepted or rejected on its
own log-probability, so the joint run is exactly one ensemble sampler per block.
"""

from __future__ import annotations

import emcee
import numpy as np

from facestats.errors import ValidationError

__all__ = ["BlockDEMove"]


class BlockDEMove(emcee.moves.RedBlueMove):
    """Differential-evolution ensemble move on independent parameter blocks.

    The parameter vector holds ``n_blocks`` blocks of ``block_dim`` parameters
    whose posteriors are independent (the log-probability factorises over
    blocks).  As in emcee's ``DEMove`` (ter Braak 2006; Nelson et al. 2013) each
    walker of one half of the ensemble proposes q = x + γ (x_a − x_b), with a
    random pair (a, b) of distinct walkers of the other half and
    γ = γ0 (1 + ε N(0, 1)), γ0 = 2.38/sqrt(2 d) for the block dimension d.  The
    proposal is made for all blocks at once but each block is accepted with
    its own Metropolis ratio, which needs the per-block log-probabilities: the
    log-probability function returns them as emcee "blobs" (shape
    (n_walkers, n_blocks)).  Given the pair and γ, which do not depend on the
    walker's position, every block performs a symmetric Metropolis step that
    leaves its own posterior invariant, so the joint chain is the product of
    ``n_blocks`` independent ensemble samplers.

    Acceptance is counted per walker and block in :attr:`accepted`, over
    :attr:`n_proposals` proposals per walker.

    Parameters
    ----------
    n_blocks : int
        Number of independent blocks (channels).
    block_dim : int
        Parameters per block, d.
    gamma0 : float, optional
        Scale γ0 of the difference vector; default 2.38/sqrt(2 d).
    sigma : float
        Relative jitter ε of γ.
    """

    def __init__(self, n_blocks, block_dim, gamma0=None, sigma=1e-5):
        super().__init__(nsplits=2, randomize_split=True, live_dangerously=True)
        self.n_blocks = int(n_blocks)
        self.block_dim = int(block_dim)
        self.g0 = 2.38 / np.sqrt(2 * self.block_dim) if gamma0 is None else float(gamma0)
        self.sigma = float(sigma)
        self.accepted = None
        self.n_proposals = 0

    def propose(self, model, state):
        """Move every walker once, accepting or rejecting each block on its own log-probability.

        Parameters
        ----------
        model : emcee.model.Model
            The sampler's model (its ``random`` state and ``compute_log_prob_fn``), as emcee passes it.
        state : emcee.State
            Current coordinates (n_walkers, n_blocks · block_dim), log-probabilities and per-block blobs
            (n_walkers, n_blocks); updated in place.

        Returns
        -------
        state : emcee.State
            ``state`` with the new coordinates, log-probabilities and blobs.
        accepted : numpy.ndarray of bool, shape (n_walkers,)
            True for a walker with at least one block accepted.

        Raises
        ------
        ValidationError
            The walkers' dimension is not ``n_blocks · block_dim``.
        """
        nw, ndim = state.coords.shape
        k, d = self.n_blocks, self.block_dim
        if ndim != k * d:
            raise ValidationError(f"BlockDEMove: {ndim} parameters are not {k} blocks of {d}")
        if self.accepted is None:
            self.accepted = np.zeros((nw, k), dtype=np.int64)
        blob_shape = np.shape(state.blobs)
        block_lp = np.asarray(state.blobs, dtype=np.float64).reshape(nw, k)
        inds = np.arange(nw) % self.nsplits
        model.random.shuffle(inds)
        any_accepted = np.zeros(nw, dtype=bool)
        for split in range(self.nsplits):
            sel = inds == split
            s, c = state.coords[sel], state.coords[~sel]
            ns, nc = s.shape[0], c.shape[0]
            i1 = model.random.randint(nc, size=ns)
            i2 = (i1 + 1 + model.random.randint(nc - 1, size=ns)) % nc  # a second, distinct walker
            gamma = self.g0 * (1 + self.sigma * model.random.randn(ns, 1))
            q = s + gamma * (c[i1] - c[i2])
            _, new_blobs = model.compute_log_prob_fn(q)
            new_lp = np.asarray(new_blobs, dtype=np.float64).reshape(ns, k)
            old_lp = block_lp[sel]
            with np.errstate(invalid="ignore"):
                accept = np.log(model.random.rand(ns, k)) < new_lp - old_lp  # NaN (-inf - -inf) rejects
            moved = np.where(accept[..., None], q.reshape(ns, k, d), s.reshape(ns, k, d)).reshape(ns, ndim)
            lp = np.where(accept, new_lp, old_lp)
            state.coords[sel] = moved
            block_lp[sel] = lp
            state.log_prob[sel] = lp.sum(axis=1)
            self.accepted[sel] += accept
            any_accepted[sel] = accept.any(axis=1)
        state.blobs = block_lp.reshape(blob_shape)
        self.n_proposals += 1
        return state, any_accepted
