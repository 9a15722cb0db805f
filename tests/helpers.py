"""Helpers shared by the tests: geometry samples, small subjects and populations, the CLI, notebooks, MERL files.

One module, imported as ``from tests.helpers import ...`` everywhere.
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import subprocess
import sys

import nbformat
import numpy as np
import pandas as pd
import scipy.io
import xarray as xr
from nbclient import NotebookClient

import facestats.cli
from facestats.acquire.sensor import default_fiber_distances
from facestats.core.conventions import CHANNELS, CONDITIONS, SITES
from facestats.io.schema import set_variable_attrs
from facestats.io.summary import summarise_subject
from facestats.model import dipole

NOTEBOOKS = pathlib.Path(__file__).resolve().parent.parent / "notebooks"
TEST_DATA = pathlib.Path(__file__).resolve().parent / "data"


# -- directions ------------------------------------------------------------------------------
def random_hemisphere(rng, n, normal=(0.0, 0.0, 1.0), min_cos=0.05):
    """Uniform random unit vectors with N·ω ≥ min_cos around ``normal``."""
    normal = np.asarray(normal, float)
    normal = normal / np.linalg.norm(normal)
    out = np.empty((0, 3))
    while len(out) < n:
        v = rng.normal(size=(4 * n, 3))
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        out = np.concatenate([out, v[v @ normal >= min_cos]])
    return out[:n]


def hemisphere_pairs(rng, texels, samples):
    """Random (ωi, ωo) pairs above the z = 0 plane, each (texels, samples, 3), unit length.

    Not uniform (unlike :func:`random_hemisphere`): normal draws folded to z > 0 and lifted by 0.05
    before normalising, which favours directions near the pole as a dome's cameras and lights do.
    The fit tests' tolerances were set on this distribution.
    """
    v = rng.normal(size=(2, texels, samples, 3))
    v[..., 2] = np.abs(v[..., 2]) + 0.05
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return v[0], v[1]


# -- subjects and populations ----------------------------------------------------------------
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
            "provenance": json.dumps({"source": "tests.helpers", "seed": seed}),
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


#: Skin-type frequencies of Weyrich Table 2 (types II-VI).
_TYPE_P = np.array([14, 67, 48, 15, 5]) / 149


class MemoryStore:
    """In-memory stand-in of the store interface used by :mod:`facestats.analysis`."""

    def __init__(self, datasets):
        self._ds = {str(ds.attrs["subject_id"]): ds for ds in datasets}
        self._index = pd.DataFrame.from_records([summarise_subject(ds) for ds in datasets]).set_index("subject_id")

    def subjects(self):
        return self._index.copy()

    def subject(self, subject_id, *, lazy=False, variables=None):
        return self._ds[subject_id]

    def datasets(self):
        """The subject Datasets, in the order given."""
        return list(self._ds.values())


def make_population(n=40, seed=0, size=24, conditions=True):
    """``n`` normal-condition subjects (skin types as Table 2) plus one person under the seven conditions.

    ρs rises with skin type and is higher for women (so CCA has something to
    find); σtr rises 4 % per skin type.
    """
    rng = np.random.default_rng(seed)
    datasets = []
    for i in range(n):
        st = int(rng.choice([2, 3, 4, 5, 6], p=_TYPE_P)) if i >= 5 else 2 + i  # every type present
        if st == 2 and rng.uniform() < 0.3:
            st = 1  # some type I subjects (grouped with II)
        gender = "F" if rng.uniform() < 0.3 else "M"
        age = int(rng.integers(18, 66))
        shift = 0.02 * (st - 3) + 0.015 * (gender == "F") + 0.004 * rng.standard_normal()
        ds = make_map_subject(
            f"S{i:03d}", size=size, skin_type=st, gender=gender, age=age, seed=seed * 1000 + i, rho_shift=shift
        )
        ds["site_sigma_tr"] = ds["site_sigma_tr"] * (1 + 0.04 * (st - 3))
        datasets.append(ds)
    if conditions:
        for j, cond in enumerate(CONDITIONS):
            datasets.append(
                make_map_subject(
                    f"C{j}",
                    size=size,
                    skin_type=3,
                    gender="M",
                    age=30,
                    condition=cond,
                    seed=seed * 1000 + 900 + j,
                    rho_shift=0.03 * j,
                    person_id="P-cond",
                )
            )
    return MemoryStore(datasets)


# -- a flat slab and its reference reflectance (the Mitsuba export's check) ------------------------------------
def flat_slab(half_width=150.0, cells=8):
    """A flat square mesh in the plane z = 0 facing +z (mm), UVs over [0, 1]²: a semi-infinite slab's surface."""
    g = np.linspace(-half_width, half_width, cells + 1)
    x, y = np.meshgrid(g, g)
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    uv = np.stack([x.ravel() + half_width, half_width - y.ravel()], 1) / (2 * half_width)
    idx = np.arange(len(vertices)).reshape(cells + 1, cells + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])  # counter-clockwise seen from +z
    normals = np.tile([0.0, 0.0, 1.0], (len(vertices), 1))
    from facestats.io.mesh import FaceMesh

    return FaceMesh(vertices, faces, uv, normals, {"kind": "mesh", "name": "flat-slab"})


