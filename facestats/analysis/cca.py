"""Canonical correlation analysis of two blocks of variables (Weyrich et al. 2006 §7, Fig. 16).

This module holds the method (:func:`cca`) and its result
(:class:`CCAResult`, with its JSON document and summary); the paper's
application to the BRDF and the experimental variables is
:func:`facestats.analysis.brdf_cca.brdf_cca`.

Weyrich et al. store, per subject, the region means of the Torrance-Sparrow
parameters (10 regions × (ρs, m)) with gender [0 = M, 1 = F], age and skin
type [II-VI] in a 23 × 149 matrix, and run CCA (Green et al. 1966) between the
BRDF block and the experimental variables.  They report principal correlations
0.768 and 0.585 and direct correlations 0.766 (skin type), 0.573 (gender) and
0.537 (age).

Method (Hotelling 1936; Mardia, Kent & Bibby 1979 §10.2)
---------------------------------------------------------
With centred blocks X (n × p) and Y (n × q) and covariance blocks Σxx, Σyy,
Σxy (divisor n − 1), the whitening maps Wx = Σxx^(−1/2), Wy = Σyy^(−1/2)
(symmetric inverse square roots, pseudo-inverse on the null space) give
K = Wx Σxy Wy.  Its SVD K = U diag(r) Vᵀ yields the canonical correlations r
(descending; equivalently r² are the eigenvalues of Σxx⁻¹ΣxyΣyy⁻¹Σyx), the
canonical weights a = Wx U, b = Wy V and the canonical variates (projections)
u = (X − x̄) a, v = (Y − ȳ) b, each with unit variance and corr(u_i, v_i) = r_i.

* Direct correlations: the canonical correlation of each experimental
  variable alone with the BRDF block, i.e. its multiple correlation
  coefficient R = sqrt(σ_yx Σxx⁻¹ σ_xy / σ_yy), with the F test of R = 0,
  F = (R²/p)/((1 − R²)/(n − p − 1)) on (p, n − p − 1) degrees of freedom.
* Asymptotic test (Bartlett 1938): for dimension i (0-based),
  Λ_i = Π_{j ≥ i}(1 − r_j²) (Wilks' lambda) and
  χ² = −(n − 1 − (p + q + 1)/2) ln Λ_i with (p − i)(q − i) degrees of freedom
  tests H0: r_i = r_{i+1} = … = 0.
* Permutation test of independence: the rows of Y are permuted (seeded) and Λ_0
  recomputed; p = (1 + #{Λ_0^perm ≤ Λ_0}) / (B + 1), an exact test of H0: the blocks
  are independent (all r_i = 0).  It is run for the first dimension only: for
  i > 0 the same comparison tests Λ_i against full independence, while its null
  keeps the leading correlations, so it is anti-conservative, not conservative as
  this docstring said before 2026-12-06 (an audit: with two real dimensions of
  149 subjects, 20 and 3 variables, it rejected a null third dimension at α = 0.05
  in 47.5 % of 80 simulations, Bartlett's test in 6.3 %).  A valid test of later
  dimensions removes the leading canonical variates first (Winkler et al. 2020,
  *Permutation inference for canonical correlation analysis*, NeuroImage 220);
  facestats reports Bartlett's test for them.
* Regularisation (optional): shrinkage of each covariance block towards its
  diagonal, Σ ← (1 − λ)Σ + λ diag(Σ), λ ∈ [0, 1]; it keeps CCA defined when a
  block has nearly as many variables as subjects.  With λ > 0 the reported
  correlations are the regularised criterion, not plain correlations (they
  can exceed 1); the asymptotic tests are then not defined (NaN) and the
  permutation test uses Σ_{j ≥ i} r_j² in place of Λ_i.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facestats.analysis.population import MODEL_NAMES
from facestats.analysis.serialize import json_ready, records
from facestats.core.published import CCA_DIRECT, CCA_PRINCIPAL
from facestats.core.validate import as_float, as_scalar, check_integer, check_range, check_seed
from facestats.errors import InsufficientDataError, ValidationError

__all__ = ["CCAResult", "cca"]


@dataclass(frozen=True)
class CCAResult:
    """Result of :func:`cca`.

    Attributes
    ----------
    correlations : ndarray, shape (k,)
        Canonical correlations, descending (k = min(rank X, rank Y)).
    x_weights, y_weights : ndarray, shape (p, k), (q, k)
        Canonical weights applied to the centred blocks.
    projections : ndarray, shape (n, k)
        Canonical variates of the X block (the BRDF data projected on the
        canonical directions; what Fig. 16 plots), unit variance.
    y_projections : ndarray, shape (n, k)
        Canonical variates of the Y block.
    x_loadings, y_loadings : ndarray, shape (p, k), (q, k)
        Structure correlations corr(variable, own canonical variate).
    direct_correlations : ndarray, shape (q,)
        Multiple correlation of each Y variable with the X block.
    direct_p_value : ndarray, shape (q,)
        F-test p-value of each direct correlation (H0: R = 0; NaN when
        regularised or n ≤ p + 1).  With many BRDF variables R is biased
        upwards: under H0, E[R²] = p/(n − 1) (≈ 0.14, R ≈ 0.37 for the
        paper's 20 variables and 149 subjects).
    wilks_lambda, chi2, df, p_value : ndarray, shape (k,)
        Bartlett's asymptotic test of H0: r_i = … = r_k = 0, per dimension.
    permutation_p : ndarray, shape (k,) or None
        Permutation p-value of independence in entry 0; NaN for the later dimensions, which have
        none (module docstring); None if not run.
    n_permutations : int
    x_names, y_names : tuple of str
    index : tuple
        Row labels (subject ids) of the projections.
    x_mean, y_mean : ndarray
    regularization : tuple of float
    y_data : pandas.DataFrame or None
        The Y block as given (for plotting colour/marker/size encodings).
    dropped : tuple
        Row labels left out for missing values.
    seed : int
        Seed of the permutations.
    model : str or None
        Specular model of the BRDF block (``brdf_cca``; None for a plain :func:`cca`).
    coding : dict or None
        How ``brdf_cca`` coded the Y variables
        (:data:`facestats.analysis.brdf_cca.CODING`), else None.
    """

    correlations: np.ndarray
    x_weights: np.ndarray
    y_weights: np.ndarray
    projections: np.ndarray
    y_projections: np.ndarray
    x_loadings: np.ndarray
    y_loadings: np.ndarray
    direct_correlations: np.ndarray
    direct_p_value: np.ndarray
    wilks_lambda: np.ndarray
    chi2: np.ndarray
    df: np.ndarray
    p_value: np.ndarray
    permutation_p: np.ndarray | None
    n_permutations: int
    x_names: tuple
    y_names: tuple
    index: tuple
    x_mean: np.ndarray
    y_mean: np.ndarray
    regularization: tuple
    y_data: object = None
    dropped: tuple = field(default_factory=tuple)
    seed: int = 0
    model: str | None = None
    coding: dict | None = None

    @property
    def n(self) -> int:
        """Number of observations (subjects) used."""
        return int(self.projections.shape[0])

    @property
    def x_projections(self) -> np.ndarray:
        """Alias of :attr:`projections`."""
        return self.projections

    def direct(self):
        """Direct correlations as a :class:`pandas.Series` indexed by the Y variable names."""
        import pandas as pd

        return pd.Series(self.direct_correlations, index=list(self.y_names), name="direct_correlation")

    def direct_table(self):
        """Direct correlations with their F-test p-values, one row per Y variable."""
        import pandas as pd

        return pd.DataFrame(
            {"direct_correlation": self.direct_correlations, "p_value": self.direct_p_value},
            index=pd.Index(list(self.y_names), name="variable"),
        )

    def summary(self):
        """Per-dimension table: correlation, Wilks' Λ, χ², df, asymptotic and permutation p-values."""
        import pandas as pd

        table = pd.DataFrame(
            {
                "correlation": self.correlations,
                "wilks_lambda": self.wilks_lambda,
                "chi2": self.chi2,
                "df": self.df,
                "p_value": self.p_value,
            },
            index=pd.RangeIndex(1, len(self.correlations) + 1, name="dimension"),
        )
        if self.permutation_p is not None:
            table["permutation_p"] = self.permutation_p
        return table

    def to_frame(self):
        """One row per subject (observation) used: its canonical variates, the points of Fig. 16.

        The per-dimension statistics are :meth:`summary`, the direct correlations :meth:`direct_table`.

        Returns
        -------
        pandas.DataFrame
            Index ``subject_id`` (:attr:`index`, the rows used; :attr:`dropped` are not in it).  Columns
            ``dimension_1`` … ``dimension_k``: the X block's canonical variates (:attr:`projections`, unit
            variance; ``to_dict()["projections"]`` holds the first two), ``y_dimension_1`` … ``y_dimension_k``: the
            Y block's (:attr:`y_projections`), then the Y variables as the analysis coded them (:attr:`y_data`,
            named by :attr:`y_names`; left out when unknown).
        """
        import pandas as pd

        k = self.projections.shape[1]
        columns = {f"dimension_{i + 1}": self.projections[:, i] for i in range(k)}
        columns.update({f"y_dimension_{i + 1}": self.y_projections[:, i] for i in range(k)})
        frame = pd.DataFrame(columns, index=pd.Index([str(s) for s in self.index], name="subject_id"))
        if self.y_data is not None:
            frame[list(self.y_names)] = pd.DataFrame(self.y_data)[list(self.y_names)].to_numpy()
        return frame

    def transform(self, X, Y=None):
        """Canonical variates of new data: (X − x̄)·a (and (Y − ȳ)·b if Y is given).

        Parameters
        ----------
        X : array_like or pandas.DataFrame, shape (m, p)
            New X-block rows: a DataFrame's columns are taken by the names ``x_names`` (others are ignored), an
            array's by position, in the order of ``x_names``; 1-D is one variable.
        Y : array_like or pandas.DataFrame, shape (m, q), optional
            New Y-block rows, likewise with ``y_names``.

        Returns
        -------
        ndarray, shape (m, k), or tuple of two
            The X variates, or (X variates, Y variates) if ``Y`` is given.

        Raises
        ------
        ValidationError
            ``X`` or ``Y`` not numeric, not 1-D or 2-D, a DataFrame without one of the fitted columns, or an array
            with another number of columns.
        """
        x = _new_block(X, "X", self.x_names) - self.x_mean
        if Y is None:
            return x @ self.x_weights
        return x @ self.x_weights, (_new_block(Y, "Y", self.y_names) - self.y_mean) @ self.y_weights

    def compare_published(self):
        """Principal and direct correlations beside Weyrich Fig. 16 (:mod:`facestats.core.published`).

        Returns
        -------
        pandas.DataFrame
            Index ``quantity``: ``principal r1``, ``principal r2`` (as far as
            there are canonical dimensions), then ``direct <variable>`` per Y
            variable; columns ``ours`` and ``paper`` (NaN for a variable the
            paper does not report).  The paper's values are those of its
            Torrance-Sparrow fit, whatever :attr:`model`.
        """
        import pandas as pd

        rows = [
            {"quantity": f"principal r{i + 1}", "ours": self.correlations[i], "paper": p}
            for i, p in enumerate(CCA_PRINCIPAL)
            if i < self.correlations.size
        ]
        rows += [
            {"quantity": f"direct {name}", "ours": r, "paper": CCA_DIRECT.get(name, float("nan"))}
            for name, r in zip(self.y_names, self.direct_correlations)
        ]
        return pd.DataFrame.from_records(rows).set_index("quantity")

    def to_dict(self) -> dict:
        """The JSON document of the analysis (``facestats analyze cca`` writes it as ``cca.json``).

        Keys (conventions: :mod:`facestats.analysis.serialize`): ``model``,
        ``n_subjects``, ``x_variables``, ``y_variables``, ``coding``,
        ``principal_correlations`` (all, descending), ``published_principal``,
        ``direct_correlations`` and ``direct_p_value`` (by variable),
        ``published_direct``, ``dimensions`` (per canonical dimension:
        ``dimension, correlation, wilks_lambda, chi2, df, p_value,
        permutation_p``), ``n_permutations``, ``seed``, ``y_loadings`` (by
        variable, per dimension), ``dropped`` (subjects left out),
        ``projections`` (``subject_id`` and the canonical variates
        ``dimension_1``, ``dimension_2``: the points of Fig. 16).
        """

        dims = records(self.summary())
        if self.permutation_p is None:
            for d in dims:
                d["permutation_p"] = None
        projections = {"subject_id": [str(s) for s in self.index]}
        for i in range(min(2, self.projections.shape[1])):
            projections[f"dimension_{i + 1}"] = self.projections[:, i]
        doc = {
            "model": self.model,
            "n_subjects": self.n,
            "x_variables": list(self.x_names),
            "y_variables": list(self.y_names),
            "coding": self.coding,
            "principal_correlations": self.correlations,
            "published_principal": list(CCA_PRINCIPAL),
            "direct_correlations": dict(zip(self.y_names, self.direct_correlations)),
            "direct_p_value": dict(zip(self.y_names, self.direct_p_value)),
            "published_direct": dict(CCA_DIRECT),
            "dimensions": dims,
            "n_permutations": self.n_permutations,
            "seed": self.seed,
            "y_loadings": {n: self.y_loadings[j] for j, n in enumerate(self.y_names)},
            "dropped": [str(s) for s in self.dropped],
            "projections": projections,
        }
        return json_ready(doc)

    def to_text(self) -> str:
        """Correlations beside Fig. 16 and the tests' p-values (what ``facestats analyze cca`` prints)."""
        what = f"the {MODEL_NAMES[self.model]} region means" if self.model else "X"
        paper = "Weyrich 2006" + (" (TS)" if self.model != "ts" else "")
        lines = [
            f"CCA of {what} ({len(self.x_names)} variables) against {', '.join(self.y_names)}: {self.n} subjects "
            "(Weyrich Fig. 16)",
            f"{'':<22}{'ours':>7}  {paper:>12}",
        ]
        for name, row in self.compare_published().iterrows():
            lines.append(f"{name:<22}{row['ours']:7.3f}  {row['paper']:>12.3f}")
        if self.permutation_p is not None:
            lines.append(
                f"permutation test of independence ({self.n_permutations} permutations): p = "
                f"{self.permutation_p[0]:.3g} (dimension 1; later dimensions: Bartlett's test below)"
            )
        lines.append("Bartlett chi2 test: p = " + ", ".join(f"{p:.3g}" for p in self.p_value))
        if self.dropped:
            lines.append(f"left out (missing region means): {len(self.dropped)} subject(s)")
        return "\n".join(lines)


def _as_block(a, name):
    """(values as float64 2-D array, column names, row labels) of an array or DataFrame."""
    import pandas as pd

    if isinstance(a, pd.Series):
        a = a.to_frame()
    if isinstance(a, pd.DataFrame):
        values = as_float(a.to_numpy(dtype=np.float64, na_value=np.nan), name, np.float64)
        names, rows = tuple(str(c) for c in a.columns), tuple(a.index)
    else:
        values = as_float(a, name, np.float64)
        if values.ndim == 1:
            values = values[:, None]
        if values.ndim != 2:
            raise ValidationError(f"{name} must be 1-D or 2-D (subjects as rows), got shape {values.shape}")
        names, rows = tuple(f"{name.lower()}{j}" for j in range(values.shape[1])), tuple(range(values.shape[0]))
    if values.shape[1] == 0:
        raise ValidationError(f"{name} must hold at least one variable (column), got shape {values.shape}")
    return values, names, rows


def _new_block(a, name, names):
    """Values of new rows of a fitted block: a DataFrame's (or Series') columns by ``names``, an array's by
    position, with as many columns as ``names``."""
    import pandas as pd

    if isinstance(a, pd.Series):
        a = a.to_frame()
    if isinstance(a, pd.DataFrame):
        columns = {str(c): c for c in a.columns}
        missing = [n for n in names if n not in columns]
        if missing:
            raise ValidationError(
                f"{name} must have the fitted columns {list(names)}, got {[str(c) for c in a.columns]} "
                f"(missing {missing}; pass an array to take columns by position)"
            )
        a = a[[columns[n] for n in names]]
    values = _as_block(a, name)[0]
    if values.shape[1] != len(names):
        raise ValidationError(
            f"{name} must have {len(names)} columns (in the order {list(names)}), got shape {values.shape}"
        )
    return values


def _shrink(cov, lam):
    """(1 − λ)Σ + λ diag(Σ)."""
    return (1 - lam) * cov + lam * np.diag(np.diag(cov))


def _whitener(cov, rcond=1e-10):
    """Inverse square root of a symmetric PSD matrix restricted to its range, shape (p, rank)."""
    w, v = np.linalg.eigh(cov)
    top = w.max() if w.size else 0.0
    keep = w > rcond * max(top, np.finfo(float).tiny)
    return v[:, keep] / np.sqrt(w[keep])


def _centred(x, mean):
    """``x − mean`` with the columns of one repeated value exactly 0.

    Centring a constant column can leave a rounding residual (0.1 − mean(0.1, …) = −4e-17), which
    :func:`_unit_scaled` would scale up to a column of ±1: a variable that passes the ``rcond`` cut and
    changes the degrees of freedom and p-values (a red team).
    """
    xc = x - mean
    xc[:, np.ptp(x, axis=0) == 0] = 0.0
    return xc


def _unit_scaled(xc):
    """``(xc / s, s)`` with s the largest magnitude of each column (1 for a column of zeros)."""
    s = np.max(np.abs(xc), axis=0, initial=0.0)
    s = np.where(s > 0, s, 1.0)
    return xc / s, s


def _canonical(xw, yw, upper=1.0):
    """Canonical correlations and rotations of whitened blocks (n × rx, n × ry).

    Singular values are clipped to [0, ``upper``] (1 for plain CCA, where larger
    values are rounding; ``inf`` when regularised, where the criterion is not a
    correlation and may exceed 1).
    """
    k = xw.T @ yw / (xw.shape[0] - 1)
    u, s, vt = np.linalg.svd(k, full_matrices=False)
    return np.clip(s, 0.0, upper), u, vt.T


def _wilks(r):
    """Wilks' Λ_i = Π_{j ≥ i}(1 − r_j²) for each i, along the last axis."""
    return np.cumprod((1 - r**2)[..., ::-1], axis=-1)[..., ::-1]


def _dependence(r, plain):
    """Permutation statistic per dimension i, larger = more dependent: −ln Λ_i, or Σ_{j ≥ i} r_j² if regularised."""
    if plain:
        with np.errstate(divide="ignore"):
            return -np.log(_wilks(r))
    return np.cumsum((r**2)[..., ::-1], axis=-1)[..., ::-1]


def cca(X, Y, *, regularization=0.0, n_permutations=0, seed=0, missing="raise", rcond=1e-10):
    """Canonical correlation analysis of two blocks of variables (subjects as rows).

    See the module docstring for the method (whitening by the covariance
    blocks and SVD), the direct correlations and the tests.

    Parameters
    ----------
    X : array_like or pandas.DataFrame, shape (n, p)
        First block (the BRDF parameters in Weyrich Fig. 16).
    Y : array_like or pandas.DataFrame, shape (n, q)
        Second block (the experimental variables).
    regularization : float or (float, float)
        Shrinkage λ ∈ [0, 1] of Σxx (and Σyy) towards their diagonals.
    n_permutations : int
        Number of row permutations of Y for the permutation test (0: skip).
    seed : int
        Seed of the permutations.
    missing : {"raise", "drop"}
        What to do with rows holding a non-finite value.
    rcond : float
        Eigenvalues of a covariance block below ``rcond`` × its largest are
        treated as zero (collinear or constant variables).

    Returns
    -------
    CCAResult

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> z = rng.standard_normal(500)
    >>> X = np.c_[z + 0.5 * rng.standard_normal(500), rng.standard_normal(500)]
    >>> Y = np.c_[z + 0.5 * rng.standard_normal(500)]
    >>> res = cca(X, Y)
    >>> res.correlations.shape, bool(0.7 < res.correlations[0] < 0.9)
    ((1,), True)
    """
    import pandas as pd

    rcond = as_scalar(rcond, "rcond", 0, 1, high_inclusive=False)
    x, y, x_names, y_names, index, dropped, reg = _complete_blocks(X, Y, regularization, n_permutations, missing, seed)
    n, q = x.shape[0], y.shape[1]
    x_mean, y_mean = x.mean(axis=0), y.mean(axis=0)
    # Each centred variable divided by its largest magnitude: the correlations do not depend on the units, but
    # `rcond` compares eigenvalues across variables (a variable in metres beside others in millimetres was
    # dropped as collinear) and covariances of values near 1e±160 under- or overflow (a red team).
    (xc, sx), (yc, sy) = _unit_scaled(_centred(x, x_mean)), _unit_scaled(_centred(y, y_mean))
    sxx = _shrink(xc.T @ xc / (n - 1), reg[0])
    syy = _shrink(yc.T @ yc / (n - 1), reg[1])
    wx, wy = _whitener(sxx, rcond), _whitener(syy, rcond)
    xw, yw = xc @ wx, yc @ wy
    plain = not reg.any()
    if plain and n - 1 < wx.shape[1] + wy.shape[1]:
        raise InsufficientDataError(_too_few_rows(n, xc, yc, wx.shape[1], wy.shape[1]))
    upper = 1.0 if plain else np.inf
    r, u, v = _canonical(xw, yw, upper)
    a, b, proj_x, proj_y, x_load, y_load = _oriented(xc, yc, wx @ u, wy @ v)
    a, b = a / sx[:, None], b / sy[:, None]  # weights of the variables in their own units

    # Direct correlations: CCA of the X block with each Y variable alone.
    direct = np.full(q, np.nan)
    for j in range(q):
        yj = yc[:, j : j + 1]
        wj = _whitener(_shrink(yj.T @ yj / (n - 1), reg[1]), rcond)
        if wj.shape[1]:
            direct[j] = _canonical(xw, yj @ wj, upper)[0][0]
    rx, ry = wx.shape[1], wy.shape[1]
    direct_p = _direct_p_value(direct, rx, n, plain)
    lam, stat, pval, df = _bartlett(r, rx, ry, n, plain)
    perm_p = _permutation_p(xw, yw, r, plain, upper, n_permutations, seed) if n_permutations else None

    y_data = pd.DataFrame(y, index=pd.Index(list(index)), columns=list(y_names))
    return CCAResult(
        correlations=r,
        x_weights=a,
        y_weights=b,
        projections=proj_x,
        y_projections=proj_y,
        x_loadings=x_load,
        y_loadings=y_load,
        direct_correlations=direct,
        direct_p_value=direct_p,
        wilks_lambda=lam,
        chi2=stat,
        df=df.astype(np.int64),
        p_value=pval,
        permutation_p=perm_p,
        n_permutations=int(n_permutations),
        x_names=x_names,
        y_names=y_names,
        index=index,
        x_mean=x_mean,
        y_mean=y_mean,
        regularization=(float(reg[0]), float(reg[1])),
        y_data=y_data,
        dropped=dropped,
        seed=seed,
    )


def _too_few_rows(n, xc, yc, rx, ry):
    """The message of a plain CCA with too few rows for its variables (:func:`cca` refuses it).

    The centred rows span at most n − 1 dimensions, so the whitened blocks have ranks rx, ry ≤ n − 1; when
    rx + ry > n − 1, some combination of X equals one of Y exactly, whatever the data, and every test
    statistic is meaningless.  The condition n − 1 ≥ rx + ry holds for generic data from n = p + q + 1 rows on,
    where p and q count the variables that are not constant (a constant column has rank 0 at any n; a
    collinear combination of others, which only more rows can reveal, lowers the need).  The ranks after
    whitening cannot state the need: they are capped by the rows at hand (12 rows of 20 variables: rank 11),
    which made the hint ask for 3 rows more than there were, whatever their number.
    """
    p, q = int(np.count_nonzero(np.any(xc, axis=0))), int(np.count_nonzero(np.any(yc, axis=0)))
    return (
        f"cca needs more complete rows (subjects) than variables: {n} rows for {p} + {q} variables "
        f"(X, Y; ranks {rx} + {ry} at these rows, which span at most {n - 1} dimensions) give a canonical "
        f"correlation of 1 by construction (need at least {p + q + 1} rows: {p} + {q} + 1, fewer only if some "
        "variables are linear combinations of others; the Python API's cca(regularization=) shrinks the "
        "covariances instead, at the price of a criterion that is no longer a correlation)"
    )


def _complete_blocks(X, Y, regularization, n_permutations, missing, seed=0):
    """Checked blocks without incomplete rows: x, y, x_names, y_names, row labels kept and dropped, (λx, λy)."""
    x, x_names, x_index = _as_block(X, "X")
    y, y_names, _ = _as_block(Y, "Y")
    if x.shape[0] != y.shape[0]:
        raise ValidationError(
            f"X and Y must have the same number of rows (subjects), got {x.shape[0]} and {y.shape[0]}"
        )
    reg = np.asarray(regularization, dtype=np.float64)
    if reg.shape not in ((), (1,), (2,)):
        raise ValidationError(
            f"regularization must be one value or (value for X, value for Y), got {np.asarray(regularization).tolist()}"
        )
    reg = np.broadcast_to(reg.reshape(-1), (2,))
    check_range(reg, "regularization", 0, 1)
    if missing not in ("raise", "drop"):
        raise ValidationError(f"missing must be 'raise' or 'drop', got {missing!r}")
    check_integer(n_permutations, "n_permutations", 0)
    check_seed(seed)  # every argument before any statement about the data
    ok = np.all(np.isfinite(x), axis=1) & np.all(np.isfinite(y), axis=1)
    if not ok.all() and missing == "raise":
        raise ValidationError(
            f"X and Y must be finite, got {int((~ok).sum())} row(s) with missing values (use missing='drop')"
        )
    dropped = tuple(lab for lab, k in zip(x_index, ok) if not k)
    x, y = x[ok], y[ok]
    index = tuple(lab for lab, k in zip(x_index, ok) if k)
    if x.shape[0] < 3:
        raise InsufficientDataError(f"cca needs at least 3 complete rows, got {x.shape[0]}")
    return x, y, x_names, y_names, index, dropped, reg


def _oriented(xc, yc, a, b):
    """Canonical weights, variates and structure correlations, oriented.

    Each dimension is signed so that the Y variable loading most on it loads
    positively.  Returns (a, b, x variates, y variates, x loadings, y loadings).
    """
    n = xc.shape[0]
    proj_x, proj_y = xc @ a, yc @ b
    sd_x, sd_y = xc.std(axis=0, ddof=1), yc.std(axis=0, ddof=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        x_load = (xc.T @ proj_x / (n - 1)) / sd_x[:, None] / proj_x.std(axis=0, ddof=1)
        y_load = (yc.T @ proj_y / (n - 1)) / sd_y[:, None] / proj_y.std(axis=0, ddof=1)
    lead = np.argmax(np.abs(np.nan_to_num(y_load)), axis=0)
    sign = np.sign(y_load[lead, np.arange(y_load.shape[1])])
    sign[~np.isfinite(sign) | (sign == 0)] = 1.0
    return a * sign, b * sign, proj_x * sign, proj_y * sign, x_load * sign, y_load * sign


def _direct_p_value(direct, rx, n, plain):
    """F-test p-value of each multiple correlation (exact under normality), NaN where undefined.

    F = (R²/p) / ((1 − R²)/(n − p − 1)) on (p, n − p − 1) degrees of freedom: the overall F-test of
    a least-squares regression with intercept on p predictors, whose null distribution under
    normality is Fisher's (1928, "The general sampling distribution of the multiple correlation
    coefficient", Proc. R. Soc. A 121).
    """
    from scipy.stats import f as f_dist

    dof2 = n - rx - 1
    direct_p = np.full(direct.size, np.nan)
    if dof2 > 0 and plain:
        r2 = direct**2
        with np.errstate(divide="ignore", invalid="ignore"):
            direct_p = f_dist.sf((r2 / rx) / ((1 - r2) / dof2), rx, dof2)
    return direct_p


def _bartlett(r, rx, ry, n, plain):
    """Bartlett's chi-square approximation to Wilks' lambda per dimension: (Λ, χ², p, df) (NaN unless plain CCA).

    For dimension k (0-based), Λ_k = Π_{i≥k} (1 − r_i²) and −[n − 1 − (p + q + 1)/2] ln Λ_k is
    approximately χ² on (p − k)(q − k) degrees of freedom under the hypothesis that the canonical
    correlations from k on are zero (Bartlett 1941, "The statistical significance of canonical
    correlations", Biometrika 32; Mardia, Kent & Bibby 1979 §10.2).  p = ``rx``, q = ``ry``.
    """
    from scipy.stats import chi2 as chi2_dist

    k = r.size
    dims = np.arange(k)
    df = (rx - dims) * (ry - dims)
    factor = n - 1 - (rx + ry + 1) / 2
    lam = _wilks(r) if plain else np.full(k, np.nan)
    stat, pval = np.full(k, np.nan), np.full(k, np.nan)
    if plain and factor > 0:
        with np.errstate(divide="ignore"):
            stat = -factor * np.log(lam)
        pval = chi2_dist.sf(stat, df)
    return lam, stat, pval, df


def _permutation_p(xw, yw, r, plain, upper, n_permutations, seed):
    """Permutation p-value of independence, (1 + #{statistic of permuted Y rows ≥ observed}) / (B + 1), in entry 0
    of a (k,) array whose later entries are NaN (module docstring: no valid test of them by plain permutation)."""
    n, k = xw.shape[0], r.size
    rng = np.random.default_rng(check_seed(seed))
    observed = _dependence(r, plain)[0]
    count = 0
    done = 0
    while done < n_permutations:
        b_n = min(256, n_permutations - done)
        perms = rng.permuted(np.tile(np.arange(n), (b_n, 1)), axis=1)
        kb = np.einsum("ni,bnj->bij", xw, yw[perms]) / (n - 1)
        rb = np.clip(np.linalg.svd(kb, compute_uv=False), 0.0, upper)[:, :k]
        count += int(np.sum(_dependence(rb, plain)[:, 0] >= observed * (1 - 1e-12)))
        done += b_n
    out = np.full(k, np.nan)
    out[0] = (1 + count) / (n_permutations + 1)
    return out
