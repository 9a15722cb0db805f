"""Per-region PCA of the specular BRDF parameters (Weyrich et al. 2006 §7, Fig. 15 right).

"For each region [...] we computed a 2 × n matrix [...], where n is the total
number of samples in that region for all subjects.  We then performed a
Principal Component Analysis (PCA) on each matrix.  The resulting eigenvectors
and eigenvalues are the directions and size of the ellipse axis, respectively.
The centers of the ellipses have been translated to the mean values of the
BRDF parameters for that region."

Conventions
-----------
* The two variables are the raw parameters (ρs, m) for Torrance-Sparrow or
  (ρs, n) for Blinn-Phong, unscaled, as in the paper; both are dimensionless.
* Eigenvalues are the variances along the principal axes (sample covariance,
  ``ddof=1`` by default), sorted in descending order; eigenvectors are unit
  columns, each signed so that its largest-magnitude component is positive.
* Drawn ellipses have half-axes k·σ_i = k·sqrt(λ_i) along the eigenvectors,
  **k = 1 by default**.  §7 calls the eigenvalues "the size of the ellipse
  axis"; read literally, a half-axis λ would not even carry the parameters'
  units, so facestats draws σ = sqrt(λ) and says so.  A 1σ ellipse holds only
  39 % of a bivariate normal (k = 2.45 holds 95 %);
  :meth:`RegionEllipse.half_axes` and the plot take ``k``.

:class:`RegionPCA` also gives the region orderings the paper discusses
(:meth:`RegionPCA.orderings`, beside the paper's in
:meth:`RegionPCA.compare_published`), the JSON document and the summary of
``facestats analyze pca``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facestats.analysis.population import (
    MODEL_NAMES,
    index_columns,
    population_index,
    region_samples,
    select_population,
)
from facestats.analysis.serialize import json_ready
from facestats.core.conventions import REGION_IDS, REGIONS
from facestats.core.published import HIGHEST_RHO_S, LARGEST_VARIANCE, SMALLEST_M
from facestats.core.validate import as_float, check_choice, check_finite, check_integer, check_shape
from facestats.errors import ValidationError

__all__ = [
    "principal_axes",
    "covariance_axes",
    "pooled_moments",
    "has_index_moments",
    "RegionEllipse",
    "RegionPCA",
    "region_pca",
    "region_sample_frame",
]


def principal_axes(samples, ddof=1):
    """Mean, eigenvalues and eigenvectors of the covariance of 2-D (or d-D) samples.

    Eigen-decomposition of the sample covariance Σ = (X − x̄)ᵀ(X − x̄)/(n − ddof)
    (Weyrich et al. 2006 §7 PCA of the 2 × n parameter matrix).

    Parameters
    ----------
    samples : array_like, shape (n, d)
        One sample per row.
    ddof : int
        Delta degrees of freedom of the covariance (1: unbiased sample covariance).

    Returns
    -------
    mean : ndarray, shape (d,)
    eigenvalues : ndarray, shape (d,)
        Variances along the principal axes, descending, ≥ 0.
    eigenvectors : ndarray, shape (d, d)
        Unit principal directions as columns, each with its largest-magnitude
        component positive.
    """
    ddof = check_integer(ddof, "ddof", 0)
    x = check_finite(as_float(samples, "samples", np.float64), "samples")
    check_shape(x, "samples", (None, None))
    if x.shape[1] == 0:
        raise ValidationError(f"samples must hold at least one variable (column), got shape {x.shape}")
    if x.shape[0] <= ddof:
        raise ValidationError(f"samples must have more than ddof={ddof} rows, got {x.shape[0]}")
    with np.errstate(over="ignore", invalid="ignore"):
        mean = x.mean(axis=0)
        xc = x - mean
        cov = xc.T @ xc / (x.shape[0] - ddof)
    if not np.all(np.isfinite(cov)):
        raise ValidationError(
            f"samples are too large for their covariance to be a float64 (|values| up to {np.abs(x).max():.3g}): "
            "rescale them (the axes do not depend on the scale, the eigenvalues scale with its square)"
        )
    w, v = covariance_axes(cov)
    return mean, w, v


def covariance_axes(cov):
    """Eigenvalues (descending, clipped at 0) and unit eigenvectors (columns, largest component positive) of ``cov``.

    Parameters
    ----------
    cov : array_like, shape (d, d)
        Symmetric covariance matrix (only its lower triangle is read, :func:`numpy.linalg.eigh`).

    Returns
    -------
    w : numpy.ndarray, shape (d,)
        Eigenvalues (variances), float64.
    v : numpy.ndarray, shape (d, d)
        Eigenvectors as columns, in the order of ``w``, each signed so its largest-magnitude component is positive.
    """
    w, v = np.linalg.eigh(np.asarray(cov, np.float64))
    order = np.argsort(w)[::-1]
    w = np.maximum(w[order], 0.0)
    v = v[:, order]
    idx = np.argmax(np.abs(v), axis=0)
    return w, v * np.sign(v[idx, np.arange(v.shape[1])])


def pooled_moments(counts, means, covariances, ddof=1):
    """Mean and covariance of the union of groups of samples, from each group's count, mean and covariance.

    The scatter of the union is the groups' own scatter plus that of their means
    about the grand mean (the decomposition behind Chan, Golub & LeVeque 1979,
    "Updating formulae and a pairwise algorithm for computing sample variances"):
    S = Σ_g (n_g − 1) C_g + Σ_g n_g (x̄_g − x̄)(x̄_g − x̄)ᵀ, x̄ = Σ_g n_g x̄_g / N, and
    the covariance is S / (N − ddof): exactly that of the pooled samples.

    Parameters
    ----------
    counts : array_like, shape (G,)
        Samples per group (groups with 0 samples are ignored).
    means : array_like, shape (G, d)
    covariances : array_like, shape (G, d, d)
        Each group's sample covariance with ddof 1 (any value where n_g = 1: it is weighted by 0).
    ddof : int
        Delta degrees of freedom of the pooled covariance.

    Returns
    -------
    mean : ndarray, shape (d,)
    covariance : ndarray, shape (d, d)
    n : int
        Total number of samples N (> ddof, else :class:`ValidationError`).
    """
    n = np.asarray(counts, np.float64)
    keep = n > 0
    n, mu = n[keep], np.asarray(means, np.float64)[keep]
    cov = np.where((n > 1)[:, None, None], np.asarray(covariances, np.float64)[keep], 0.0)
    total = n.sum()
    if total <= ddof:
        raise ValidationError(f"the groups must hold more than ddof={ddof} samples, got {int(total)}")
    mean = (n[:, None] * mu).sum(0) / total
    dev = mu - mean
    scatter = np.einsum("g,gij->ij", n - 1, cov) + np.einsum("g,gi,gj->ij", n, dev, dev)
    return mean, scatter / (total - ddof), int(total)


@dataclass(frozen=True)
class RegionEllipse:
    """PCA of one region's (ρs, lobe) samples.

    Attributes
    ----------
    region : int
        Region number (Weyrich Fig. 15).
    mean : ndarray, shape (2,)
        Mean (ρs, lobe): the centre of the ellipse.
    eigenvalues : ndarray, shape (2,)
        Variances along the principal axes, descending.
    eigenvectors : ndarray, shape (2, 2)
        Principal directions as unit columns in (ρs, lobe) coordinates.
    n : int
        Number of samples over all subjects.
    n_subjects : int
        Number of subjects contributing samples.
    """

    region: int
    mean: np.ndarray
    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    n: int
    n_subjects: int

    @property
    def name(self) -> str:
        return REGIONS[self.region]

    @property
    def std(self) -> np.ndarray:
        """Standard deviations σ_i = sqrt(λ_i) along the principal axes."""
        return np.sqrt(self.eigenvalues)

    @property
    def total_variance(self) -> float:
        """Total variance λ1 + λ2 of the region's samples (the size of its ellipse)."""
        return float(self.eigenvalues.sum())

    def half_axes(self, k=1.0) -> np.ndarray:
        """Half-axis lengths k·σ_i of the drawn ellipse (k = 1: one standard deviation).

        Parameters
        ----------
        k : float
            Number of standard deviations.

        Returns
        -------
        ndarray, shape (2,)
            Major then minor half axis, in (ρs, lobe) units.
        """
        return k * self.std

    @property
    def angle(self) -> float:
        """Angle of the major axis from the ρs axis, radians in (−π/2, π/2]."""
        v = self.eigenvectors[:, 0]
        a = float(np.arctan2(v[1], v[0]))
        if a > np.pi / 2:
            a -= np.pi
        elif a <= -np.pi / 2:
            a += np.pi
        return a

    def boundary(self, k=1.0, n_points=100) -> np.ndarray:
        """Points (n_points, 2) on the ellipse mean + V·diag(kσ)·(cos t, sin t).

        Parameters
        ----------
        k : float
            Number of standard deviations of the half axes (:meth:`half_axes`).
        n_points : int
            Number of points, t evenly spaced over [0, 2π] with both ends included (the last point repeats the
            first, closing the curve).

        Returns
        -------
        ndarray, shape (n_points, 2)
            (ρs, lobe) coordinates.
        """
        t = np.linspace(0, 2 * np.pi, n_points)
        circle = np.stack([np.cos(t), np.sin(t)])
        return (self.mean[:, None] + self.eigenvectors @ (self.half_axes(k)[:, None] * circle)).T


