"""Per-subject summaries: the rows of the population index.

One row per subject holds its metadata, per-region mean and spread of the BRDF
parameters, the per-site and per-subject scattering coefficients and albedo
statistics; 256-bin albedo histograms per channel are kept beside the row.
These functions work on a subject :class:`xarray.Dataset` (either kind of
:mod:`facestats.io.schema`) and are what the store calls when it writes a
subject, so the index can never disagree with the data it summarises.

Column names (``r`` = region 1-10, ``ch`` = R/G/B, ``site`` = cheek/forehead/neck):

* metadata: ``subject_id``, ``person_id``, ``age``, ``gender``, ``skin_type``,
  ``condition``, ``kind`` (``maps``/``samples``), ``source``;
* ``{p}_mean_r{r}``, ``{p}_std_r{r}`` for p in ``ts_rho_s``, ``ts_m``,
  ``bp_rho_s``, ``bp_exponent``: the mean and the sample standard deviation (ddof 1) of the values of the
  region's unflagged texels (all of them, determined or not: see below) — ``_std`` here is the *spread* of the
  values within the region, not a standard error and not the subject's ``*_std`` maps;
  ``n_ts_r{r}``, ``n_bp_r{r}`` (sample counts);
  ``{model}_cov_r{r}`` for model ``ts``/``bp``: the sample covariance (ddof 1) of
  the region's (scale, lobe) pairs, so that with the counts, means and standard
  deviations the pooled covariance of any selection of subjects follows exactly
  (:func:`facestats.analysis.pca.pooled_moments`, Fig. 15 without reading maps);
  statistics in float64;
* ``{p}_se_r{r}``: the root mean square of the per-texel standard errors of p
  (the ``*_std`` maps: robust HC3 standard errors of the eq. 14 fit) over the same texels' *determined*
  ones, and ``{p}_mean_se_r{r}``: the standard error of their mean, sqrt(Σ σ²)/n
  (texel fits are independent) — the within-subject uncertainty; NaN for
  subjects without standard-error maps (older stores, imported or edited parameters).  A texel is
  determined when its standard error is at most its value's magnitude (:data:`DETERMINED_RELATIVE_SE`).
  The others (on the default store 5.5 % of the unflagged Blinn-Phong texels, 27 % of the chin's and 15 % of the
  lips', and 1.0 % of the Torrance-Sparrow ones, 12 % of the lips' and 6 % of the nose's; counted for ρs) have
  linearised errors up to 8.0e3 times their value (``bench_fit.bench_determined_texels()``),
  which say only that the fit leaves the value open; one of them would outweigh a region's hundreds of
  determined texels in both sums.  The index holds no count of them: :func:`region_undetermined` counts them per
  region from a subject's maps;
* ``site_sigma_tr_{site}_{ch}``, ``site_sigma_s_prime_{site}_{ch}``,
  ``site_sigma_a_{site}_{ch}``;
* ``sigma_s_prime_{ch}``, ``sigma_a_{ch}``, ``sigma_tr_{ch}``;
* ``albedo_mean_{ch}``, ``albedo_std_{ch}``;
* ``flagged_fraction`` (texels whose Torrance-Sparrow fit was flagged).

Missing quantities (e.g. an imported subject without sensor data) are NaN.
"""

from __future__ import annotations

import numpy as np

from facestats.core.conventions import CHANNELS, REGION_IDS, SITES
from facestats.io.schema import face_bands, provenance, subject_kind

__all__ = [
    "HIST_BINS",
    "IDENTITY_COLUMNS",
    "BRDF_PARAMS",
    "MODEL_PARAMS",
    "SUMMARY_MAPS",
    "GATHERED_TEXELS",
    "FaceTexels",
    "region_samples",
    "region_standard_errors",
    "region_sample_variables",
    "DETERMINED_RELATIVE_SE",
    "determined",
    "region_undetermined",
    "albedo_histogram",
    "summarise_subject",
    "column",
]

