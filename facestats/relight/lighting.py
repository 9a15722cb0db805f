"""Light probes as lighting: validation, rotation, layout conversion and resampling to a light set (L·δA per light).

One job: turn an environment map into the per-light weights L(θ, φ) δA(θ, φ) of
Debevec et al. 2000 eq. 4.  Directions, layouts and the rotation convention are
those of :mod:`facestats.model.sphere`.

Resampling conserves Σ L·δΩ exactly:

* lat-long probe → lat-long light stage: the integral of the (piecewise
  constant) probe over each light-stage cell, from the exact overlap areas of
  probe pixels and cells.  Cells of the lat-long grid are products of a polar
  interval and an azimuth interval, so an overlap's solid angle is the product
  of its azimuth length and the difference of the cosines of its polar
  bounds; the resampling is two small matrix products.  (A block mean of
  pixels weighted by sin φ at pixel centres errs by percents near the poles.)
* any probe → an arbitrary light set (a real dome's LEDs): every probe
  pixel, subdivided ``supersample`` × ``supersample`` into sub-cells with exact
  solid angles, is given to its nearest light, i.e. the probe is integrated
  over the spherical Voronoi cells of the lights
  (:func:`facestats.model.sphere.voronoi_solid_angles`), each bounded by the
  light's reach (:func:`facestats.model.sphere.light_reach`: four median light
  spacings).  Every sub-cell goes to at most one light, so the total over the
  directions the lights reach is conserved exactly; light from beyond every
  light's reach (behind a frontal OLAT rig) is left out rather than given to
  a rim light far from it.  Each light's share is exact up to the sub-cells cut
  by a Voronoi edge.
"""

from __future__ import annotations

import math

import numpy as np

from facestats.core.validate import (
    as_finite,
    as_scalar,
    check_broadcast,
    check_integer,
    check_shape,
)
from facestats.errors import ValidationError
from facestats.model.sphere import (
    angles_from_direction,
    angular_coordinates,
    angular_directions,
    angular_solid_angles,
    check_probe,
    latlong_coordinates,
    latlong_directions,
    latlong_edges,
    latlong_solid_angles,
    nearest_light,
    resolve_reach,
    rotate_directions,
    unit_directions,
)

__all__ = [
    "probe_samples",
    "resample_probe",
    "rotate_probe",
    "latlong_to_angular",
    "angular_to_latlong",
    "uniform_probe",
    "sky_probe",
]


def _overlap_1d(target_edges, source_edges, measure):
    """Matrix (T, S) of measure(overlap of target interval t and source interval s)."""
    lo = np.maximum(target_edges[:-1, None], source_edges[None, :-1])
    hi = np.minimum(target_edges[1:, None], source_edges[None, 1:])
    return np.where(hi > lo, measure(lo, hi), 0.0)


def _latlong_to_grid(probe, n_phi, n_theta):
    """Exact ∫ L dΩ of a lat-long probe over the cells of an n_phi × n_theta lat-long grid, (n_phi, n_theta, 3)."""
    h, w = probe.shape[:2]
    sp, st = latlong_edges(h, w)
    tp, tt = latlong_edges(n_phi, n_theta)
    rows = _overlap_1d(tp, sp, lambda a, b: np.cos(a) - np.cos(b))  # (n_phi, H)
    cols = _overlap_1d(tt, st, lambda a, b: b - a)  # (n_theta, W)
    p = probe.astype(np.float64)
    return np.einsum("ah,hwc,bw->abc", rows, p, cols, optimize=True)