@dataclass(frozen=True)
class RegionPCA:
    """Region PCA ellipses of a population (Fig. 15 right).

    Attributes
    ----------
    model : str
        ``"ts"`` or ``"bp"``.
    parameters : tuple of str
        Names of the two variables, ``("rho_s", "m")`` or ``("rho_s", "exponent")``.
    regions : dict of int to RegionEllipse
        Regions with at least ``ddof + 1`` samples, in region order.
    n_subjects : int
        Subjects in the analysed population.
    ddof : int
    left_out : dict of int to str
        The other regions, with the reason (``"no texels"``, or too few samples for the covariance).
    """

    model: str
    parameters: tuple
    regions: dict
    n_subjects: int
    ddof: int = 1
    left_out: dict = field(default_factory=dict)

    def __getitem__(self, region) -> RegionEllipse:
        return self.regions[region]

    def to_frame(self):
        """One row per region: name, n, n_subjects, mean, eigenvalues, σ, major axis, angle and total variance."""
        import pandas as pd

        p0, p1 = self.parameters
        rows = []
        for r, e in self.regions.items():
            rows.append(
                {
                    "region": r,
                    "name": e.name,
                    "n": e.n,
                    "n_subjects": e.n_subjects,
                    f"mean_{p0}": e.mean[0],
                    f"mean_{p1}": e.mean[1],
                    "eigenvalue_1": e.eigenvalues[0],
                    "eigenvalue_2": e.eigenvalues[1],
                    "std_1": e.std[0],
                    "std_2": e.std[1],
                    f"axis_1_{p0}": e.eigenvectors[0, 0],
                    f"axis_1_{p1}": e.eigenvectors[1, 0],
                    "angle": e.angle,
                    "total_variance": e.total_variance,
                }
            )
        return pd.DataFrame.from_records(rows).set_index("region")

    def orderings(self) -> dict:
        """The region orderings Weyrich et al. discuss in §7, from this population.

        Returns
        -------
        dict
            ``highest_rho_s``: the five regions of highest mean ρs, descending;
            ``largest_variance``: the five regions of largest total variance
            λ1 + λ2, descending; ``smallest_lobe``: the region of the smoothest
            lobe, i.e. the smallest mean m (Torrance-Sparrow) or the largest
            mean exponent n (Blinn-Phong).
        """
        mean_rho = {r: e.mean[0] for r, e in self.regions.items()}
        mean_lobe = {r: e.mean[1] for r, e in self.regions.items()}
        total = {r: e.total_variance for r, e in self.regions.items()}
        return {
            "highest_rho_s": sorted(mean_rho, key=mean_rho.get, reverse=True)[:5],
            "largest_variance": sorted(total, key=total.get, reverse=True)[:5],
            "smallest_lobe": (min if self.model == "ts" else max)(mean_lobe, key=mean_lobe.get),
        }

    def published_orderings(self) -> dict | None:
        """The §7 orderings of the paper's Torrance-Sparrow fit (:mod:`facestats.core.published`); None for bp."""
        if self.model != "ts":
            return None

        return {
            "highest_rho_s": list(HIGHEST_RHO_S),
            "largest_variance": list(LARGEST_VARIANCE),
            "smallest_m": SMALLEST_M,
        }

    def compare_published(self, as_sets=False):
        """Our §7 orderings (:meth:`orderings`) beside the paper's, over the regions present here.

        The paper ranks all ten regions.  Where some are left out here (:attr:`left_out`), its orderings are
        restricted to the regions present (removing a region from a ranking keeps the order of the others), and
        ours are cut to as many regions: the paper's five of largest variance 8 1 3 9 10 become 8 3 9 10
        without region 1, beside our four of largest variance.  The paper's smoothest region is None if it is
        left out.

        Parameters
        ----------
        as_sets : bool
            List each ordering's regions sorted by number (the comparison as
            sets of regions; the single smoothest region as a one-element list)
            instead of in rank order (ours) and the paper's order.

        Returns
        -------
        pandas.DataFrame
            Index ``ordering`` (``highest_rho_s``, ``largest_variance``,
            ``smallest_lobe``); columns ``ours`` and ``paper`` (None for
            Blinn-Phong, which the paper does not analyse).
        """
        import pandas as pd

        ours = self.orderings()
        pub = self.published_orderings()
        keys = ("highest_rho_s", "largest_variance", "smallest_lobe")
        ours = [ours[k] for k in keys]
        if pub is None:
            paper = [None] * 3
        else:
            paper = [[r for r in pub[k] if r in self.regions] for k in ("highest_rho_s", "largest_variance")]
            ours = [ours[0][: len(paper[0])], ours[1][: len(paper[1])], ours[2]]
            paper.append(pub["smallest_m"] if pub["smallest_m"] in self.regions else None)
        if as_sets:
            ours = [sorted(np.atleast_1d(v).tolist()) for v in ours]
            paper = [None if v is None else sorted(np.atleast_1d(v).tolist()) for v in paper]
        return pd.DataFrame({"ours": ours, "paper": paper}, index=pd.Index(keys, name="ordering"))

    def to_dict(self, k=1.0) -> dict:
        """The JSON document of the analysis (``facestats analyze pca`` writes it as ``pca.json``).

        Keys (conventions: :mod:`facestats.analysis.serialize`): ``model``
        (``"ts"``/``"bp"``), ``parameters`` (``["rho_s", "m"]`` or
        ``["rho_s", "exponent"]``), ``n_subjects``, ``ddof``, ``k`` (ellipse
        half-axes in standard deviations); ``regions``: a list of
        ``{region, name, n, n_subjects, mean: [ρs, lobe], eigenvalues: [λ1, λ2],
        std: [σ1, σ2], axes: [[major], [minor]] (unit directions in (ρs, lobe)),
        angle_deg (major axis from the ρs axis), total_variance (λ1 + λ2)}``;
        ``orderings``: ``{highest_rho_s: 5 regions, largest_variance: 5 regions
        (by total variance), smallest_lobe: region}`` (:meth:`orderings`) and
        ``published`` (the §7 orderings of the Torrance-Sparrow fit over all ten
        regions, ``null`` for Blinn-Phong; :meth:`compare_published` restricts
        them to the regions present); ``left_out``: a list of ``{region, name,
        reason}`` for the regions without an ellipse.

        Parameters
        ----------
        k : float
            Half-axes of the drawn ellipses in standard deviations (recorded as ``k``).

        Returns
        -------
        dict
            JSON-ready (numbers, lists and strings only).
        """
        regions = [
            {
                "region": r,
                "name": e.name,
                "n": e.n,
                "n_subjects": e.n_subjects,
                "mean": e.mean,
                "eigenvalues": e.eigenvalues,
                "std": e.std,
                "axes": e.eigenvectors.T,
                "angle_deg": np.degrees(e.angle),
                "total_variance": e.total_variance,
            }
            for r, e in self.regions.items()
        ]
        doc = {
            "model": self.model,
            "parameters": list(self.parameters),
            "n_subjects": self.n_subjects,
            "ddof": self.ddof,
            "k": k,
            "regions": regions,
            "orderings": self.orderings(),
            "published": self.published_orderings(),
            "left_out": [{"region": r, "name": REGIONS[r], "reason": why} for r, why in self.left_out.items()],
        }
        return json_ready(doc)

    def to_text(self) -> str:
        """Summary table per region and the §7 orderings beside the paper's (what ``facestats analyze pca`` prints)."""
        lobe = self.parameters[1]
        lines = [
            f"Region PCA of the {MODEL_NAMES[self.model]} parameters (rho_s, {lobe}), {self.n_subjects} subjects "
            f"(Weyrich Fig. 15)",
            f"{'region':<13}{'n':>7}  {'rho_s':>7}  {lobe:>8}  {'sd1':>8}  {'sd2':>8}  {'angle':>6}",
        ]
        for r, e in self.regions.items():
            lines.append(
                f"{r:>2} {e.name:<10}{e.n:>7}  {e.mean[0]:7.4f}  {e.mean[1]:8.4f}  {e.std[0]:8.4f}  "
                f"{e.std[1]:8.4f}  {np.degrees(e.angle):5.0f}d"
            )
        if self.left_out:
            lines.append("left out: " + self.left_out_text())
        cmp = self.compare_published()
        smooth = "smallest m" if self.model == "ts" else "largest n"
        paper_name = "paper" if not self.left_out else f"paper without {_regions(self.left_out)}"
        if self.left_out and self.model == "ts":
            lines.append(f"orderings over the {len(self.regions)} regions present (the paper's restricted to them):")
        for key, label in (("highest_rho_s", "highest rho_s:"), ("largest_variance", "largest variance:")):
            ours, paper = cmp.loc[key, "ours"], cmp.loc[key, "paper"]
            lines.append(
                f"{label:<18}{_regions(ours)}" + ("" if paper is None else f"   ({paper_name}: {_regions(paper)})")
            )
        ours, paper = cmp.loc["smallest_lobe", "ours"], cmp.loc["smallest_lobe", "paper"]
        if self.model == "ts" and paper is None:
            paper_text = f"   (paper: {SMALLEST_M}, left out here)"
        else:
            paper_text = "" if paper is None else f"   ({paper_name}: {paper})"
        lines.append(f"{smooth + ':':<18}{ours}{paper_text}")
        return "\n".join(lines)

    def left_out_text(self) -> str:
        """The regions without an ellipse and why (``"region 1 mustache (no texels)"``; ``""`` if none)."""
        return "; ".join(f"region {r} {REGIONS[r]} ({why})" for r, why in self.left_out.items())