#: Albedo histograms: 256 bins over [0, 1] per channel.
HIST_BINS = 256
#: The BRDF parameters summarised per region.
BRDF_PARAMS = ("ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent")
#: model -> (scale parameter, lobe parameter, flag variable).
MODEL_PARAMS = {"ts": ("ts_rho_s", "ts_m", "ts_flag"), "bp": ("bp_rho_s", "bp_exponent", "bp_flag")}
#: model -> the standard-error maps of its (scale, lobe) parameters.
MODEL_STD = {"ts": ("ts_rho_s_std", "ts_m_std"), "bp": ("bp_rho_s_std", "bp_exponent_std")}
#: The map variables whose face texels a map subject's index row and albedo histogram read.
SUMMARY_MAPS = ("albedo", *MODEL_PARAMS["ts"], *MODEL_STD["ts"], *MODEL_PARAMS["bp"], *MODEL_STD["bp"])
#: Texels :meth:`FaceTexels.bands` yields at a time from gathered texels.
GATHERED_BLOCK = 1 << 14
#: Key of ``Dataset.encoding`` where a reader that read the bands of maps anyway leaves their face texels,
#: ``{name: (variable, texels)}`` and ``"region": (variable, None)`` (``open_generation(..., banded=True)``):
#: :class:`FaceTexels` takes them instead of reading the maps again as long as each ``ds.variables[name]``, the
#: region's included, is still that very variable (a Dataset derived from it reads its maps again).
GATHERED_TEXELS = "facestats_face_texels"


class FaceTexels:
    """The face texels (``region > 0``) of a map subject's variables, in row-major order of (``v``, ``u``).

    Everything the index row reads from a map is on the face (the regions are 1-10, the albedo statistics and the
    flagged fraction are the face's), so the summary reads maps through this: band by band from the Dataset
    (:func:`facestats.io.schema.face_bands`: a map left on disk is never whole in memory), or from the face texels a
    reader gathered while reading the bands anyway (:data:`GATHERED_TEXELS`), then not read again.  ``texels(name)``
    equals ``values[region > 0]`` of the map (texels, *other dims*), element for element.

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject.
    """

    def __init__(self, ds):
        self.ds = ds
        region = np.asarray(ds["region"].values)
        self.face = region > 0
        self.region = region[self.face]
        gathered = ds.encoding.get(GATHERED_TEXELS) or {}
        same = all(ds.variables.get(n) is var for n, (var, _) in gathered.items())  # the region too
        self.gathered = {n: t for n, (_, t) in gathered.items() if n != "region"} if same else {}

    def bands(self, name: str):
        """The face texels of map ``name`` in pieces (bands of rows, or all at once if gathered), in texel order.

        Parameters
        ----------
        name : str
            The map variable's name.

        Yields
        ------
        ndarray, shape (texels, ...)
            The face texels of the next piece, in the map's own dtype.
        """
        if name in self.gathered:
            texels = self.gathered[name]
            for lo in range(0, len(texels), GATHERED_BLOCK):  # views: a float64 copy of one block at a time
                yield texels[lo : lo + GATHERED_BLOCK]
        else:
            yield from face_bands(self.ds[name].variable, self.face)

    def __call__(self, name: str) -> np.ndarray:
        """The face texels of map ``name``: an array (texels, *other dims*) in its own dtype."""
        if name in self.gathered:
            return self.gathered[name]
        out, n = None, 0
        for part in self.bands(name):
            if out is None:
                out = np.empty((self.region.size, *part.shape[1:]), part.dtype)
            out[n : n + len(part)] = part
            n += len(part)
        return np.empty(0) if out is None else out