def slab_reflectance(albedo, eta, photons=50_000, seed=0):
    """Reflectance at normal incidence of a semi-infinite isotropically scattering medium of single-scattering
    albedo ``albedo`` (per channel) under a smooth boundary of relative index ``eta``, by Monte Carlo.

    Photons enter along the normal with weight 1 − F(0); free paths are exponential in units of 1/σt (the
    slab has no other length, so the result does not depend on σt); at each scattering the weight is
    multiplied by the albedo and the direction cosine redrawn uniformly in [−1, 1] (isotropic); at the
    boundary F_r(μ, 1/η) (total internal reflection included) is reflected back and 1 − F_r leaves.
    Photons below 1e-4 of their weight are dropped (a bias below 1e-4).  Under uniform radiance 1 the
    reflected radiance towards the normal equals this reflectance (reciprocity)."""
    from facestats.model.fresnel import fresnel_reflectance

    rng = np.random.default_rng(seed)
    albedo = np.asarray(albedo, np.float64)
    channel = np.repeat(np.arange(albedo.size), photons)
    f0 = float(fresnel_reflectance(1.0, eta))
    z, mu, w = np.zeros(channel.size), -np.ones(channel.size), np.full(channel.size, 1 - f0)
    out = np.zeros(albedo.size)
    while w.size:
        z = z + mu * rng.exponential(size=w.size)
        hit = z >= 0
        r = fresnel_reflectance(mu[hit], 1 / eta)
        out += np.bincount(channel[hit], w[hit] * (1 - r), minlength=albedo.size)
        w[hit] *= r
        z[hit], mu[hit] = 0.0, -mu[hit]  # reflected back in: a fresh free path (exponential: memoryless)
        w[~hit] *= albedo[channel[~hit]]
        mu[~hit] = rng.uniform(-1, 1, np.count_nonzero(~hit))
        keep = w > 1e-4
        z, mu, w, channel = z[keep], mu[keep], w[keep], channel[keep]
    return f0 + out / photons