def probe_samples(probe, layout: str = "latlong", supersample: int = 1, rows: slice | None = None):
    """The probe as weighted direction samples: ``(directions (N, 3), L·δΩ (N, 3))``.

    Each pixel is split into ``supersample``² sub-cells: exact lat-long sub-cells
    (equal steps in φ and θ, exact areas), or for angular probes quadrature
    sub-cells of equal (u, v) size weighted by the Jacobian.  Radiance is
    constant over a pixel, so Σ L·δΩ equals that of the pixels exactly.
    ``rows`` (a slice of consecutive probe rows): the samples of those rows alone, so a large probe can be
    integrated band by band in bounded memory.

    Parameters
    ----------
    probe : array_like, shape (H, W, 3)
        Linear radiance (checked by :func:`check_probe`).
    layout : {"latlong", "angular"}
    supersample : int
        Sub-cells per pixel side, 1-16.
    rows : slice, optional
        Probe rows to sample (step 1); default all.

    Returns
    -------
    directions : numpy.ndarray, shape (N, 3)
        Unit vectors of the sub-cells (those of positive solid angle only: an angular probe's corners outside
        the disc are dropped).
    weights : numpy.ndarray of float64, shape (N, 3)
        L·δΩ per sub-cell and channel (the probe's unit × sr).

    Raises
    ------
    ValidationError
        For an invalid probe, ``supersample`` outside 1-16, or ``rows`` with a step other than 1.
    """
    p = check_probe(probe, layout)
    s = check_integer(supersample, "supersample", 1, 16)
    h, w = p.shape[:2]
    band = range(h) if rows is None else range(h)[rows]
    if band.step != 1:
        raise ValidationError(f"rows must be a slice of consecutive probe rows, got {rows!r}")
    r0, n = band.start, len(band)
    sub = slice(r0 * s, (r0 + n) * s)  # the band's sub-cell rows
    if layout == "latlong":
        sub_d = latlong_directions(h * s, w * s, rows=sub).reshape(n, s, w, s, 3)
        phi_e, _ = latlong_edges(h * s, w * s)
        sub_sa = (2 * np.pi / (w * s)) * (np.cos(phi_e[:-1]) - np.cos(phi_e[1:]))
        sa = np.broadcast_to(sub_sa[sub].reshape(n, s, 1, 1), (n, s, w, s))
    else:
        sub_d, inside = angular_directions(h * s, rows=sub)
        sa = angular_solid_angles(h * s, rows=sub).reshape(n, s, w, s)
        sub_d = np.where(inside[..., None], sub_d, np.array([0.0, 0.0, 1.0])).reshape(n, s, w, s, 3)
    rad = np.broadcast_to(p[r0 : r0 + n, None, :, None, :], (n, s, w, s, 3))
    keep = sa.reshape(-1) > 0
    d = sub_d.reshape(-1, 3)[keep]
    lw = (rad.reshape(-1, 3) * sa.reshape(-1, 1))[keep]
    return d, lw


def _grid_cells(directions, n_phi, n_theta):
    """Flat index of the lat-long grid cell containing each direction."""
    phi, theta = angles_from_direction(directions)
    i = np.clip((phi / np.pi * n_phi).astype(np.int64), 0, n_phi - 1)
    j = np.clip(((theta + np.pi) / (2 * np.pi) * n_theta).astype(np.int64), 0, n_theta - 1)
    return i * n_theta + j


def _is_latlong_grid(d):
    return d.ndim == 3 and d.shape[2] == 3 and np.allclose(d, latlong_directions(d.shape[0], d.shape[1]), atol=1e-6)