def column(kind: str, **keys) -> str:
    """Build an index column name, e.g. ``column("mean", param="ts_m", region=6)`` -> ``"ts_m_mean_r6"``.

    Parameters
    ----------
    kind : {"mean", "std", "se", "mean_se", "n", "cov", "site", "subject"}
        The column family (see the module docstring).
    **keys
        ``param`` and ``region`` (mean, std, se, mean_se), ``model`` and ``region`` (n, cov),
        ``param``, ``site`` and ``channel`` (site), ``param`` and ``channel`` (subject).

    Returns
    -------
    str
    """
    if kind in ("mean", "std", "se", "mean_se"):
        return f"{keys['param']}_{kind}_r{keys['region']}"
    if kind == "n":
        return f"n_{keys['model']}_r{keys['region']}"
    if kind == "cov":
        return f"{keys['model']}_cov_r{keys['region']}"
    if kind == "site":
        return f"site_{keys['param']}_{keys['site']}_{keys['channel']}"
    if kind == "subject":
        return f"{keys['param']}_{keys['channel']}"
    raise KeyError(kind)


def region_sample_variables(kind: str, model: str = "ts") -> list:
    """The variables :func:`region_samples` reads from a subject of ``kind`` ("maps" or "samples").

    Parameters
    ----------
    kind : str
        The subject's kind; anything but ``"maps"`` is taken as ``"samples"``.
    model : {"ts", "bp"}
        The BRDF model of a map subject (:data:`MODEL_PARAMS`); sample subjects are Torrance-Sparrow only.

    Returns
    -------
    list of str
        ``region`` and the model's scale, lobe and flag maps, or the three ``ts_sample_*`` variables.
    """
    if kind == "maps":
        return ["region", *MODEL_PARAMS[model]]
    return ["ts_sample_region", "ts_sample_rho_s", "ts_sample_m"]


def region_samples(ds, model: str = "ts", texels: FaceTexels | None = None) -> dict:
    """Per-region parameter samples of one subject: ``{region: (rho_s, lobe)}`` arrays.

    For map subjects these are the texels of the region whose fit was not
    flagged (texels filled from neighbours are excluded: they are not
    measurements).  For sample subjects (published files) they are the stored
    samples; sample subjects carry Torrance-Sparrow samples only.

    Parameters
    ----------
    ds : xarray.Dataset
        A subject of either kind.
    model : {"ts", "bp"}
        Torrance-Sparrow or Blinn-Phong (:data:`MODEL_PARAMS`).
    texels : FaceTexels, optional
        The face texels of a map subject ``ds`` (default: read from ``ds``).

    Returns
    -------
    dict
        ``{region 1-10: (rho_s, lobe)}`` float64 arrays (empty for a region without samples), texels in row-major
        order.
    """
    rho_name, lobe_name, flag_name = MODEL_PARAMS[model]
    out = {}
    if subject_kind(ds) == "maps":
        return dict(_region_texels(ds, model, (rho_name, lobe_name), texels))
    if model != "ts":
        return {r: (np.empty(0), np.empty(0)) for r in REGION_IDS}
    reg = np.asarray(ds["ts_sample_region"].values)
    rho = np.asarray(ds["ts_sample_rho_s"].values, dtype=np.float64)
    m = np.asarray(ds["ts_sample_m"].values, dtype=np.float64)
    for r in REGION_IDS:
        sel = reg == r
        out[r] = (rho[sel], m[sel])
    return out


def region_standard_errors(ds, model: str = "ts", texels: FaceTexels | None = None):
    """Per-region standard errors of the texels :func:`region_samples` returns: ``{region: (rho_s_std, lobe_std)}``.

    Parameters
    ----------
    ds : xarray.Dataset
    model : {"ts", "bp"}
    texels : FaceTexels, optional
        The face texels of a map subject ``ds`` (default: read from ``ds``).

    Returns
    -------
    dict or None
        float64 arrays per region 1-10 (NaN for a map the subject lacks); None when the subject has neither
        standard-error map (a sample subject, a store written before they existed, an edited parameter).
    """
    names = MODEL_STD[model]
    if not _has_standard_errors(ds, model):
        return None
    return dict(_region_texels(ds, model, names, texels))


def _has_standard_errors(ds, model: str) -> bool:
    """True for a map subject with a standard-error map of ``model`` (:func:`region_standard_errors`)."""
    return subject_kind(ds) == "maps" and any(n in ds.data_vars for n in MODEL_STD[model])