def _regions(ids):
    """Region numbers separated by spaces."""
    return " ".join(str(r) for r in ids)


def region_sample_frame(source, model="ts", subjects=None):
    """Long-form per-region samples (``subject_id, region, rho_s, lobe``) of a store or a DataFrame.

    A store's samples come from :func:`facestats.analysis.population.region_samples`;
    a DataFrame with those columns is filtered to ``subjects``.

    Parameters
    ----------
    source : Store or pandas.DataFrame
        A parameter store, or samples already in long form.
    model : {"ts", "bp"}
        Specular model of a store's samples: Torrance-Sparrow (ρs, m) or Blinn-Phong (ρs, n).
    subjects : sequence of str, optional
        Subject ids to keep (default all).

    Returns
    -------
    pandas.DataFrame
        One row per sample: ``subject_id``, ``region`` (1-10, Weyrich Fig. 15), ``rho_s``, ``lobe`` (m or n).

    Raises
    ------
    ValidationError
        A source of another type, or a DataFrame without those columns.
    """
    import pandas as pd

    if isinstance(source, pd.DataFrame):
        frame = source
        if subjects is not None:
            frame = frame[frame["subject_id"].isin(list(subjects))]
    elif callable(getattr(source, "subject", None)):
        frame = region_samples(source, model=model, subjects=None if subjects is None else list(subjects))
    else:
        raise ValidationError(
            f"source must be a parameter store (with a subject() method) or a DataFrame of samples, "
            f"got {type(source).__name__}"
        )
    missing = [c for c in ("subject_id", "region", "rho_s", "lobe") if c not in frame.columns]
    if missing:
        raise ValidationError(f"region samples must have columns subject_id, region, rho_s, lobe; missing {missing}")
    return frame


