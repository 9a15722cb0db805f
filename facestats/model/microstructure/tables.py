"""Kernel tables: filter parameters (α, σ) as piecewise-linear functions of the stretch ratio (Nagano 2015 eq. 8-9).

Nagano et al. 2015 §5 "Kernel Table Construction": the fitted (α, σ) of skin
patches under stretch ratios r (> 1 stretch, < 1 compression) are summarised by
piecewise-linear models; α is continuous and passes through (r = 1, α = 0)
exactly, σ has one line for compression and one for stretching, discontinuous
at r = 1 (harmless: α → 0 there, so the convolved map is continuous).  The
forehead patch gives (eq. 8-9)::

    α = min(1, 15.4 r − 13.8, 3.09 (r − 1))
    σ = 38.2 r − 26.5 µm   (r ≥ 1),   70.5 r − 46.9 µm   (r < 1)

A :class:`KernelTable` stores α by its knots (``np.interp``: linear between
knots, constant beyond the end knots) and σ by its two lines; both are clamped
to the fitted ranges α ∈ [−2, 1], σ ∈ [1, 100] µm.  :data:`FOREHEAD` is eq. 8-9
exactly: its α knots are the points where the lines of eq. 8 meet each other
and the clamp (15.4 r − 13.8 = −2 at r = 0.76623; = 3.09 (r − 1) at
r = 10.71/12.31 = 0.87002; 3.09 (r − 1) = 1 at r = 1.32362) and (1, 0), so
that α(1) is exactly 0 (every table has that knot: the neutral kernel is the
identity and the convolution skips it).  Note Fig. 11's
published points scatter about eq. 8-9 (e.g. r = 1.22: fitted α = 1, table
0.68): the table is a fit, not an interpolation.

Below the measured compressions the ratio is held at the smallest one
(``min_ratio``; 0.73 for :data:`FOREHEAD`, Fig. 11's smallest r).  Resolution of
an extrapolation the paper leaves open: eq. 9's compression line falls to the
1 µm clamp at r = 0.68 and would be negative below r = 0.665, and a 1 µm kernel
is the identity at any texel size skin is mapped at, so extrapolated, the most
compressed skin would get no roughening at all (the rms slope across the axis
× 1.17 at r = 0.8, × 1.06 at 0.73, × 1.00 from 0.68 down, 6 µm texels), against
the paper's "compressed skin becomes rougher".  Held at r = 0.73, every
stronger compression gets that kernel (α = −2, σ = 4.57 µm).  Stretch is not
held: eq. 8-9 grow monotonically there (α reaches 1 at r = 1.32; σ grows), so
more stretch blurs more.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.core.validate import as_finite
from facestats.errors import ValidationError
from facestats.model.microstructure.kernel import ALPHA_RANGE, SIGMA_RANGE_UM

__all__ = ["KernelTable", "FOREHEAD", "TABLES", "FIG11", "kernel_parameters", "fit_kernel_table"]


@dataclass(frozen=True)
class KernelTable:
    """Filter parameters as functions of the stretch ratio r (eq. 8-9 form).

    Attributes
    ----------
    alpha_knots, alpha_values : tuple of float
        α at increasing knots of r (linear between knots, constant outside).
    sigma_compress, sigma_stretch : (slope, intercept)
        σ = slope · r + intercept, µm, for r < 1 and r ≥ 1.
    name : str
    min_ratio : float
        Smallest measured ratio: a smaller r takes its parameters (no extrapolation of the compression line,
        which reaches the 1 µm clamp, an identity kernel, for the forehead); 0 keeps every ratio, in [0, 1).
    """

    alpha_knots: tuple
    alpha_values: tuple
    sigma_compress: tuple
    sigma_stretch: tuple
    name: str = "custom"
    min_ratio: float = 0.0

    def __post_init__(self):
        k = np.asarray(self.alpha_knots, float)
        v = np.asarray(self.alpha_values, float)
        if k.ndim != 1 or k.size < 1 or k.shape != v.shape or np.any(np.diff(k) <= 0) or not np.all(np.isfinite(v)):
            raise ValidationError(
                f"alpha_knots must increase strictly and match alpha_values in length, got {self.alpha_knots!r}"
            )
        for name in ("sigma_compress", "sigma_stretch"):
            line = np.asarray(getattr(self, name), float)
            if line.shape != (2,) or not np.all(np.isfinite(line)):
                raise ValidationError(f"{name} must be (slope, intercept), got {getattr(self, name)!r}")
        if not 0 <= self.min_ratio < 1:  # NaN fails too
            raise ValidationError(f"min_ratio must be a stretch ratio in [0, 1), got {self.min_ratio!r}")

    def alpha(self, r) -> np.ndarray:
        """α(r), clamped to [−2, 1] (eq. 8 form); r below ``min_ratio`` takes α(min_ratio).

        Parameters
        ----------
        r : array_like
            Stretch ratio (> 1 stretch, < 1 compression), finite and > 0.

        Returns
        -------
        ndarray
            α, the shape of ``r``.

        Raises
        ------
        ValidationError
            A non-numeric, non-finite or non-positive ``r``.
        """
        return np.clip(np.interp(self._held(r), self.alpha_knots, self.alpha_values), *ALPHA_RANGE)

    def sigma(self, r) -> np.ndarray:
        """σ(r) in µm, clamped to [1, 100] µm (eq. 9 form); r below ``min_ratio`` takes σ(min_ratio).

        Parameters
        ----------
        r : array_like
            Stretch ratio (> 1 stretch, < 1 compression), finite and > 0.

        Returns
        -------
        ndarray
            σ in µm, the shape of ``r``.

        Raises
        ------
        ValidationError
            A non-numeric, non-finite or non-positive ``r``.
        """
        r = self._held(r)
        (a_c, b_c), (a_s, b_s) = self.sigma_compress, self.sigma_stretch
        with np.errstate(over="ignore", invalid="ignore"):  # a ratio near 1e308 overflows to ±inf: clipped to the range
            return np.clip(np.where(r >= 1, a_s * r + b_s, a_c * r + b_c), *SIGMA_RANGE_UM)

    def __call__(self, r):
        """(α, σ in µm) of the kernel at stretch ratio ``r`` (Nagano et al. 2015 eq. 8-9)."""
        return self.alpha(r), self.sigma(r)

    def _held(self, r) -> np.ndarray:
        """r checked (finite, > 0), ratios below ``min_ratio`` raised to it."""
        return np.maximum(_ratio(r), self.min_ratio)


def _ratio(r) -> np.ndarray:
    return as_finite(r, "r", 0.0, low_inclusive=False)


#: Nagano et al. 2015 Fig. 11: fitted (r, α, σ µm) of a forehead patch.
FIG11 = (
    (0.73, -2.0, 6.5),
    (0.79, -1.76, 6.5),
    (0.88, -0.2, 13.0),
    (0.94, -0.02, 22.0),
    (1.08, 0.54, 14.5),
    (1.15, 0.27, 19.0),
    (1.22, 1.0, 17.0),
    (1.28, 1.0, 24.0),
)


def _forehead() -> KernelTable:
    """Eq. 8-9 (forehead patch) as a :class:`KernelTable` (knots where the lines of eq. 8 meet)."""
    r_clamp = (13.8 + ALPHA_RANGE[0]) / 15.4  # 15.4 r - 13.8 = -2
    r_meet = (13.8 - 3.09) / (15.4 - 3.09)  # 15.4 r - 13.8 = 3.09 (r - 1)
    r_top = 1 + 1 / 3.09  # 3.09 (r - 1) = 1
    return KernelTable(
        alpha_knots=(r_clamp, r_meet, 1.0, r_top),
        alpha_values=(ALPHA_RANGE[0], 3.09 * (r_meet - 1), 0.0, 1.0),
        sigma_compress=(70.5, -46.9),
        sigma_stretch=(38.2, -26.5),
        name="forehead",
        min_ratio=min(r for r, _, _ in FIG11),
    )


#: Nagano et al. 2015 eq. 8-9, the forehead patch (the default table).
FOREHEAD = _forehead()
#: Tables by name.
TABLES = {"forehead": FOREHEAD}


def _table(table) -> KernelTable:
    if isinstance(table, KernelTable):
        return table
    if table in TABLES:
        return TABLES[table]
    raise ValidationError(f"table must be a KernelTable or one of {sorted(TABLES)}, got {table!r}")


def kernel_parameters(r, table="forehead"):
    """Kernel parameters (α, σ µm) for stretch ratios r (Nagano et al. 2015 eq. 8-9).

    Parameters
    ----------
    r : float or array_like
        Stretch ratio(s), > 0 (> 1 stretch, < 1 compression).
    table : str or KernelTable
        ``"forehead"`` (eq. 8-9, the default) or a table from :func:`fit_kernel_table`.

    Returns
    -------
    alpha, sigma_um : ndarray
        α ∈ [−2, 1] and σ ∈ [1, 100] µm, shaped like ``r``.
    """
    return _table(table)(r)


def fit_kernel_table(r, alpha, sigma_um, alpha_knots, *, name="custom") -> KernelTable:
    """Fit a kernel table to per-patch fits (Nagano et al. 2015 §5 "Kernel Table Construction", Fig. 12).

    α: the continuous piecewise-linear function of ``alpha_knots`` (interpolation
    between knots, constant outside) that fits the points in least squares
    subject to α(1) = 0 (a Lagrange multiplier; 1 need not be a knot).  σ: one
    least-squares line through the compression points (r < 1) and one through
    the stretch points (r ≥ 1).  Ratios below the smallest fitted one take its
    parameters (``min_ratio``, as :data:`FOREHEAD` does).

    Parameters
    ----------
    r, alpha, sigma_um : array_like, shape (n,)
        Stretch ratios and the fitted α and σ (µm) of each patch.
    alpha_knots : array_like
        Increasing knots of α chosen by inspecting the data (the paper partitions "manually").
    name : str

    Returns
    -------
    KernelTable
    """
    r = as_finite(r, "r", 0.0, low_inclusive=False).reshape(-1)
    a = as_finite(alpha, "alpha", *ALPHA_RANGE).reshape(-1)
    s = as_finite(sigma_um, "sigma_um", 0.0, unit="um").reshape(-1)
    knots = as_finite(alpha_knots, "alpha_knots").reshape(-1)
    if not (r.shape == a.shape == s.shape):
        raise ValidationError(
            f"r, alpha and sigma_um must have one value per patch, got {r.shape}, {a.shape}, {s.shape}"
        )
    if knots.size < 1 or np.any(np.diff(knots) <= 0):
        raise ValidationError(f"alpha_knots must increase strictly, got {knots.tolist()}")
    basis = np.stack([np.interp(r, knots, np.eye(knots.size)[k]) for k in range(knots.size)], 1)  # hat functions
    at_one = np.array([np.interp(1.0, knots, np.eye(knots.size)[k]) for k in range(knots.size)])
    kkt = np.block([[basis.T @ basis, at_one[:, None]], [at_one[None, :], np.zeros((1, 1))]])
    rhs = np.concatenate([basis.T @ a, [0.0]])
    values = np.linalg.lstsq(kkt, rhs, rcond=None)[0][:-1]
    if not np.any(knots == 1.0):  # a knot at (1, 0) makes the neutral kernel the identity exactly
        at = np.searchsorted(knots, 1.0)
        knots, values = np.insert(knots, at, 1.0), np.insert(values, at, 0.0)
    values[knots == 1.0] = 0.0
    lines = []
    for side, sel in (("compression (r < 1)", r < 1), ("stretch (r >= 1)", r >= 1)):
        distinct = np.unique(r[sel])
        if distinct.size < 2:  # one ratio (or none) leaves the line's slope undetermined
            raise ValidationError(
                f"r must hold at least 2 distinct {side} ratios to fit sigma's line, got "
                f"{np.count_nonzero(sel)} patch(es) at {distinct.tolist()}"
            )
        slope, intercept = np.polyfit(r[sel], s[sel], 1)
        lines.append((float(slope), float(intercept)))
    return KernelTable(
        tuple(knots.tolist()), tuple(values.tolist()), lines[0], lines[1], name=name, min_ratio=float(r.min())
    )