def _region_texels(ds, model: str, names, texels: FaceTexels | None = None):
    """``(region, arrays)`` per region 1-10, one region at a time: the float64 values of the maps ``names`` (NaN for
    a map the subject lacks) on the region's texels whose ``model`` fit was not flagged, in row-major order."""
    texels = FaceTexels(ds) if texels is None else texels
    good = texels(MODEL_PARAMS[model][2]) == 0
    maps = [texels(n) if n in ds.data_vars else None for n in names]  # standard-error maps are optional
    for r in REGION_IDS:
        sel = (texels.region == r) & good
        yield r, tuple(np.full(int(sel.sum()), np.nan) if m is None else m[sel].astype(np.float64) for m in maps)


#: Largest standard error, relative to the value's magnitude, of a texel counted in the region's standard errors.
DETERMINED_RELATIVE_SE = 1.0


def determined(sd, value) -> np.ndarray:
    """Which texels the fit determines: a finite standard error at most :data:`DETERMINED_RELATIVE_SE` times the
    value's magnitude (module docstring).

    The index's ``{p}_se_r{r}`` and ``{p}_mean_se_r{r}`` are taken over these texels only; its ``{p}_mean_r{r}``
    and ``{p}_std_r{r}`` over all of the region's unflagged texels, these and the others.

    Parameters
    ----------
    sd : array_like
        Per-texel standard errors (a ``*_std`` map's values), in the parameter's unit.
    value : array_like
        The fitted values they belong to (same shape).

    Returns
    -------
    ndarray of bool
        True where the texel is determined; False for a NaN or infinite standard error too.
    """
    sd = np.asarray(sd)
    return np.isfinite(sd) & (sd <= DETERMINED_RELATIVE_SE * np.abs(np.asarray(value)))


def region_undetermined(ds, model: str = "ts", texels: FaceTexels | None = None) -> dict | None:
    """Per region, how many of the texels the index row summarises the fit leaves undetermined (:func:`determined`).

    The index keeps no such column (a new column would make every row written before disagree with its data on
    validation, and the shipped default store would have to be rebuilt): this counts them from the subject's maps,
    over the same texels as the row (the region's unflagged ones, :func:`region_samples`).

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject.
    model : {"ts", "bp"}
        Torrance-Sparrow or Blinn-Phong (:data:`MODEL_PARAMS`).
    texels : FaceTexels, optional
        The face texels of ``ds`` (default: read from ``ds``).

    Returns
    -------
    dict or None
        ``{region 1-10: {"n": texels, <scale parameter>: undetermined, <lobe parameter>: undetermined}}``, e.g.
        ``{6: {"n": 56, "ts_rho_s": 3, "ts_m": 1}, ...}``: ``n`` is the row's ``n_{model}_r{r}``, and the counts are
        of texels left out of ``{p}_se_r{r}`` and ``{p}_mean_se_r{r}`` but in ``{p}_mean_r{r}`` and ``{p}_std_r{r}``
        (a map the subject lacks counts all its texels); None for a subject without standard-error maps
        (:func:`region_standard_errors`).
    """
    if not _has_standard_errors(ds, model):
        return None
    names = MODEL_PARAMS[model][:2]
    out = {}
    for r, arrays in _region_texels(ds, model, names + MODEL_STD[model], texels):
        values, sds = arrays[:2], arrays[2:]
        out[r] = {"n": int(values[0].size)}
        for name, x, sd in zip(names, values, sds):
            out[r][name] = int(np.count_nonzero(~determined(sd, x)))
    return out


def _standard_errors(sd, value):
    """(RMS of the per-texel standard errors, standard error of their mean sqrt(Σσ²)/n) of the determined texels
    (:func:`determined`)."""
    sd = sd[determined(sd, value)]
    if sd.size == 0:
        return np.nan, np.nan
    scale = float(np.max(np.abs(sd)))  # squares of values near 1e155 and above would overflow float64
    if scale == 0:
        return 0.0, 0.0
    var = np.square(sd / scale)
    return scale * float(np.sqrt(var.mean())), scale * float(np.sqrt(var.sum())) / sd.size


