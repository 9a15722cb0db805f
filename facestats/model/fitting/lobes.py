"""The specular lobes of the batch fit as ρs times a lobe, and their per-texel sums (Weyrich et al. 2006 eq. 11-14).

Both models are ρs times a lobe: f_sM cos θi = ρs · g(p), with g = s(p) u and
u = A e^{c z} for per-sample parameter-free factors (A, z) of
:func:`facestats.model.fitting.specular.specular_factors`:

* Torrance-Sparrow (eq. 12-13): s = 1/m², c = −1/m², z = tan²δ,
  A = K cos θi / cos⁴δ;
* Blinn-Phong (eq. 11): s = n + 2, c = n, z = ln cos δ, A = cos θi / (2π).

Samples are flat arrays in which every texel's samples form one contiguous run;
per-texel sums are ``np.add.reduceat`` over the runs (pairwise float32 sums,
accumulated per texel in float64).  One exponential and five products per
sample give everything a Gauss-Newton step and E(p) need.
"""

from __future__ import annotations

import numpy as np

__all__ = ["lobe_rate", "lobe_base", "lobe_sums", "lobe_moments", "lobe_scale"]

# The functions here run inside the fit's iterations and do not check their ``model`` (any value other than
# ``"torrance_sparrow"`` is read as ``"blinn_phong"``); the entry points that call them
# (:func:`facestats.model.fitting.solver.solve_specular`, :mod:`facestats.model.fitting.uncertainty`) check it
# against :data:`facestats.model.skin.SPECULAR_MODELS`.


def lobe_rate(model, p):
    """Per-texel rate c of the lobe's exponential u = A e^{c z}: −1/m² (TS, z = tan²δ) or n (BP, z = ln cos δ).

    Parameters
    ----------
    model : str
        ``"torrance_sparrow"``; any other value is read as ``"blinn_phong"``.
    p : float or ndarray
        Lobe parameter per texel: roughness m (TS) or exponent n (BP), not its logarithm.

    Returns
    -------
    float or ndarray
        c, shape of ``p``.
    """
    return -1 / (p * p) if model == "torrance_sparrow" else p


def lobe_base(model, q, counts, z, a, out=None):
    """Per-sample u = A e^{c z} for per-texel q = ln p repeated ``counts`` times (one exponential per sample).

    The lobe is g = s(p) u with s = 1/m² (TS: g = A e^{−t/m²}/m²) or n + 2
    (BP: g = A (n+2) cosⁿδ); see :func:`lobe_moments`.

    Parameters
    ----------
    model : str
        ``"torrance_sparrow"``; any other value is read as ``"blinn_phong"``.
    q : array_like, shape (k,)
        ln p per texel (ln m or ln n).
    counts : ndarray of int, shape (k,)
        Samples per texel (their runs are consecutive); they sum to S.
    z, a : ndarray, shape (S,)
        Per-sample abscissa z (tan²δ or ln cos δ) and factor A; ``z``'s float dtype is the computation's.
    out : ndarray, shape (S,), optional
        Buffer of ``z``'s dtype to write u into.

    Returns
    -------
    ndarray, shape (S,)
        u, in ``z``'s dtype (``out`` when given).
    """
    u = np.multiply(z, np.repeat(lobe_rate(model, np.exp(np.asarray(q, np.float64))).astype(z.dtype), counts), out=out)
    np.exp(u, out=u)
    u *= a
    return u