def region_pca(source, model="ts", subjects=None, conditions=("normal",), ddof=1, *, from_index="auto"):
    """PCA ellipses of the specular parameters per face region (Weyrich et al. 2006 §7, Fig. 15).

    For every region the samples of all selected subjects form the 2 × n
    matrix of (ρs, lobe) values; its covariance is eigen-decomposed
    (:func:`principal_axes`): centre = mean, axes = eigenvectors, sizes =
    eigenvalues (variances; ellipses are drawn with half-axes k·σ, k = 1 by
    default, see the module docstring).

    A store's population index holds every subject's per-region sample count,
    means, standard deviations and (ρs, lobe) covariance
    (:mod:`facestats.io.summary`); from them the pooled mean and covariance
    follow exactly (:func:`pooled_moments`), so a store's PCA reads no maps.
    Stores written before the index held the covariance are read sample by
    sample.

    Parameters
    ----------
    source : store or pandas.DataFrame
        A parameter store (``subjects`` and ``subject``), or a long-form
        DataFrame of samples with columns ``subject_id, region, rho_s, lobe``
        (then ``subjects``/``conditions`` filtering uses only ``subjects``).
    model : {"ts", "bp"}
        Torrance-Sparrow (ρs, m), as in the paper, or Blinn-Phong (ρs, n).
    subjects : sequence of str, optional
        Subject ids to use.
    conditions : sequence of str or None
        Conditions to keep when ``source`` is a store (default: normal only).
    ddof : int
        Delta degrees of freedom of the covariance.
    from_index : {"auto", True, False}
        For a store: pool the index's moments (True; an error if the index lacks them), read the
        samples (False), or the index where it has the moments of every selected subject ("auto").

    Returns
    -------
    RegionPCA
        Regions with more than ``ddof`` samples; the others are named in its ``left_out`` with the reason.
    """
    import pandas as pd

    check_choice(model, "model", ("ts", "bp"))
    check_choice(from_index, "from_index", ("auto", True, False))
    ddof = check_integer(ddof, "ddof", 0)  # both paths (the index's moments and the maps' samples)
    _, _, lobe_name = index_columns(model)
    if not isinstance(source, pd.DataFrame):
        rows = select_population(source, subjects, conditions)
        subjects = list(rows.index)
        moments = _index_moments(rows, model) if from_index is not False else None
        if moments is None and from_index is True:
            raise ValidationError(f"the store's index has no per-region {model} covariances (written before they were)")
        if moments is not None:
            return _pca_from_moments(moments, model, lobe_name, ddof)
    samples = region_sample_frame(source, model, subjects)
    region = samples["region"].to_numpy()
    values = samples[["rho_s", "lobe"]].to_numpy(np.float64)
    sid = samples["subject_id"].to_numpy()
    finite = np.all(np.isfinite(values), axis=1)
    ellipses, left_out = {}, {}
    for r in REGION_IDS:
        sel = (region == r) & finite
        if sel.sum() <= ddof:
            left_out[r] = _too_few(int(sel.sum()), ddof)
            continue
        mean, w, v = principal_axes(values[sel], ddof=ddof)
        ellipses[r] = RegionEllipse(r, mean, w, v, int(sel.sum()), int(pd.unique(sid[sel]).size))
    if not ellipses:
        raise ValidationError(f"no region has more than {ddof} finite {model} samples in the selected subjects")
    n_subjects = int(pd.unique(sid[finite]).size)
    return RegionPCA(model, ("rho_s", lobe_name), ellipses, n_subjects, ddof, left_out)