# -- MERL/ETH files --------------------------------------------------------------------------
def merl_dict(rng=None, n=4, k=200, ka=120, albedo_cols=3):
    """A valid ts_data.mat content: column vectors, numeric codes."""
    rng = rng or np.random.default_rng(7)
    subj = np.concatenate([np.arange(1, n + 1), rng.integers(1, n + 1, k - n)])
    asubj = np.concatenate([np.arange(1, n + 1), rng.integers(1, n + 1, ka - n)])
    d = {
        "s_count": np.array([[n]], dtype=float),
        "subj_age": (np.arange(n) * 9 + 21).reshape(-1, 1).astype(float),
        "subj_gen": (np.arange(n) % 2).reshape(-1, 1).astype(float),
        "subj_skintype": (np.arange(n) % 5 + 2).reshape(-1, 1).astype(float),
        "ts": np.column_stack([rng.uniform(0.2, 0.5, k), rng.uniform(0.05, 0.4, k)]),
        "ts_region": rng.integers(1, 11, (k, 1)).astype(float),
        "ts_subjec": subj.reshape(-1, 1).astype(float),
    }
    if albedo_cols:
        d["albedo"] = rng.uniform(0.05, 0.7, (ka, albedo_cols))
        d["albedo_region"] = rng.integers(1, 11, (ka, 1)).astype(float)
        d["albedo_subjec"] = asubj.reshape(-1, 1).astype(float)
    return d


def save_mat(tmp_path, d, name="ts_data.mat"):
    p = tmp_path / name
    scipy.io.savemat(p, d)
    return p


# -- the command line ------------------------------------------------------------------------
def real_bracket_dir():
    """``frobisher_001`` of colour-science/colour-hdri-tests-datasets (three Canon EOS 5D Mark II JPEGs, 1/8, 1 and
    8 s on a tripod; BSD-licensed project, no licence file of its own, so not committed):
    ``$FACESTATS_COLOUR_HDRI_DATASETS/frobisher_001``; the test is skipped without it."""
    import pytest

    root = os.environ.get("FACESTATS_COLOUR_HDRI_DATASETS")
    d = pathlib.Path(root) / "frobisher_001" if root else None
    if d is None or not (d / "IMG_2600.jpg").is_file():
        pytest.skip(
            "real bracket absent: set FACESTATS_COLOUR_HDRI_DATASETS to a checkout of "
            "colour-science/colour-hdri-tests-datasets (frobisher_001: three Canon JPEGs, 1/8, 1 and 8 s)"
        )
    return d


def facestats_exe():
    exe = pathlib.Path(sys.executable).parent / "facestats"
    if exe.exists():
        return [str(exe)]
    found = shutil.which("facestats")
    if found:
        return [found]
    return [sys.executable, "-m", "facestats"]


def run_cli(*args, cwd=None, timeout=600, env=None):
    e = dict(os.environ, MPLBACKEND="Agg", PYTHONWARNINGS="ignore")
    if env:
        e.update(env)
    return subprocess.run(
        facestats_exe() + [str(a) for a in args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=e,
        stdin=subprocess.DEVNULL,
    )


class Hung(Exception):
    """A command run by :func:`run_main` did not finish within its ``timeout``."""


def _alarm(signum, frame):
    raise Hung("the command did not finish in time (blocked on a FIFO or a lock?)")


#: ``(parser, [(action, copy of its default)])`` of :func:`_shared_parser`, built on first use.
_PARSER: tuple | None = None


def _mutable_defaults(parser) -> list:
    """The actions of ``parser`` and of all its subcommands' parsers whose default is a list, dict or set."""
    import argparse
    import copy

    out = []
    for action in parser._actions:
        if isinstance(action.default, (list, dict, set)):
            out.append((action, copy.deepcopy(action.default)))
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):  # aliases map to the same parser
                out += _mutable_defaults(sub)
    return out


def _shared_parser():
    """The ``facestats`` parser every :func:`run_main` of this process uses, built by ``build_parser`` once.

    Building it takes about 17 ms, as long as many of the commands the corpora run (hundreds of runs per module).
    argparse keeps no state between two parses but the default values it puts into the namespace: a command that
    changed a mutable default in place would change the next run's, so :func:`run_main` checks after every command
    that none did (:func:`_check_defaults`).
    """
    global _PARSER
    if _PARSER is None:
        parser = _BUILD_PARSER()
        _PARSER = (parser, _mutable_defaults(parser))
    return _PARSER[0]