def resample_probe(
    probe, directions=None, *, layout: str = "latlong", rotate: float = 0.0, supersample: int = 4, reach="auto"
):
    """Per-light L·δA of a light probe for a light set (Debevec et al. 2000 eq. 4), conserving Σ L·δΩ exactly.

    Parameters
    ----------
    probe : array_like, shape (H, W, 3)
        Linear radiance (any unit; the result is in that unit × sr), in the
        lat-long (W = 2H) or angular (W = H) layout of :mod:`facestats.model.sphere`.
    directions : array_like, shape (..., 3), optional
        Unit vectors towards the lights.  Default: Debevec's 64 × 32 light
        stage, :func:`facestats.model.sphere.light_stage_directions`.  A lat-long
        grid of directions (n_phi, n_theta, 3) is integrated over its exact
        cells; any other set over its spherical Voronoi cells (module docstring).
    layout : {"latlong", "angular"}
    rotate : float
        Rotate the environment about +y by this angle first (radians, right-handed,
        :func:`rotate_probe`).
    supersample : int
        Sub-cells per pixel side for the Voronoi integration (and for angular
        probes), 1-16.
    reach : "auto", float or None
        How far a Voronoi cell extends from its light (radians,
        :func:`facestats.model.sphere.light_reach`; None: unbounded); the probe's
        light from directions beyond every light's reach is left out.  Use the
        same value as the field's solid angles
        (:func:`facestats.model.sphere.voronoi_solid_angles`).

    Returns
    -------
    ndarray of float64, shape directions.shape[:-1] + (3,)
        ∫_cell L dΩ per light and channel.  Their sum over lights equals
        Σ_pixels L ΔΩ of the probe (exactly, up to rounding) over the directions
        the lights reach: all of them for a lat-long grid or a set that
        surrounds the subject.
    """
    p = check_probe(probe, layout)
    supersample = check_integer(supersample, "supersample", 1, 16)
    rot = as_finite(rotate, "rotate", dtype=np.float64)
    if rot.ndim:
        raise ValidationError(f"rotate must be one angle (radians), got an array of shape {rot.shape}")
    if rot:
        p = rotate_probe(p, float(rot), layout=layout)
    if directions is None:
        d = latlong_directions(32, 64)
    else:
        d = unit_directions(directions)
        if d.size == 0:  # the probe's light would go nowhere
            raise ValidationError(f"directions must hold at least one light, got shape {d.shape}")
    if layout == "latlong" and _is_latlong_grid(d):
        return _latlong_to_grid(p, d.shape[0], d.shape[1])
    flat = d.reshape(-1, 3)
    grid = _is_latlong_grid(d)  # an angular probe onto a lat-long grid: its cells, not Voronoi cells
    r = None if grid else resolve_reach(reach, flat)
    n = flat.shape[0]
    out = np.zeros((n, 3))
    for rows in _bands(p.shape, layout, supersample):  # loop over bands of probe rows: bounded memory
        samples, weights = probe_samples(p, layout, supersample, rows=rows)
        # the nearest light on the unit sphere = its Voronoi cell; n (dropped) beyond every light's reach
        idx = _grid_cells(samples, d.shape[0], d.shape[1]) if grid else nearest_light(flat, samples, r)
        for c in range(3):
            out[:, c] += np.bincount(idx, weights=weights[:, c], minlength=n + 1)[:n]
    return out.reshape(d.shape[:-1] + (3,))


#: Sub-cell samples per band of :func:`resample_probe` (about 100 MB of temporaries).
_BAND_SAMPLES = 2**20