def _too_few(n, ddof):
    """Why a region of ``n`` samples has no ellipse."""
    return "no texels" if n == 0 else f"{n} sample{'s' * (n != 1)}, a covariance with ddof={ddof} needs more"


def has_index_moments(source, model="ts") -> bool:
    """True if the population index of ``source`` (a store or the index) holds the per-region moments of
    every subject that :func:`region_pca` pools instead of reading samples.

    Every row of the index is checked (not only a selected population): each region's count, covariance,
    means and standard deviations must be columns, and finite for every subject with samples.

    Parameters
    ----------
    source : store or pandas.DataFrame
        A parameter store (``subjects()`` returns its index) or the index itself.
    model : {"ts", "bp"}
        Torrance-Sparrow or Blinn-Phong columns.

    Returns
    -------
    bool

    Raises
    ------
    ValidationError
        For another ``model``, or a ``source`` that :func:`population_index` refuses.
    """
    check_choice(model, "model", ("ts", "bp"))
    return _index_moments(population_index(source), model) is not None


def _index_moments(rows, model):
    """``({region: (counts, means (S, 2), covariances (S, 2, 2))}, subjects with samples)`` of the index ``rows``.

    None where the index lacks a column or a subject's statistics are not finite (then the samples decide).
    """
    from facestats.io.summary import column

    scale, lobe, _ = index_columns(model)
    out, contributing = {}, np.zeros(len(rows), bool)
    for r in REGION_IDS:
        names = [column("n", model=model, region=r), column("cov", model=model, region=r)]
        names += [column(k, param=p, region=r) for k in ("mean", "std") for p in (scale, lobe)]
        if any(c not in rows.columns for c in names):
            return None
        n, cov, m1, m2, s1, s2 = (rows[c].to_numpy(np.float64) for c in names)
        n = np.nan_to_num(n)
        has = n > 0
        if not np.all(np.isfinite(np.stack([cov, m1, m2, s1, s2])[:, has])):
            return None  # a subject whose samples are not all finite: the samples decide
        c = np.zeros((n.size, 2, 2))
        c[:, 0, 0], c[:, 1, 1], c[:, 0, 1], c[:, 1, 0] = s1**2, s2**2, cov, cov
        out[r] = (n[has], np.stack([m1, m2], 1)[has], c[has])
        contributing |= has
    return out, int(contributing.sum())


def _pca_from_moments(moments, model, lobe_name, ddof):
    """:class:`RegionPCA` from :func:`_index_moments` (:func:`pooled_moments` per region)."""
    per_region, n_subjects = moments
    ellipses, left_out = {}, {}
    for r, (n, means, covs) in per_region.items():
        if n.sum() <= ddof:
            left_out[r] = _too_few(int(n.sum()), ddof)
            continue
        mean, cov, total = pooled_moments(n, means, covs, ddof)
        w, v = covariance_axes(cov)
        ellipses[r] = RegionEllipse(r, mean, w, v, total, int(n.size))
    if not ellipses:
        raise ValidationError(f"no region has more than {ddof} finite {model} samples in the selected subjects")
    return RegionPCA(model, ("rho_s", lobe_name), ellipses, n_subjects, ddof, left_out)