def _check_defaults() -> None:
    """Fail (and drop the shared parser) if a command changed a mutable default of :func:`_shared_parser`'s parser."""
    global _PARSER
    if _PARSER is None:
        return
    changed = [a.dest for a, value in _PARSER[1] if a.default != value]
    if changed:
        _PARSER = None
        raise AssertionError(f"a command changed the parser's defaults of {changed}: the next run would see them")


#: The command line's own ``build_parser``, which :func:`run_main` swaps for :func:`_shared_parser` while it runs.
_BUILD_PARSER = facestats.cli.build_parser


def run_main(*args, cwd=None, env=None, timeout: float = 600.0):
    """``facestats ARGS`` run by :func:`facestats.cli.main` in this process, reported as :func:`run_cli` reports it.

    For the checks whose subject is the command's answer (its exit code, its message, what it wrote), not the
    console script's process: each :func:`run_cli` costs a Python start-up and the imports (1-2 s), while the
    console script is ``sys.exit(main())``, so the code ``main`` returns is the process's exit status.  argparse's
    ``SystemExit`` (a malformed command line) becomes the returned code as the process would exit with it.
    ``cwd`` is the working directory and ``env`` (name -> value) is set for the call, both restored afterwards;
    the command line is parsed by one parser per process (:func:`_shared_parser`).  A command still running after
    ``timeout`` seconds raises :class:`Hung` (a test failure, not a hang).  It sees what Python code writes to
    ``sys.stdout`` and ``sys.stderr``, not what a library writes to the file descriptors, nor warnings (pytest
    records them; the console script under :func:`run_cli` ignores them): a check that a stream stays empty
    (``--quiet``) or that a warning is shown belongs to :func:`run_cli`.

    Returns
    -------
    subprocess.CompletedProcess
        ``returncode``, ``stdout`` and ``stderr`` (text) of the call.
    """
    import contextlib
    import io
    import signal

    argv = [str(a) for a in args]
    before = {name: os.environ.get(name) for name in env or {}}
    out, err = io.StringIO(), io.StringIO()
    old_cwd = os.getcwd()
    previous = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, timeout)
    facestats.cli.build_parser = _shared_parser
    try:
        os.environ.update({name: str(value) for name, value in (env or {}).items()})
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = facestats.cli.main(argv)
            except SystemExit as exc:  # as the interpreter exits with it: None is 0, a message is printed and 1
                code = 0 if exc.code is None else exc.code if isinstance(exc.code, int) else 1
                if not isinstance(exc.code, (int, type(None))):
                    print(exc.code, file=sys.stderr)
    finally:
        facestats.cli.build_parser = _BUILD_PARSER
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
        os.chdir(old_cwd)
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    _check_defaults()
    return subprocess.CompletedProcess(facestats_exe() + argv, code, out.getvalue(), err.getvalue())


# -- notebooks -------------------------------------------------------------------------------


def read_committed(path):
    """The notebook as committed, asserted to be valid nbformat 4 with code cells and no outputs."""
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(c.outputs == [] and c.execution_count is None for c in code)
    return nb


def execute(path, workdir, env=None):
    """The notebook at ``path`` after running every cell with ``workdir`` as the working directory.

    ``env`` (name -> value) is set for the kernel, which inherits this process's environment, and
    restored afterwards.
    """
    nb = nbformat.read(path, as_version=4)
    before = {name: os.environ.get(name) for name in env or {}}
    os.environ.update({name: str(value) for name, value in (env or {}).items()})
    try:
        NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(workdir)}}).execute()
    finally:
        for name, value in before.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    return nb