def _bands(shape, layout, supersample):
    """Slices of probe rows holding about :data:`_BAND_SAMPLES` sub-cells each; a sixteenth of that for angular
    probes, whose sub-cells' solid angles take an 8 × 8 quadrature each
    (:func:`facestats.model.sphere.angular_solid_angles`)."""
    h, w = shape[:2]
    per_band = _BAND_SAMPLES if layout == "latlong" else _BAND_SAMPLES // 16
    step = max(1, per_band // (w * int(supersample) ** 2))
    return [slice(r, min(r + step, h)) for r in range(0, h, step)]


def _bilinear_latlong(probe, directions):
    """Bilinear lookup of a lat-long probe at directions (columns wrap, rows clamp)."""
    from scipy.ndimage import map_coordinates

    h, w = probe.shape[:2]
    r, c = latlong_coordinates(directions, h, w)
    padded = np.concatenate([probe[:, -1:], probe, probe[:, :1]], axis=1)  # one wrapped column each side
    c = np.mod(c + 0.5, w) - 0.5 + 1  # into the padded image
    coords = np.stack([r.reshape(-1), c.reshape(-1)])
    out = [map_coordinates(padded[..., k], coords, order=1, mode="nearest") for k in range(3)]
    return np.stack(out, axis=-1).reshape(np.shape(directions)[:-1] + (3,))


def _bilinear_angular(probe, directions):
    """Bilinear lookup of an angular probe at directions, weighting only pixels inside the disc."""
    from scipy.ndimage import map_coordinates

    s = probe.shape[0]
    _, inside = angular_directions(s)
    r, c = angular_coordinates(directions, s)
    coords = np.stack([r.reshape(-1), c.reshape(-1)])
    m = map_coordinates(inside.astype(np.float64), coords, order=1, mode="constant")
    out = [map_coordinates(probe[..., k] * inside, coords, order=1, mode="constant") for k in range(3)]
    with np.errstate(invalid="ignore", divide="ignore"):
        v = np.stack(out, axis=-1) / m[:, None]
    return np.where(m[:, None] > 0, v, 0.0).reshape(np.shape(directions)[:-1] + (3,))


def _lookup(probe, layout, directions):
    return _bilinear_latlong(probe, directions) if layout == "latlong" else _bilinear_angular(probe, directions)


def rotate_probe(probe, angle: float, *, layout: str = "latlong") -> np.ndarray:
    """The environment rotated about +y by ``angle`` radians (right-handed): L'(d) = L(R_y(−angle) d).

    Lat-long probes are shifted by ``angle`` W/(2π) columns towards smaller column
    indices with exact area weights (the shifted pixel j covers parts of two
    source pixels), so Σ L·δΩ is conserved exactly and a shift by whole
    columns is a roll.  Angular probes are resampled bilinearly.

    Parameters
    ----------
    probe : array_like, shape (H, W, 3)
        Linear radiance, checked by :func:`check_probe`.
    angle : float
        Rotation about +y (radians, right-handed); any finite value (taken modulo 2π).
    layout : {"latlong", "angular"}
        Layout of :mod:`facestats.model.sphere`: lat-long W = 2H, angular W = H.

    Returns
    -------
    ndarray of float32, shape of ``probe``

    Raises
    ------
    ValidationError
        A probe :func:`check_probe` refuses, or an ``angle`` that is not one finite number.
    """
    p = check_probe(probe, layout)
    a = as_finite(angle, "angle", dtype=np.float64)
    if a.ndim:
        raise ValidationError(f"angle must be one number (radians), got an array of shape {a.shape}")
    a = math.fmod(float(a), 2 * math.pi)  # the same rotation; keeps the column shift below an int's range
    if layout == "latlong":
        w = p.shape[1]
        s = a * w / (2 * np.pi)
        n = int(np.floor(s))
        f = s - n
        a0 = np.roll(p, -n, axis=1)
        return ((1 - f) * a0 + f * np.roll(a0, -1, axis=1)).astype(np.float32)
    d, inside = angular_directions(p.shape[0])
    src = rotate_directions(np.where(inside[..., None], d, 0.0), -a)
    out = _lookup(p, layout, np.where(inside[..., None], src, np.array([0.0, 0.0, -1.0])))
    return np.where(inside[..., None], out, 0.0).astype(np.float32)


def latlong_to_angular(probe, size: int | None = None, *, supersample: int | None = None) -> np.ndarray:
    """An angular (light-probe) image of side ``size`` (default H) from a lat-long probe, conserving Σ L·δΩ.

    Each output pixel t is a weighted sum of probe pixels p, out_t = Σ_p T_tp L_p / ΔΩ_t, with a transport
    T_tp ≥ 0 whose rows sum to the output pixels' solid angles ΔΩ_t and whose columns sum to the probe pixels'
    exact solid angles ΔΩ_p (:func:`facestats.model.sphere.latlong_solid_angles`): every probe pixel hands out
    exactly L_p ΔΩ_p, so Σ L·ΔΩ over the output (ΔΩ_t of :func:`facestats.model.sphere.angular_solid_angles` at
    ``size``) equals the probe's at any ``size`` (up to rounding), and a constant probe stays constant (within
    4.4e-4: the rows' scaling is stopped, below).  Point sampling, as before 2026-12-08, missed or multiplied small
    bright sources: on the Probulator probe grace at 128², 12 / 9 / 7 % of the power in R / G / B lost at its
    default ``supersample`` of 2; at 32², 66 % lost or 165 % gained.

    T is the overlap of output pixels and probe pixels, measured on ``supersample``² sub-cells per output pixel:
    each sub-cell's solid angle (:func:`facestats.model.sphere.angular_solid_angles` of the sub-cell grid; 0
    outside the disc) goes to the four probe pixels around its centre direction with their bilinear weights
    (columns wrap, rows clamp at the poles), so ΔΩ_t is the sum of its sub-cells'.  A probe pixel that no sub-cell
    reaches (a probe finer than the sub-cells, or its rows near the poles) is shared, by the scaling below, among the
    output pixel containing its centre direction and that pixel's four neighbours (given whole to the one pixel, a
    uniform 1024-row probe came out 0.965-1.0038 around the poles at 1024², now 0.9990-1.0004).
    Measured so, the columns sum to ΔΩ_p only approximately (sampling a probe pixel's bilinear weights at spacing ρ,
    sub-cell over probe pixel, errs by O(ρ²), and more where the pixels are thin near the poles); T is scaled to
    both sums by alternating row and column scaling (Sinkhorn 1964, the iteration of §1 on a non-negative matrix
    with prescribed row and column sums; :data:`SINKHORN_STEPS`,
    :data:`SINKHORN_TOLERANCE`), ending on the columns.  ``supersample`` thus sets how finely each probe pixel's
    power is shared among output pixels, never the power; below the default the sharing is coarse (a uniform
    256-row probe at 256²: 0.73-1.54 with 1, 0.98-1.03 with 2, within 4.4e-4 with the default 4).
    The default is the smallest in [4, 16] with ``size`` · ``supersample`` ≥ 8 H (sub-cells a quarter of a probe pixel
    along the radius); where 16 falls short (``size`` < H / 2) the probe is first merged into blocks of k × k pixels, k
    the largest divisor of H up to 8 H / (16 ``size``), each of their mean radiance weighted by solid angle (Σ L·ΔΩ
    unchanged), so that the sub-cells again stay finer than the pixels. Without the merge a uniform 1024-row probe came
    out 0.987-1.010 at 64² and 0.995-1.0014 at 256², a 256-row one 0.9968-1.0036 at 16² and 4² (pixels no sub-cell
    reaches, each given whole to one output pixel, and the scaling far from converged in its steps). Figures in
    docs/relighting.md.

    Parameters
    ----------
    probe : array_like, shape (H, 2H, 3)
        Lat-long probe, linear radiance (:func:`check_probe`).
    size : int, optional
        Side of the angular image, ≥ 1 (default H).
    supersample : int, optional
        Sub-cells per output pixel side, 1-16 (default: automatic, above; given, the probe is never merged).

    Returns
    -------
    numpy.ndarray of float32, shape (size, size, 3)
        Radiance; 0 at pixels wholly outside the disc (and at rim slivers that no sub-cell reaches).

    Raises
    ------
    ValidationError
        For an invalid probe, ``size`` or ``supersample``.
    """
    p = check_probe(probe, "latlong")
    h, w = p.shape[:2]
    n = h if size is None else check_integer(size, "size", 1)
    if supersample is None:
        s = min(16, max(4, -(-8 * h // n)))
        p = _merge_rows(p, 8 * h // (n * s))  # a probe finer than 16 sub-cells per output pixel: blocks of pixels
        h, w = p.shape[:2]
    else:
        s = check_integer(supersample, "supersample", 1, 16)
    transport, area = _angular_transport(h, w, n, s)
    exact = angular_solid_angles(n).reshape(-1)
    area = np.where(exact > 0, exact, area)  # a sliver of the rim that only the sub-cells' finer quadrature sees
    a, g = _sinkhorn(transport, area, latlong_solid_angles(h, w).reshape(-1))
    flat = p.reshape(-1, 3).astype(np.float64)
    power = a[:, None] * (transport @ (g[:, None] * flat))
    out = np.divide(power, area[:, None], out=np.zeros_like(power), where=area[:, None] > 0)
    return out.reshape(n, n, 3).astype(np.float32)


def _merge_rows(p, most):
    """A lat-long probe (H, W, 3) as blocks of k × k pixels, k the largest divisor of H (and so of W = 2 H) up to
    ``most`` (≥ 1; 1: unchanged): each block's radiance is its pixels' mean weighted by their exact solid angles
    (:func:`facestats.model.sphere.latlong_solid_angles`), so Σ L·ΔΩ is unchanged (a block's solid angle is the sum
    of its pixels': the rows are equally spaced in polar angle)."""
    h, w = p.shape[:2]
    k = max((d for d in range(1, max(1, most) + 1) if h % d == 0), default=1)
    if k == 1:
        return p
    sa = latlong_solid_angles(h, w)[..., None]
    power = (p.astype(np.float64) * sa).reshape(h // k, k, w // k, k, 3).sum((1, 3))
    return power / sa.reshape(h // k, k, w // k, k, 1).sum((1, 3))


#: Largest relative deviation of the rows of :func:`latlong_to_angular`'s transport from the output pixels' solid
#: angles at which the scaling stops early (the columns, the probe pixels' power, are exact at every step it stops
#: on).
SINKHORN_TOLERANCE = 1e-4

#: Most scaling steps :func:`latlong_to_angular` takes.  The iteration converges slowly (linearly, on the rim's
#: thin pixels): after 300 steps a uniform probe comes out within 4.4e-4 of its value at 8² to 512² from 128 rows
#: (1e-4 after 1,000 steps, which take twice as long at 512²: 13.5 against 7.4 s).
SINKHORN_STEPS = 300


def _sinkhorn(t, rows, cols):
    """Scales a (R,) and g (C,) with diag(a) T diag(g) summing to ``cols`` over each column exactly and to ``rows``
    over each row within :data:`SINKHORN_TOLERANCE` (Sinkhorn, *A relationship between arbitrary positive matrices
    and doubly stochastic matrices*, Ann. Math. Statist. 35, 1964: alternate row and column normalisation, here to
    prescribed sums; ending on the columns).

    Rows without an entry are left out and the other rows' targets scaled to the columns' total (the quadratures of
    the two pixel grids' solid angles differ by 1e-7-1e-4 of 4π), so that both sums can be met."""
    a = np.ones(t.shape[0])
    has = (rows > 0) & (np.diff(t.indptr) > 0)
    rows = np.where(has, rows, 0.0)
    rows = rows * (cols.sum() / rows.sum())
    tt = t.T.tocsr()
    for _ in range(SINKHORN_STEPS):
        g = cols / (tt @ a)  # every column has an entry (a sampled weight or its centre's pixel) in a row of a > 0
        sums = t @ g
        if np.max(np.abs(a[has] * sums[has] / rows[has] - 1)) <= SINKHORN_TOLERANCE:
            return a, g
        a = np.divide(rows, sums, out=np.zeros_like(rows), where=has)
    return a, cols / (tt @ a)


def _angular_transport(h, w, n, s):
    """The sampled overlaps of an n × n angular image's pixels and an h × w lat-long probe's (sparse (n², h·w), with
    a probe pixel no sub-cell reaches at the output pixel of its centre and its four neighbours) and the output
    pixels' solid angles (n²,): :func:`latlong_to_angular`."""
    from scipy import sparse

    rows, cols, vals = [], [], []
    area = np.zeros(n * n)
    reached = np.zeros(h * w, bool)
    for band in _bands((n, n), "angular", s):  # bands of output rows: bounded memory at any size
        target, pix, wgt = _angular_sub_cells(n, s, band, h, w)
        area += np.bincount(target, weights=wgt.sum(-1), minlength=n * n)
        block = sparse.coo_matrix((wgt.reshape(-1), (np.repeat(target, 4), pix.reshape(-1))), shape=(n * n, h * w))
        block = block.tocsr().tocoo()  # duplicates summed
        rows.append(block.row)
        cols.append(block.col)
        vals.append(block.data)
        reached[block.col[block.data > 0]] = True
    missed = np.flatnonzero(~reached)
    if missed.size:  # probe pixels finer than the sub-cells: to the output pixel of their centre and its 4 neighbours
        centre = _angular_pixel(latlong_directions(h, w).reshape(-1, 3)[missed], n, area)
        r, c = np.divmod(centre, n)
        for dr, dc in ((0, 0), (-1, 0), (1, 0), (0, -1), (0, 1)):  # the scaling shares the power among them
            rr, cc = r + dr, c + dc
            inside = (rr >= 0) & (rr < n) & (cc >= 0) & (cc < n)
            near = np.where(inside, np.clip(rr, 0, n - 1) * n + np.clip(cc, 0, n - 1), centre)
            rows.append(np.where(area[near] > 0, near, centre))
            cols.append(missed)
            vals.append(np.ones(missed.size))  # any weight: the scaling sets it
    t = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n * n, h * w))
    return t, area


def _angular_pixel(d, n, area):
    """Flat pixel of an angular image of side n containing each direction; moved one pixel inwards where that pixel
    has no ``area`` (a rim pixel whose sub-cells all lie outside the disc)."""
    r, c = angular_coordinates(d, n)
    u, v = 2 * (c + 0.5) / n - 1, 1 - 2 * (r + 0.5) / n
    t = []
    for shrink in (0.0, 2.0 / n):  # as found, and one pixel towards the centre
        rad = np.hypot(u, v)
        k = np.where(rad > 0, np.maximum(rad - shrink, 0) / np.where(rad > 0, rad, 1), 0.0)
        row = np.clip(np.floor((1 - v * k) * n / 2), 0, n - 1).astype(np.int64)
        col = np.clip(np.floor((u * k + 1) * n / 2), 0, n - 1).astype(np.int64)
        t.append(row * n + col)
    return np.where(area[t[0]] > 0, t[0], t[1])


def _angular_sub_cells(n, s, rows, h, w):
    """The sub-cells of output rows ``rows`` of an n × n angular image (s × s per pixel) against an h × w lat-long
    probe: their output pixel (flat, (N,)), the four probe pixels around each sub-cell's centre direction (flat,
    (N, 4)) and the sub-cell's solid angle times each one's bilinear weight ((N, 4); columns wrap, rows clamp at
    the poles).  Sub-cells of zero solid angle (outside the disc) are left out."""
    sub = slice(rows.start * s, rows.stop * s)
    d, inside = angular_directions(n * s, rows=sub)
    sa = angular_solid_angles(n * s, rows=sub).reshape(-1)
    d = np.where(inside[..., None], d, np.array([0.0, 0.0, 1.0])).reshape(-1, 3)  # corners cut by the rim: +z
    keep = sa > 0
    d, sa = d[keep], sa[keep]
    i = np.arange(sub.start, sub.stop)[:, None] // s
    j = np.arange(n * s)[None, :] // s
    target = (i * n + j).reshape(-1)[keep]
    r, c = latlong_coordinates(d, h, w)
    r0, c0 = np.floor(r), np.floor(c)
    fr, fc = r - r0, c - c0
    r0, c0 = r0.astype(np.int64), c0.astype(np.int64)
    rows_ = np.clip(np.stack([r0, r0, r0 + 1, r0 + 1], -1), 0, h - 1)
    cols_ = np.mod(np.stack([c0, c0 + 1, c0, c0 + 1], -1), w)
    bil = np.stack([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc], -1)
    return target, rows_ * w + cols_, bil * sa[:, None]


def angular_to_latlong(probe, height: int | None = None, *, supersample: int = 2) -> np.ndarray:
    """A lat-long probe (``height`` × 2 ``height``, default S/2 rows) from an angular probe (bilinear, supersampled).

    Parameters
    ----------
    probe : array_like, shape (S, S, 3)
        Angular probe, linear radiance (:func:`check_probe`); only pixels inside its disc are looked up.
    height : int, optional
        Rows of the result, ≥ 1 (default max(1, S // 2)).
    supersample : int
        Bilinear lookups per output pixel side (averaged), 1-8.

    Returns
    -------
    numpy.ndarray of float32, shape (height, 2 height, 3)

    Raises
    ------
    ValidationError
        For an invalid probe, ``height`` or ``supersample``.
    """
    p = check_probe(probe, "angular")
    h = max(1, p.shape[0] // 2) if height is None else check_integer(height, "height", 1)
    s = check_integer(supersample, "supersample", 1, 8)
    d = latlong_directions(h * s, 2 * h * s)
    vals = _lookup(p, "angular", d).reshape(h, s, 2 * h, s, 3)
    return vals.mean(axis=(1, 3)).astype(np.float32)


def uniform_probe(height: int = 32, radiance=1.0) -> np.ndarray:
    """A constant lat-long environment of the given RGB radiance, (H, 2H, 3) float32 (tests, white furnace).

    Parameters
    ----------
    height : int
        Rows H, ≥ 1.
    radiance : float or array_like, shape (3,)
        Radiance, finite and ≥ 0: one value for all channels or one per channel.

    Returns
    -------
    numpy.ndarray of float32, shape (height, 2 height, 3)

    Raises
    ------
    ValidationError
        For ``height`` < 1, or a negative, non-finite or mis-shaped ``radiance``.
    """
    h = check_integer(height, "height", 1)
    r = check_broadcast(as_finite(radiance, "radiance", 0, None), "radiance", (3,), "one value per RGB channel")
    return np.broadcast_to(r.astype(np.float32), (h, 2 * h, 3)).copy()


def sky_probe(
    height: int = 64,
    sun_direction=(0.3, 0.8, 0.5),
    *,
    sun_radiance=2000.0,
    sun_radius_deg=2.0,
    sky=(0.35, 0.5, 0.8),
    ground=(0.15, 0.12, 0.1),
) -> np.ndarray:
    """A synthetic outdoor lat-long probe: blue sky above, brown ground below, a small bright disc sun.

    For demonstrations and tests when no measured probe is at hand; not a
    physical sky model.  Radiances are relative (sky ≈ 0.5, sun ``sun_radiance``).

    Parameters
    ----------
    height : int
        Rows H of the probe, ≥ 2.
    sun_direction : array_like, shape (3,)
        Direction towards the sun, world frame (+y up); non-zero, normalised here.
    sun_radiance : float
        Radiance of the sun's disc (all channels), finite and ≥ 0.
    sun_radius_deg : float
        Angular radius of the disc, degrees, in (0, 90]; at least the pixel nearest the sun is lit.
    sky, ground : array_like, shape (3,)
        RGB radiance of the sky at the zenith (scaled by 0.6 + 0.4 y, 0.6 at the horizon) and of the ground,
        finite and ≥ 0.

    Returns
    -------
    numpy.ndarray of float32, shape (height, 2 height, 3)

    Raises
    ------
    ValidationError
        For an invalid ``height``, ``sun_direction``, ``sun_radiance``, ``sun_radius_deg``, ``sky`` or ``ground``.
    """
    h = check_integer(height, "height", 2)
    sun_radiance = as_scalar(sun_radiance, "sun_radiance", 0.0)
    sky, ground = (
        check_shape(as_finite(v, n, 0.0, dtype=np.float64), n, (3,)) for v, n in ((sky, "sky"), (ground, "ground"))
    )
    sun = check_shape(as_finite(sun_direction, "sun_direction", dtype=np.float64), "sun_direction", (3,))
    if np.linalg.norm(sun) == 0:
        raise ValidationError("sun_direction must be a non-zero vector, got (0, 0, 0)")
    sun = sun / np.linalg.norm(sun)
    d = latlong_directions(h, 2 * h)
    up = np.clip(d[..., 1:2], 0, 1)
    env = np.where(d[..., 1:2] >= 0, sky * (0.6 + 0.4 * up), ground)
    cos_r = np.cos(np.radians(as_finite(sun_radius_deg, "sun_radius_deg", 0, 90, low_inclusive=False)))
    cos_sun = d @ sun
    disc = (cos_sun >= cos_r) | (cos_sun == cos_sun.max())  # at least the pixel nearest the sun
    env = np.where(disc[..., None], sun_radiance, env)
    return env.astype(np.float32)