def _albedo_bands(ds, texels: FaceTexels | None = None):
    """Albedo values (texels, 3) of the face texels, band by band of rows of a map (:meth:`FaceTexels.bands`: a map
    left on disk is never whole in memory), or of the stored albedo samples in one piece; float64, in row-major texel
    order."""
    if subject_kind(ds) == "maps":
        texels = FaceTexels(ds) if texels is None else texels
        for band in texels.bands("albedo"):
            yield band.astype(np.float64)
    elif "albedo_sample" in ds.variables:  # a 2-D variable named like its dim: xarray makes it a coordinate
        yield np.asarray(ds["albedo_sample"].values, dtype=np.float64).reshape(-1, 3)


def _albedo_values(ds, texels: FaceTexels | None = None) -> np.ndarray:
    """Albedo values (n, 3) of the face texels (:class:`FaceTexels`, the map's dtype) or of the stored albedo samples
    (float64), in row-major texel order.

    In the map's own dtype: each channel becomes float64 on its own (:func:`_mean_std`), a third of the float64
    copy of all three the index row held before (beside the float32 face texels gathered by a validation).
    """
    if subject_kind(ds) != "maps":
        return next(_albedo_bands(ds), np.empty((0, 3)))
    return (FaceTexels(ds) if texels is None else texels)("albedo")


def albedo_histogram(ds, bins: int = HIST_BINS, texels: FaceTexels | None = None) -> np.ndarray:
    """Counts of albedo values per channel in ``bins`` equal bins over [0, 1].

    Values are the face texels of a map subject or the stored albedo samples,
    clipped to [0, 1]; value a (float64) falls in bin min(floor(a · bins), bins − 1).
    Counted band by band of rows of a map (:func:`_albedo_bands`): integer sums, the same counts as all texels at
    once.

    Parameters
    ----------
    ds : xarray.Dataset
    bins : int
    texels : FaceTexels, optional
        The face texels of a map subject ``ds`` (default: read from ``ds``).

    Returns
    -------
    ndarray of int64, shape (3, bins)
    """
    counts = np.zeros((3, bins), np.int64)
    for vals in _albedo_bands(ds, texels):
        idx = np.minimum((np.clip(vals, 0, 1) * bins).astype(np.int64), bins - 1)
        for c in range(3):
            counts[c] += np.bincount(idx[:, c], minlength=bins)
    return counts


def _mean_std(x):
    """Mean and sample standard deviation (ddof 1) of a 1-D array in float64: NaN, NaN if empty; std 0 for one value."""
    if x.size == 0:
        return np.nan, np.nan
    x = np.asarray(x, np.float64)
    return float(np.mean(x)), (float(np.std(x, ddof=1)) if x.size > 1 else 0.0)


def _covariance(x, y) -> float:
    """Sample covariance (ddof 1) of paired 1-D arrays in float64: NaN if empty, 0 for one pair."""
    if x.size == 0:
        return np.nan
    if x.size == 1:
        return 0.0
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    return float(np.dot(x - x.mean(), y - y.mean()) / (x.size - 1))


#: The first columns of every index row: who the subject is, what kind and from where.
IDENTITY_COLUMNS = ("subject_id", "person_id", "age", "gender", "skin_type", "condition", "kind", "source")


