"""Physics core throughput: vectorised model against a plain-Python loop (issue: foundation).

The baseline is what one would write without numpy: the same formula evaluated
with :mod:`math` one sample at a time.  The scalar versions below are also
checked against the library on the first samples, so the comparison is of equal
work.
"""

from __future__ import annotations

import math
import time

import numpy as np

from facestats.core.published import ETA_SKIN
from facestats.model import brdf, dipole

N_VEC = 10_000_000
N_LOOP = 10_000


def _directions(rng, n):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + 0.05
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _ts_scalar(n, wi, wo, rho, m, eta=ETA_SKIN):
    nwi = n[0] * wi[0] + n[1] * wi[1] + n[2] * wi[2]
    nwo = n[0] * wo[0] + n[1] * wo[1] + n[2] * wo[2]
    if nwi <= 0 or nwo <= 0:
        return 0.0
    h = [wi[0] + wo[0], wi[1] + wo[1], wi[2] + wo[2]]
    hn = math.sqrt(h[0] ** 2 + h[1] ** 2 + h[2] ** 2)
    h = [h[0] / hn, h[1] / hn, h[2] / hn]
    nh = n[0] * h[0] + n[1] * h[1] + n[2] * h[2]
    woh = wo[0] * h[0] + wo[1] * h[1] + wo[2] * h[2]
    c2 = nh * nh
    d = math.exp(-(1 - c2) / c2 / (m * m)) / (m * m * c2 * c2)
    g = min(1.0, 2 * nh * nwo / woh, 2 * nh * nwi / woh)
    sin2t = (1 - woh * woh) / (eta * eta)
    cost = math.sqrt(1 - sin2t)
    rs = (woh - eta * cost) / (woh + eta * cost)
    rp = (eta * woh - cost) / (eta * woh + cost)
    f = 0.5 * (rs * rs + rp * rp)
    return rho / math.pi * d * g / (nwi * nwo) * f


def _dipole_scalar(r, s, a, eta=ETA_SKIN):
    st = s + a
    alpha = s / st
    tr = math.sqrt(3 * a * st)
    fdr = -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta
    big_a = (1 + fdr) / (1 - fdr)
    zr = 1 / st
    zv = zr * (1 + 4 * big_a / 3)
    dr = math.sqrt(r * r + zr * zr)
    dv = math.sqrt(r * r + zv * zv)
    return (
        alpha
        / (4 * math.pi)
        * (zr * (1 + tr * dr) * math.exp(-tr * dr) / dr**3 + zv * (1 + tr * dv) * math.exp(-tr * dv) / dv**3)
    )


def _rate(fn, n, repeat=1):
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return n / best


def bench_torrance_sparrow(n_vec=N_VEC, n_loop=N_LOOP):
    rng = np.random.default_rng(0)
    normal = np.array([0.0, 0.0, 1.0])
    wi, wo = _directions(rng, n_vec), _directions(rng, n_vec)
    rho, m = rng.uniform(0.1, 0.3, n_vec), rng.uniform(0.2, 0.5, n_vec)
    vec = _rate(lambda: brdf.torrance_sparrow(normal, wi, wo, rho, m), n_vec, repeat=2)
    nl = [0.0, 0.0, 1.0]
    wil, wol, rl, ml = wi[:n_loop].tolist(), wo[:n_loop].tolist(), rho[:n_loop].tolist(), m[:n_loop].tolist()
    ref = brdf.torrance_sparrow(normal, wi[:100], wo[:100], rho[:100], m[:100])
    assert np.allclose([_ts_scalar(nl, wil[i], wol[i], rl[i], ml[i]) for i in range(100)], ref, rtol=1e-9)
    loop = _rate(lambda: [_ts_scalar(nl, wil[i], wol[i], rl[i], ml[i]) for i in range(n_loop)], n_loop, repeat=3)
    return {"vectorised_eval_per_s": vec, "python_loop_eval_per_s": loop, "ratio": vec / loop, "samples": n_vec}


def bench_dipole_profile(n_vec=N_VEC, n_loop=N_LOOP):
    rng = np.random.default_rng(1)
    r = rng.uniform(0, 10, n_vec)
    s, a = rng.uniform(0.5, 3, n_vec), rng.uniform(0.01, 0.5, n_vec)
    vec = _rate(lambda: dipole.dipole_profile(r, s, a), n_vec, repeat=2)
    rl, sl, al = r[:n_loop].tolist(), s[:n_loop].tolist(), a[:n_loop].tolist()
    assert np.allclose(
        [_dipole_scalar(rl[i], sl[i], al[i]) for i in range(100)],
        dipole.dipole_profile(r[:100], s[:100], a[:100]),
        rtol=1e-10,
    )
    loop = _rate(lambda: [_dipole_scalar(rl[i], sl[i], al[i]) for i in range(n_loop)], n_loop, repeat=3)
    return {"vectorised_eval_per_s": vec, "python_loop_eval_per_s": loop, "ratio": vec / loop, "samples": n_vec}


BENCHMARKS = [("torrance_sparrow", bench_torrance_sparrow), ("dipole_profile", bench_dipole_profile)]

#: Tiny sizes for the test suite (tests/test_benchmarks.py).
SMOKE = {
    "torrance_sparrow": {"n_vec": 2000, "n_loop": 200},
    "dipole_profile": {"n_vec": 2000, "n_loop": 200},
}