def lobe_sums(model, q, counts, starts, z, a, y, scratch):
    """Per-texel Σ y u, Σ y u z, Σ u², Σ u² z, Σ u² z² (float64) over runs of samples, for q = ln p.

    One exponential and five products per sample: everything the Gauss-Newton
    step and E(p) need (:func:`lobe_moments`); float32 sums are pairwise.

    Parameters
    ----------
    model : str
        ``"torrance_sparrow"``; any other value is read as ``"blinn_phong"``.
    q : array_like, shape (k,)
        ln p per texel.
    counts, starts : ndarray of int, shape (k,)
        Length and offset of each texel's run of samples (runs consecutive and non-empty: ``np.add.reduceat``).
    z, a : ndarray, shape (S,)
        Per-sample abscissa and factor A, as :func:`lobe_base`.
    y : ndarray, shape (S,)
        Per-sample observations (grey specular f_s cos θi).
    scratch : ndarray, shape (3, S)
        Work buffers of ``z``'s dtype, overwritten.

    Returns
    -------
    s_yu, s_yuz, s_uu, s_uuz, s_uuzz : ndarray of float64, shape (k,)
    """
    u = lobe_base(model, q, counts, z, a, out=scratch[0])
    yu = np.multiply(y, u, out=scratch[1])
    uu = np.multiply(u, u, out=scratch[2])

    def rsum(x):
        return np.add.reduceat(x, starts).astype(np.float64)

    s_yu, s_uu = rsum(yu), rsum(uu)
    s_yuz = rsum(np.multiply(yu, z, out=yu))
    s_uuz = rsum(np.multiply(uu, z, out=uu))
    s_uuzz = rsum(np.multiply(uu, z, out=uu))
    return s_yu, s_yuz, s_uu, s_uuz, s_uuzz


def lobe_moments(model, q, sums):
    """Σ y g, Σ g², Σ y g', Σ g g', Σ g'² (g' = ∂g/∂ln p) per texel from :func:`lobe_sums`.

    Torrance-Sparrow (Weyrich et al. 2006 eq. 12 with the parameter-free factor A):
    g = w u, w = 1/m², u = A e^{−w t}, and ∂g/∂ln m = 2 g (w t − 1) = 2w² u t − 2w u.
    Blinn-Phong (eq. 11): g = (n+2) u, u = A e^{n ln cos δ}, and
    ∂g/∂ln n = g (n/(n+2) + n ln cos δ) = n u (1 + (n+2) z), z = ln cos δ.
    (Both derivatives checked against finite differences in the tests.)

    Parameters
    ----------
    model : str
        ``"torrance_sparrow"``; any other value is read as ``"blinn_phong"``.
    q : array_like, shape (k,)
        ln p per texel.
    sums : sequence of 5 ndarray, shape (k,), or ndarray, shape (5, k)
        The five sums of :func:`lobe_sums` at ``q``.

    Returns
    -------
    syg, sgg, sydg, sgdg, sdgdg : ndarray of float64, shape (k,)
        Σ y g, Σ g², Σ y g', Σ g g' and Σ g'² (the last clipped at 0).
    """
    s_yu, s_yuz, s_uu, s_uuz, s_uuzz = sums
    p = np.exp(np.asarray(q, np.float64))
    if model == "torrance_sparrow":
        w = 1 / (p * p)
        syg, sgg = w * s_yu, w * w * s_uu
        sydg = 2 * w * (w * s_yuz - s_yu)
        sgdg = 2 * w * w * (w * s_uuz - s_uu)
        sdgdg = 4 * w * w * (w * w * s_uuzz - 2 * w * s_uuz + s_uu)
    else:
        k = p + 2
        syg, sgg = k * s_yu, k * k * s_uu
        sydg = p * (s_yu + k * s_yuz)
        sgdg = k * p * (s_uu + k * s_uuz)
        sdgdg = p * p * (s_uu + 2 * k * s_uuz + k * k * s_uuzz)
    return syg, sgg, sydg, sgdg, np.maximum(sdgdg, 0)


def lobe_scale(model, q):
    """s(p) with g = s u: 1/m² (TS) or n + 2 (BP), per texel.

    Parameters
    ----------
    model : str
        ``"torrance_sparrow"``; any other value is read as ``"blinn_phong"``.
    q : array_like
        ln p per texel.

    Returns
    -------
    ndarray of float64
        s, shape of ``q``.
    """
    p = np.exp(np.asarray(q, np.float64))
    return 1 / (p * p) if model == "torrance_sparrow" else p + 2
