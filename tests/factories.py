"""Small schema-valid subject Datasets for tests that do not need the fit pipeline, and sample geometry."""

from __future__ import annotations

import json

import numpy as np
import xarray as xr

from facestats.acquire.sensor import default_fiber_distances
from facestats.core.conventions import CHANNELS, SITES
from facestats.io.schema import set_variable_attrs
from facestats.model import dipole


def hemisphere_pairs(rng, texels, samples):
    """Random (ωi, ωo) pairs above the z = 0 plane, each (texels, samples, 3), unit length."""
    v = rng.normal(size=(2, texels, samples, 3))
    v[..., 2] = np.abs(v[..., 2]) + 0.05
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return v[0], v[1]


def region_map(size: int) -> np.ndarray:
    """A crude 10-region layout on a size×size grid (0 outside an ellipse)."""
    v, u = np.mgrid[0:size, 0:size] / (size - 1)
    face = ((u - 0.5) / 0.45) ** 2 + ((v - 0.5) / 0.48) ** 2 < 1
    reg = np.zeros((size, size), np.uint8)
    bands = [
        (0.0, 0.25, 2),
        (0.25, 0.32, 3),
        (0.32, 0.4, 4),
        (0.4, 0.47, 5),
        (0.47, 0.62, 7),
        (0.62, 0.68, 1),
        (0.68, 0.76, 8),
        (0.76, 0.88, 9),
        (0.88, 1.01, 10),
    ]
    for lo, hi, r in bands:
        reg[(v >= lo) & (v < hi)] = r
    reg[(np.abs(u - 0.5) < 0.08) & (v > 0.35) & (v < 0.62)] = 6
    reg[~face] = 0
    return reg


def make_map_subject(
    subject_id="S000",
    *,
    size=24,
    skin_type=3,
    gender="M",
    age=25,
    condition="normal",
    seed=0,
    rho_shift=0.0,
    person_id=None,
):
    rng = np.random.default_rng(seed)
    reg = region_map(size)
    face = reg > 0
    base = np.array([0.55, 0.32, 0.24]) * (1.0 - 0.12 * (skin_type - 2))
    albedo = np.clip(base * (1 + 0.05 * rng.standard_normal((size, size, 3))), 0.01, 0.95).astype(np.float32)
    albedo[~face] = 0
    rho = (0.18 + rho_shift + 0.01 * reg + 0.01 * rng.standard_normal((size, size))).astype(np.float32)
    m = (0.35 - 0.01 * (reg == 6) + 0.02 * rng.standard_normal((size, size))).astype(np.float32)
    expo = (2 / m**2 - 2).astype(np.float32)
    zeros = np.zeros((size, size), np.float32)
    flags = np.zeros((size, size), np.uint8)
    flags[0, 0] = 1
    fib = default_fiber_distances()
    sigma_tr = np.array([[0.55, 0.98, 1.55], [0.54, 0.98, 1.55], [0.69, 1.25, 1.92]]) * (
        1 + 0.05 * rng.standard_normal((3, 3))
    )
    alb_avg = albedo[face].mean(0).astype(np.float64)
    sp, sa = dipole.scattering_from_albedo(np.broadcast_to(alb_avg, (3, 3)), sigma_tr)
    prof = np.stack(
        [[dipole.dipole_profile(fib, sp[s, c], sa[s, c]) for c in range(3)] for s in range(3)], 0
    ).transpose(0, 2, 1)
    sp0, sa0 = dipole.scattering_from_albedo(alb_avg, np.array([0.5508, 0.9791, 1.5497]))
    ds = xr.Dataset(
        {
            "region": (("v", "u"), reg),
            "albedo": (("v", "u", "channel"), albedo),
            "ts_rho_s": (("v", "u"), np.where(face, rho, 0).astype(np.float32)),
            "ts_m": (("v", "u"), np.where(face, m, 0).astype(np.float32)),
            "ts_error": (("v", "u"), zeros + 0.01),
            "ts_flag": (("v", "u"), flags),
            "bp_rho_s": (("v", "u"), np.where(face, rho * 0.9, 0).astype(np.float32)),
            "bp_exponent": (("v", "u"), np.where(face, expo, 0).astype(np.float32)),
            "bp_error": (("v", "u"), zeros + 0.01),
            "bp_flag": (("v", "u"), flags.copy()),
            "sensor_profile": (("site", "fiber", "channel"), prof),
            "sensor_profile_std": (("site", "fiber", "channel"), prof * 0.01),
            "site_sigma_s_prime": (("site", "channel"), sp),
            "site_sigma_a": (("site", "channel"), sa),
            "site_sigma_tr": (("site", "channel"), sigma_tr),
            "albedo_avg": (("channel",), alb_avg),
            "sigma_s_prime": (("channel",), sp0),
            "sigma_a": (("channel",), sa0),
            "sigma_tr": (("channel",), np.array([0.5508, 0.9791, 1.5497])),
        },
        coords={
            "u": (np.arange(size) + 0.5) / size,
            "v": (np.arange(size) + 0.5) / size,
            "channel": list(CHANNELS),
            "site": list(SITES),
            "fiber_distance": ("fiber", fib),
        },
        attrs={
            "subject_id": subject_id,
            "person_id": person_id or subject_id,
            "age": int(age),
            "gender": gender,
            "skin_type": int(skin_type),
            "condition": condition,
            "provenance": json.dumps({"source": "tests.factories", "seed": seed}),
        },
    )
    return set_variable_attrs(ds)


def make_sample_subject(subject_id="M001", *, n_per_region=20, skin_type=3, gender="F", age=31, seed=0):
    rng = np.random.default_rng(seed)
    reg = np.repeat(np.arange(1, 11), n_per_region).astype(np.int16)
    ds = xr.Dataset(
        {
            "ts_sample_m": (("sample",), rng.uniform(0.25, 0.45, reg.size)),
            "ts_sample_rho_s": (("sample",), rng.uniform(0.1, 0.3, reg.size)),
            "ts_sample_region": (("sample",), reg),
            "albedo_sample": (("albedo_sample", "channel"), rng.uniform(0.1, 0.6, (reg.size, 3))),
            "albedo_sample_region": (("albedo_sample",), reg),
        },
        coords={"channel": list(CHANNELS)},
        attrs={
            "subject_id": subject_id,
            "person_id": subject_id,
            "age": int(age),
            "gender": gender,
            "skin_type": int(skin_type),
            "condition": "normal",
            "provenance": json.dumps({"source": "tests"}),
        },
    )
    return set_variable_attrs(ds)