def summarise_subject(ds, texels: FaceTexels | None = None) -> dict:
    """The population-index row of a subject (see the module docstring for the columns).

    Parameters
    ----------
    ds : xarray.Dataset
        A subject of either kind.
    texels : FaceTexels, optional
        The face texels of a map subject ``ds`` (default: read from ``ds``, each map once per use).

    Returns
    -------
    dict
        ``{column: value}`` in a fixed column order; missing quantities are NaN.
    """
    a = ds.attrs
    if texels is None and subject_kind(ds) == "maps":
        texels = FaceTexels(ds)
    identity = (
        str(a["subject_id"]),
        str(a.get("person_id", a["subject_id"])),
        int(a["age"]),
        str(a["gender"]),
        int(a["skin_type"]),
        str(a["condition"]),
        subject_kind(ds),
        str(provenance(ds).get("source", "")),
    )
    row = dict(zip(IDENTITY_COLUMNS, identity))
    _add_brdf_columns(row, ds, texels)
    _add_scattering_columns(row, ds)
    alb = _albedo_values(ds, texels)
    for c, ch in enumerate(CHANNELS):
        mean, std = _mean_std(alb[:, c])
        row[f"albedo_mean_{ch}"] = mean
        row[f"albedo_std_{ch}"] = std
    row["flagged_fraction"] = _flagged_fraction(ds, texels)
    return row


def _brdf_regions(ds, model: str, texels: FaceTexels | None):
    """``(region, (rho_s, lobe), (rho_s_std, lobe_std) or None)`` per region 1-10: :func:`region_samples` and
    :func:`region_standard_errors`, for a map subject one region's float64 arrays at a time (all regions of one
    model at once were the peak of the index row: 118-129 MiB traced at 2048²)."""
    if subject_kind(ds) != "maps":
        samples = region_samples(ds, model)
        yield from ((r, samples[r], None) for r in REGION_IDS)
        return
    errors = _has_standard_errors(ds, model)
    names = MODEL_PARAMS[model][:2] + (MODEL_STD[model] if errors else ())
    for r, arrays in _region_texels(ds, model, names, texels):
        yield r, arrays[:2], (arrays[2:] if errors else None)


def _add_brdf_columns(row: dict, ds, texels: FaceTexels | None) -> None:
    """Per model and region: sample count, mean, spread and standard errors of both BRDF parameters."""
    for model in ("ts", "bp"):
        rho_name, lobe_name, _ = MODEL_PARAMS[model]
        for r, (rho, lobe), errors in _brdf_regions(ds, model, texels):
            row[column("n", model=model, region=r)] = int(rho.size)
            row[column("cov", model=model, region=r)] = _covariance(rho, lobe)
            for k, (name, x) in enumerate(((rho_name, rho), (lobe_name, lobe))):
                mean, std = _mean_std(x)
                row[column("mean", param=name, region=r)] = mean
                row[column("std", param=name, region=r)] = std
                se, mean_se = (np.nan, np.nan) if errors is None else _standard_errors(errors[k], x)
                row[column("se", param=name, region=r)] = se
                row[column("mean_se", param=name, region=r)] = mean_se


def _add_scattering_columns(row: dict, ds) -> None:
    """Per-site, then per-subject scattering coefficients per channel (NaN where missing)."""
    sites = [str(s) for s in ds["site"].values] if "site" in ds.dims else []  # each once (the schema)
    for param in ("sigma_tr", "sigma_s_prime", "sigma_a"):
        var = f"site_{param}"
        values = np.asarray(ds[var].transpose("site", "channel").values, float) if var in ds.data_vars else None
        for site in SITES:
            for c, ch in enumerate(CHANNELS):
                val = np.nan
                if values is not None and site in sites:
                    val = float(values[sites.index(site), c])
                row[column("site", param=param, site=site, channel=ch)] = val
    for param in ("sigma_s_prime", "sigma_a", "sigma_tr"):
        vals = np.asarray(ds[param].values, float) if param in ds.data_vars else np.full(3, np.nan)
        for c, ch in enumerate(CHANNELS):
            row[column("subject", param=param, channel=ch)] = float(vals[c])


def _flagged_fraction(ds, texels: FaceTexels | None = None) -> float:
    """Fraction of face texels whose Torrance-Sparrow fit was flagged (NaN for sample subjects)."""
    if subject_kind(ds) == "maps":
        flags = (FaceTexels(ds) if texels is None else texels)("ts_flag")
        return float(np.mean(flags != 0))
    return np.nan
