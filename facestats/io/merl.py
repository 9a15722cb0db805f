"""Reader of the MERL/ETH Skin Reflectance Database statistics file ``ts_data.mat``.

The database distributes its Torrance-Sparrow statistics (Weyrich et al. 2006
§7) as a MATLAB file read with :func:`scipy.io.loadmat`, with keys

=================  ======================================================================
``s_count``        number of subjects S
``subj_age``       S ages in years
``subj_gen``       S genders: 0 = male, 1 = female, or 'M'/'F', 'm'/'f', 'male'/'female'
``subj_skintype``  S Fitzpatrick skin types, 1-6 or Roman numerals
``ts``             K×2 Torrance-Sparrow samples, column 0 = m, column 1 = ρs (one row per vertex)
``ts_region``      K regions 1-10 (Weyrich Fig. 15)
``ts_subjec``      K 1-based subject indices
``albedo``         K'×3 (or K'×1) albedo samples in [0, 1]          (optional, with the next two)
``albedo_region``  K' regions 1-10
``albedo_subjec``  K' 1-based subject indices
=================  ======================================================================

Units and convention: m is Beckmann's RMS slope (dimensionless), ρs the scale of Weyrich et
al. 2006 eq. 12 with the Beckmann D of eq. 13 printed without 1/π, the convention of
:func:`facestats.model.brdf.torrance_sparrow` (ρs = 1/4 is a surface of Fresnel mirror
facets), so imported and fitted ρs compare directly; albedo samples are taken as linear RGB
reflectance, like the store's albedo maps (the file itself does not state an encoding).

Shapes are read liberally: row or column vectors, scalars wrapped in arrays,
2×K instead of K×2, char arrays ('MFM', a char matrix) or cell arrays of
strings for the labels.  Values are checked strictly and a
:class:`~facestats.errors.FormatError` names the key, the 1-based row and the
value: m > 0 and ρs ≥ 0 (finite), regions 1-10, subject indices 1..S, integer
ages 0-200, albedo in [0, 1] with 1 or 3 columns (one column is replicated
to R, G, B and recorded in the provenance), consistent lengths; m and ρs are
checked against the physical domains of the store's schema
(:data:`facestats.io.schema.DOMAINS`: m > 0, 0 ≤ ρs ≤ 1/(4 F_r(0))), so a file
with m = ρs = 1e300 is refused, naming the row.

Every subject becomes a *sample subject* (:mod:`facestats.io.schema`) with id
``<prefix>-NNN`` (``merl-001`` ...), condition "normal", no maps, and
provenance ``source`` (the file's absolute path), ``source_sha256``,
``source_format``, ``subject_index``.  Subjects without any sample are
imported all the same (their index summaries are NaN) and listed in
:attr:`MerlData.empty`, so subject numbering stays that of the file.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from facestats.core.conventions import CHANNELS, REGIONS, parse_gender, parse_skin_type
from facestats.core.version import __version__
from facestats.errors import FormatError, ValidationError
from facestats.io.batch import prepare_batch
from facestats.io.ids import MAX_SUBJECT_ID_LENGTH, check_subject_id
from facestats.io.matlab import read_mat
from facestats.io.root import new_store_guard
from facestats.io.schema import DOMAINS, set_provenance, set_variable_attrs
from facestats.io.store import Store, open_store

__all__ = ["REQUIRED_KEYS", "ALBEDO_KEYS", "MerlData", "read_merl", "import_merl"]

REQUIRED_KEYS = ("s_count", "subj_age", "subj_gen", "subj_skintype", "ts", "ts_region", "ts_subjec")
ALBEDO_KEYS = ("albedo", "albedo_region", "albedo_subjec")
SOURCE_FORMAT = "MERL/ETH Skin Reflectance Database ts_data.mat"


@dataclass
class MerlData:
    """The subjects of one ``ts_data.mat`` file.

    Attributes
    ----------
    path : pathlib.Path
    sha256 : str
    datasets : list of xarray.Dataset
        One sample subject per subject of the file, in file order.
    n_ts, n_albedo : int
        Torrance-Sparrow and albedo samples in the file.
    albedo_channels : int
        0 (no albedo keys), 1 or 3.
    empty : list of str
        Ids of subjects without any Torrance-Sparrow sample.
    """

    path: Path
    sha256: str
    datasets: list
    n_ts: int
    n_albedo: int
    albedo_channels: int
    empty: list = field(default_factory=list)

    @property
    def ids(self) -> list[str]:
        return [str(ds.attrs["subject_id"]) for ds in self.datasets]


class _Reader:
    def __init__(self, path: Path, mat: dict, logical=frozenset()):
        self.path = path
        self.mat = mat
        self.logical = logical  # keys stored as MATLAB logical (loadmat reads them as uint8)

    def fail(self, msg: str):
        raise FormatError(f"{self.path}: {msg}")

    def get(self, key):
        if key not in self.mat:
            present = sorted(k for k in self.mat if not k.startswith("__"))
            self.fail(f"missing key {key!r} (keys present: {present})")
        return self.mat[key]

    def numeric(self, key, value=None) -> np.ndarray:
        a = np.asarray(self.get(key) if value is None else value)
        if a.dtype.kind == "b" or (value is None and key in self.logical):
            self.fail(f"{key} must be numeric, got logical (true/false) data")
        if a.dtype == object:  # a cell array of numbers, one per cell
            cells = [np.asarray(x) for x in a.reshape(-1)]
            several = next((c for c in cells if c.size != 1), None)
            if several is not None:  # its first number alone would be read
                self.fail(f"{key} must hold one number per cell, got a cell of shape {several.shape}")
            try:
                a = np.array([c.reshape(-1)[0] for c in cells], dtype=np.float64).reshape(a.shape)
            except (TypeError, ValueError):
                self.fail(f"{key} must be numeric, got a cell array of {type(a.reshape(-1)[0]).__name__}")
        if a.dtype.kind not in "fiu":  # (MATLAB logical, refused above: true/false are no counts or indices)
            self.fail(f"{key} must be numeric, got {a.dtype} data")
        return a.astype(np.float64)

    def vector(self, key, a: np.ndarray, n: int | None = None) -> np.ndarray:
        if a.ndim > 1 and sum(d > 1 for d in a.shape) > 1:
            self.fail(f"{key} must be a vector (1×n or n×1), got shape {a.shape}")
        a = a.reshape(-1)
        if n is not None and a.size != n:
            self.fail(f"{key} must have {n} entries, got {a.size}")
        return a

    def integers(self, key, n=None, low=None, high=None, what="") -> np.ndarray:
        a = self.vector(key, self.numeric(key), n)
        bad = ~np.isfinite(a) | (a != np.round(a))
        if low is not None:
            bad |= a < low
        if high is not None:
            bad |= a > high
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            self.fail(
                f"{key}[{i + 1}] must be {what}, got {_show(a[i])}"
                + (f" ({int(bad.sum())} bad entries)" if bad.sum() > 1 else "")
            )
        return a.astype(np.int64)

    def labels(self, key, n: int) -> list:
        """S labels from a numeric vector, a char array or a cell array of strings."""
        a = np.asarray(self.get(key))
        if a.dtype.kind in "fiub":
            return self.vector(key, a.astype(np.float64), n).tolist()
        if a.dtype.kind == "U":
            flat = [s.strip() for s in a.reshape(-1).tolist()]
            if len(flat) == 1 and n > 1 and len(flat[0]) == n:
                return list(flat[0])  # 'MFM': one character per subject
            if len(flat) != n:
                self.fail(f"{key} must have {n} entries, got {len(flat)} ({flat[:5]!r}...)")
            return flat
        if a.dtype == object:
            flat = []
            for x in a.reshape(-1):
                x = np.asarray(x)
                if x.dtype.kind == "U":
                    flat.append("".join(x.reshape(-1).tolist()).strip())
                elif x.dtype.kind in "fiub" and x.size == 1:
                    flat.append(float(x.reshape(-1)[0]))
                else:
                    self.fail(f"{key} entries must be strings or numbers, got {x!r}")
            if len(flat) != n:
                self.fail(f"{key} must have {n} entries, got {len(flat)}")
            return flat
        self.fail(f"{key} must be numeric, a char array or a cell array of strings, got {a.dtype} data")

    def parsed(self, key, n: int, parse, expected: str) -> list:
        """``parse`` applied to each of the S labels of ``key``; a bad one fails naming its 1-based row."""
        out = []
        for i, v in enumerate(self.labels(key, n)):
            try:
                out.append(parse(v))
            except ValidationError:
                self.fail(f"{key}[{i + 1}] must be {expected}, got {v!r}")
        return out

    def columns(self, key, allowed) -> np.ndarray:
        """A K×c table with c in ``allowed`` (a c×K table is transposed; a vector is K×1 if 1 is allowed)."""
        a = self.numeric(key)
        if a.size == 0:
            return np.zeros((0, max(allowed)))
        if a.ndim == 1 and 1 in allowed:
            a = a[:, None]
        if a.ndim != 2:
            self.fail(f"{key} must be a K×{'/'.join(map(str, allowed))} table, got shape {a.shape}")
        if a.shape[1] not in allowed and a.shape[0] in allowed:
            a = a.T
        if a.shape[1] not in allowed:
            self.fail(f"{key} must be a K×{'/'.join(map(str, allowed))} table, got shape {a.shape}")
        return a


def _show(x) -> str:
    """A value for a message: ``11`` rather than ``np.float64(11.0)``."""
    x = float(x)
    return repr(int(x)) if x.is_integer() and abs(x) < 1e15 else repr(x)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _split(subj: np.ndarray, n: int):
    """Row indices of each subject 1..n (stable order), via one sort."""
    order = np.argsort(subj, kind="stable")
    bounds = np.searchsorted(subj[order], np.arange(1, n + 2))
    return [order[bounds[i] : bounds[i + 1]] for i in range(n)]


def read_merl(path, *, prefix: str = "merl") -> MerlData:
    """Read and check a ``ts_data.mat`` file; sample-subject Datasets, nothing written.

    ρs and m are read in the convention of Weyrich et al. 2006 eq. 12-13 (module docstring).

    Parameters
    ----------
    path : str or os.PathLike
        The MATLAB file (v7 or older; v7.3 HDF5 files are refused with a hint).
    prefix : str
        Subject ids are ``<prefix>-001`` ... (more digits for more than 999 subjects).

    Returns
    -------
    MerlData

    Raises
    ------
    FormatError
        The file cannot be read as MATLAB data, a key is missing, or a value
        is out of range (the message names the key, row and value).
    """
    _check_prefix(prefix)
    path = Path(path).expanduser().resolve()
    r = _Reader(path, *read_mat(path))
    n = _subject_count(r)
    ages = r.integers("subj_age", n, 0, 200, "an integer age in 0-200 years")
    genders = r.parsed("subj_gen", n, parse_gender, "0/1, M/F or male/female")
    types = r.parsed("subj_skintype", n, parse_skin_type, "a Fitzpatrick type 1-6 or I-VI")
    ts, ts_region, ts_subj = _read_ts(r, n)
    albedo = _read_albedo(r, n)
    albedo_channels = albedo.channels if albedo is not None else 0
    ts_rows = _split(ts_subj, n)

    sha = _sha256(path)
    width = max(3, len(str(n)))
    datasets, empty = [], []
    for i in range(n):
        sid = f"{prefix}-{i + 1:0{width}d}"
        rows = ts_rows[i]
        data = {
            "ts_sample_m": (("sample",), ts[rows, 0]),
            "ts_sample_rho_s": (("sample",), ts[rows, 1]),
            "ts_sample_region": (("sample",), ts_region[rows].astype(np.int16)),
        }
        if albedo is not None:
            data.update(albedo.variables(i))
        meta = {"age": int(ages[i]), "gender": genders[i], "skin_type": int(types[i])}
        source = {"source": str(path), "source_sha256": sha, "subject_index": i + 1, "albedo_channels": albedo_channels}
        if rows.size == 0:
            empty.append(sid)
        datasets.append(_sample_subject(sid, data, meta, source))
    return MerlData(
        path=path,
        sha256=sha,
        datasets=datasets,
        n_ts=ts.shape[0],
        n_albedo=int(albedo.values.shape[0]) if albedo is not None else 0,
        albedo_channels=albedo_channels,
        empty=empty,
    )


def _check_prefix(prefix) -> None:
    """The id prefix must make valid subject ids (:func:`facestats.io.ids.check_subject_id`)."""

    try:
        if not isinstance(prefix, str) or len(prefix) > MAX_SUBJECT_ID_LENGTH - 4:
            raise ValidationError("too long or not a string")
        check_subject_id(f"{prefix}-001")
    except ValidationError:
        raise ValidationError(
            f"prefix must make subject ids '<prefix>-001' ...: 1-{MAX_SUBJECT_ID_LENGTH - 4} letters, digits, '.', "
            f"'_' or '-' starting with a letter or digit, got {prefix!r}"
        ) from None


def _subject_count(r: _Reader) -> int:
    """``s_count``, one positive integer."""
    s = r.numeric("s_count").reshape(-1)
    if s.size != 1 or not np.isfinite(s[0]) or s[0] != round(s[0]) or s[0] < 1:
        r.fail(f"s_count must be one positive integer, got {r.get('s_count')!r}")
    return int(s[0])


def _read_ts(r: _Reader, n: int):
    """The checked Torrance-Sparrow samples: ``ts`` (K, 2) [m, rho_s], their regions and 1-based subjects."""
    ts = r.columns("ts", (2,))
    k = ts.shape[0]
    bad = ~np.isfinite(ts).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        r.fail(f"ts row {i + 1} must be finite, got {ts[i].tolist()}")
    for col, name, var in ((0, "m", "ts_sample_m"), (1, "rho_s", "ts_sample_rho_s")):
        ok = ~DOMAINS[var].outside(ts[:, col])
        if not ok.all():
            i = int(np.flatnonzero(~ok)[0])
            r.fail(
                f"ts row {i + 1}: {name} (column {col}) must be {DOMAINS[var].violated(ts[i, col])}, "
                f"got {_show(ts[i, col])}"
                + (f" ({int((~ok).sum())} bad rows)" if (~ok).sum() > 1 else "")
                + f" (physical domain {DOMAINS[var].describe()}, facestats.io.schema.DOMAINS)"
            )
    ts_region = r.integers("ts_region", k, 1, max(REGIONS), "a region 1-10")
    ts_subj = r.integers("ts_subjec", k, 1, n, f"a subject index 1-{n}")
    return ts, ts_region, ts_subj


@dataclass
class _Albedo:
    """The albedo samples of a file: values (K', 3), regions, rows of each subject, channels in the file."""

    values: np.ndarray
    region: np.ndarray
    rows: list
    channels: int

    def variables(self, i: int) -> dict:
        """The albedo variables of subject ``i`` (0-based)."""
        rows = self.rows[i]
        return {
            "albedo_sample": (("albedo_sample", "channel"), self.values[rows]),
            "albedo_sample_region": (("albedo_sample",), self.region[rows].astype(np.int16)),
        }


def _read_albedo(r: _Reader, n: int) -> _Albedo | None:
    """The checked albedo samples, or None if the file has none (all three keys or none)."""
    present = [key for key in ALBEDO_KEYS if key in r.mat]
    if present and len(present) != len(ALBEDO_KEYS):
        r.fail(f"albedo data need all of {list(ALBEDO_KEYS)}, got only {present}")
    if not present:
        return None
    alb = r.columns("albedo", (1, 3))
    channels = alb.shape[1]
    ka = alb.shape[0]
    ok = np.isfinite(alb).all(axis=1) & (alb >= 0).all(axis=1) & (alb <= 1).all(axis=1)
    if not ok.all():
        i = int(np.flatnonzero(~ok)[0])
        r.fail(f"albedo row {i + 1} must lie in [0, 1], got {alb[i].tolist()}")
    if channels == 1:
        alb = np.repeat(alb, 3, axis=1)
    alb_region = r.integers("albedo_region", ka, 1, max(REGIONS), "a region 1-10")
    alb_subj = r.integers("albedo_subjec", ka, 1, n, f"a subject index 1-{n}")
    return _Albedo(alb, alb_region, _split(alb_subj, n), channels)


def _sample_subject(sid: str, data: dict, meta: dict, source: dict):
    """A sample subject: ``data`` variables, ``meta`` (age, gender, skin type), provenance from ``source``."""
    import xarray as xr

    ds = xr.Dataset(
        data,
        coords={"channel": list(CHANNELS)},
        attrs={"subject_id": sid, "person_id": sid, **meta, "condition": "normal", "provenance": "{}"},
    )
    set_variable_attrs(ds)
    set_provenance(ds, **source, source_format=SOURCE_FORMAT, software_version=__version__)
    return ds


def import_merl(path, store, *, prefix: str = "merl", overwrite: bool = False) -> MerlData:
    """Import a ``ts_data.mat`` file into a store (all subjects in one atomic commit).

    Parameters
    ----------
    path : str or os.PathLike
        The MATLAB file.
    store : facestats.io.store.Store or str or os.PathLike
        A writable store, or a directory path (created if missing).
    prefix : str
        Subject ids are ``<prefix>-001`` ...
    overwrite : bool
        Replace subjects of the same ids (otherwise :class:`StoreError`).

    Returns
    -------
    MerlData
        What was read (ids, sample counts, subjects without samples).
    """

    data = read_merl(path, prefix=prefix)
    prepare_batch(data.datasets)  # every subject checked before a store is created or touched
    if not isinstance(store, Store):
        with new_store_guard(store), open_store(store, mode="a") as st:
            st.write_subjects(data.datasets, overwrite=overwrite)
    else:
        store.write_subjects(data.datasets, overwrite=overwrite)
    return data