def once_per_session(name, tmp_path_factory, make):
    """The folder ``make(folder)`` filled, made once per test session even under ``pytest -n N``.

    A module fixture runs once per worker that gets one of the module's tests, and xdist's
    ``loadgroup`` cannot keep a module on one worker with pytest 9.2 (xdist sets ``item._nodeid``,
    pytest 9.2 reads ``item._id``).  So the first worker to ask calls ``make`` holding a lock in the
    session's shared temporary folder, and marks the folder done when ``make`` returned; the others
    wait for the lock and reuse the folder.  A ``make`` that raised leaves the folder unmarked: the next
    caller empties it and tries again (and meets the same failure).
    """
    import fcntl

    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # the session's folder under xdist
    folder, done = shared / f"once-{name}", shared / f"once-{name}.done"
    with open(shared / f"once-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            make(folder)
            done.touch()
    return folder


def execute_once(path, tmp_path_factory, env=None):
    """``(notebook executed by :func:`execute`, its working directory)``, run once per test session.

    The working directory is ``workdir/`` of a :func:`once_per_session` folder; the executed notebook
    is saved beside it.
    """

    def run(folder):
        (folder / "workdir").mkdir()
        (folder / "tmp").mkdir()
        env_tmp = {**(env or {}), "TMPDIR": folder / "tmp"}  # the kernel's tempfile folder, checked afterwards
        nbformat.write(execute(path, folder / "workdir", env=env_tmp), folder / "executed.ipynb")

    folder = once_per_session(f"notebook-{pathlib.Path(path).stem}", tmp_path_factory, run)
    return nbformat.read(folder / "executed.ipynb", as_version=4), folder / "workdir"


def assert_nothing_left(workdir):
    """Nothing left by a notebook run by :func:`execute_once`: its working directory and its kernel's temporary
    folder (``TMPDIR``) are empty after the last cell, but for Dask's shared ``dask-scratch-space`` holding only its
    lock files (Dask keeps that folder for every later cluster)."""
    assert list(workdir.iterdir()) == []
    tmp = workdir.parent / "tmp"
    dask = tmp / "dask-scratch-space"
    left = [p for p in tmp.iterdir() if p != dask] + [p for p in dask.rglob("*") if p.is_file() and p.suffix != ".lock"]
    assert left == [], f"left in the temporary folder: {[p.name for p in left]}"


def cell_text(cell):
    """All text a cell displayed (streams and text/plain results)."""
    parts = []
    for o in cell.outputs:
        if o.output_type == "stream":
            parts.append(o.text)
        elif "data" in o:
            parts.append(o.data.get("text/plain", ""))
    return "\n".join(parts)


def tagged(nb, tag):
    """The one cell carrying ``tag`` in its metadata."""
    cells = [c for c in nb.cells if tag in c.metadata.get("tags", [])]
    assert len(cells) == 1, f"expected one cell tagged {tag!r}"
    return cells[0]


def assert_no_errors(nb):
    """Assert that every code cell of an executed notebook ran and none displayed an error."""
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.execution_count is not None
            errors = [o for o in cell.outputs if o.output_type == "error"]
            assert not errors, f"{errors[0].ename}: {errors[0].evalue}"


def shows_figure(cell):
    """True if the cell displayed a PNG image."""
    return any("image/png" in o.get("data", {}) for o in cell.outputs)


def store_from_default(path, ids=("S001", "S002", "S003", "S004", "S005", "S006", "S007", "S008")):
    """A small directory store at ``path`` holding copies of some subjects of the embedded default store."""
    from facestats.io.store import open_store

    with open_store(None) as src, open_store(path, mode="a") as dst:
        dst.write_subjects([src.subject(sid) for sid in ids])
    return str(path)


def with_micro_normals(ds, cameras=3, seed=0):
    """``ds`` with a ``cameras``-camera micro-normal map (``camera``, ``v``, ``u``, ``component``): random unit
    vectors on the face texels, 0 outside."""
    n = np.random.default_rng(seed).standard_normal((cameras,) + ds["region"].shape + (3,)).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[:, ds["region"].values == 0] = 0
    return ds.assign(micro_normal=(("camera", "v", "u", "component"), n, {"units": "1"}))
