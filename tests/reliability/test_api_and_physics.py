"""API misuse and silent wrong results: clear errors, finite physics over the documented domains, degenerate cases.

* Every public physics function (``fresnel``, ``brdf``, ``dipole``) given ``None``, an object, a dict
  or a string for any argument raises :class:`ValidationError` naming it (generated from signatures).
* The issue's API cases: ``skin_type`` 'abc'/None on write, ``open_store(123)``, ``transfer_texture``
  with an empty image, ``seed='abc'``, ``bins=10**9``.
* Numerics: ``scattering_from_albedo`` finite up to albedo → 1 in float32 and float64 with σtr
  reproduced; ``torrance_sparrow(m=1e-200)`` and ``blinn_phong(rho_s=1e308)`` raise;
  ``dipole_profile(1, 1e200, 1e200)`` is finite.
* Degenerate transfers: a constant source goes to the target's mean (inside its range).
* ``fit_specular``: non-unit directions refused; f_s × 1e30 ends at the ρs bound flagged ``at_bound``;
  f_s × 1e-30 is fitted exactly (ρs × 1e-30).
* Physical domains of stored variables, on write and in validate, and in MERL imports; the ρs bound
  of Torrance-Sparrow checked by a numerical integral.
* Checks before work, no side effects: ``transfer_colour`` names an empty source or target and refuses
  ``bins=10**12`` before allocating; ``Dome.load`` refuses a FIFO, a device or a directory at once;
  ``generate_neutral_map`` checks its output path and numbers before generating (and writes all or
  nothing); the emulators check every argument before drawing the subject or creating a folder, and
  remove the folders they created when starting fails.
"""

import contextlib
import inspect
import os
import re
import signal
import tempfile

import numpy as np
import pytest
import scipy.io

from facestats.core.conventions import FLAG_BITS
from facestats.errors import FacestatsError, FormatError, SchemaError, StoreError, ValidationError
from facestats.io import batch, open_store
from facestats.io.merl import read_merl
from facestats.io.schema import TS_RHO_S_MAX
from facestats.model import brdf, dipole, fresnel
from tests.helpers import hemisphere_pairs, make_map_subject, merl_dict

GOOD = {
    "normal": np.array([0.0, 0.0, 1.0]),
    "wi": np.array([0.6, 0.0, 0.8]),
    "wo": np.array([-0.6, 0.0, 0.8]),
    "rho_s": 0.3,
    "m": 0.3,
    "exponent": 20.0,
    "eta": 1.38,
    "cos_i": 0.7,
    "cos_theta": 0.7,
    "r": 1.0,
    "radius": 1.0,
    "sigma_s_prime": 1.0,
    "sigma_a": 0.05,
    "sigma_tr": 0.55,
    "albedo": 0.5,
    "total_reflectance": 0.5,
    "cos_delta": 0.9,  # the building blocks of brdf: N·H, N·ωi, N·ωo, ωo·H, ωi·ωo
    "n_h": 0.9,
    "n_wi": 0.8,
    "n_wo": 0.8,
    "wo_h": 0.95,
    "wi_wo": 0.28,
}
BAD = [None, object(), {"a": 1}, {}, "abc", [1, "a"], [[1, 2], [3]]]


def _physics():
    for module in (fresnel, brdf, dipole):
        for name in module.__all__:
            fn = getattr(module, name)
            params = [p for p in inspect.signature(fn).parameters.values() if p.name in GOOD]
            if params and all(p.name in GOOD for p in inspect.signature(fn).parameters.values()):
                yield fn, [p.name for p in params]


CALLS = [(fn, arg) for fn, args in _physics() for arg in args]


def test_every_public_physics_function_is_covered():
    """The table of valid arguments knows every parameter: no public function is skipped by the generated test."""
    covered = {fn for fn, _ in CALLS}
    public = {getattr(m, name) for m in (fresnel, brdf, dipole) for name in m.__all__}
    assert public == covered, sorted(f.__name__ for f in public - covered)


@pytest.mark.parametrize("fn, arg", CALLS, ids=[f"{f.__name__}-{a}" for f, a in CALLS])
def test_physics_functions_name_non_numeric_arguments(fn, arg):
    params = inspect.signature(fn).parameters
    for bad in BAD:
        kwargs = {p: GOOD[p] for p in params}
        kwargs[arg] = bad
        with pytest.raises(ValidationError, match=arg):
            fn(**kwargs)


def test_the_api_cases(tmp_path):
    from facestats.edit import transfer_texture

    with open_store(tmp_path / "s.zarr", mode="a") as st:
        for bad in ("abc", None, 3.5, True):
            ds = make_map_subject("A1", size=16)
            ds.attrs["skin_type"] = bad
            with pytest.raises(SchemaError, match="skin_type must be an integer 1-6"):
                st.write_subject(ds)
        assert len(st) == 0
    for bad in (123, 1.5, ["x"], b"", "", "\0"):
        with pytest.raises(ValidationError, match="path must"):
            open_store(bad)
    rng = np.random.default_rng(0)
    target = rng.uniform(0.2, 0.7, (64, 64, 3))
    for empty in ((0, 0, 3), (0, 64, 3), (64, 0, 3)):
        got = re.escape(f"must hold at least one pixel, got shape {empty}")
        with pytest.raises(ValidationError, match="^source_albedo " + got):
            transfer_texture(np.zeros(empty), target)
        with pytest.raises(ValidationError, match="^target " + got):  # an empty target, not only the source
            transfer_texture(target, np.zeros(empty))
    for seed, pattern in (("abc", "seed must be an integer"), (-1, r"seed must be an integer in \[0")):
        with pytest.raises(ValidationError, match=pattern):
            transfer_texture(target, target, seed=seed)
    with pytest.raises(ValidationError, match=r"bins must be an integer in \[2, 65536\]"):
        transfer_texture(target, target, bins=10**9)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_scattering_from_albedo_is_finite_up_to_one(dtype):
    top = np.nextafter(dtype(1), dtype(0))  # the largest albedo below 1 of the dtype
    albedo = np.array([0.01, 0.5, 0.9995, 1 - 1e-7, top], dtype=dtype)
    sigma_tr = np.full(albedo.shape, 0.55, dtype)
    sp, sa = dipole.scattering_from_albedo(albedo, sigma_tr)
    assert sp.dtype == dtype and np.all(np.isfinite(sp)) and np.all(np.isfinite(sa)) and np.all(sa > 0)
    assert np.all(np.diff(sp) > 0)  # more albedo, more scattering
    np.testing.assert_allclose(dipole.transport_coefficient(sa.astype(float), sp.astype(float)), 0.55, rtol=1e-6)
    back = dipole.total_diffuse_reflectance(sp.astype(float), sa.astype(float))
    np.testing.assert_allclose(back[:3], albedo[:3].astype(float), rtol=1e-6)


def test_extreme_parameters_give_finite_results_or_errors():
    n, wi, wo = GOOD["normal"], GOOD["wi"], GOOD["wo"]
    with pytest.raises(ValidationError, match="torrance_sparrow is not finite.*m = 1e-200"):
        brdf.torrance_sparrow(n, n, n, 0.3, 1e-200)
    with pytest.raises(ValidationError, match="m = 1e-200"):  # 1/m² underflows m²: an error, not NaN
        brdf.torrance_sparrow(n, wi, wo, 0.3, 1e-200)
    assert np.isfinite(brdf.torrance_sparrow(n, wi, wo, 0.3, 1e-6))
    with pytest.raises(ValidationError, match="blinn_phong is not finite.*rho_s = 1e\\+308"):
        brdf.blinn_phong(n, wi, wo, 1e308, 20.0)
    assert dipole.dipole_profile(1.0, 1e200, 1e200) == 0.0  # an opaque medium: no light 1 mm away
    with pytest.raises(ValidationError, match="dipole_profile is not finite"):
        dipole.dipole_profile(1.0, 1e308, 1e308)


def test_the_building_blocks_give_finite_results_or_errors():
    with pytest.raises(ValidationError, match="beckmann_distribution is not finite.*m = 1e-200"):
        brdf.beckmann_distribution(0.9, 1e-200)  # was ZeroDivisionError
    assert np.isfinite(brdf.beckmann_distribution(0.9, 1e-6))
    with pytest.raises(ValidationError, match="eta must be numeric"):
        brdf.torrance_sparrow_cosines(0.8, 0.8, 0.28, eta=None)  # was ignored (F_r = 1)
    with pytest.raises(ValidationError, match="torrance_sparrow_cosines .* n_wi = 1e-300"):
        brdf.torrance_sparrow_cosines(1e-300, 1e-300, 0.28)
    assert brdf.v_groove_shadowing(1e300, 1e300, 1e300, 1e-300) == 1.0
    assert np.isfinite(brdf.blinn_phong_lobe(1.0, 1.7e308))
    sigma_tr = dipole.transport_coefficient(1e200, 1e200)  # was inf: sqrt(3 σa) sqrt(σ't) does not overflow
    assert sigma_tr == pytest.approx(np.sqrt(6) * 1e200)
    with pytest.raises(ValidationError, match="transport_coefficient is not finite.*sigma_a = 1e\\+308"):
        dipole.transport_coefficient(1e308, 1e308)
    with pytest.raises(ValidationError, match="diffuse_mean_free_path is not finite.*sigma_tr = 5e-324"):
        dipole.diffuse_mean_free_path(5e-324)  # was inf
    for fn, args in (
        (brdf.beckmann_distribution, (1.5, 0.3)),
        (brdf.beckmann_distribution, (0.9, 0.0)),
        (brdf.blinn_phong_lobe, (0.9, -1.0)),
        (brdf.v_groove_shadowing, (0.9, 0.0, 0.8, 0.95)),
        (brdf.torrance_sparrow_cosines, (np.nan, 0.8, 0.28)),
    ):
        with pytest.raises(ValidationError, match="must (lie in|be finite)"):
            fn(*args)


def test_a_constant_source_moves_to_the_targets_mean():
    from facestats.edit import transfer_colour, transfer_texture

    rng = np.random.default_rng(1)
    target = rng.uniform(0.2, 0.7, (64, 64, 3))
    const = np.full((64, 64, 3), 0.05)
    for out in (transfer_colour(const, target), transfer_texture(const, target, levels=3, seed=0).albedo):
        px = out.reshape(-1, 3)
        np.testing.assert_allclose(px.mean(0), target.reshape(-1, 3).mean(0), atol=0.02)
    px = transfer_colour(const, target).reshape(-1, 3)
    assert np.all(px >= 0.2) and np.all(px <= 0.7)
    # The texture transfer starts from noise of the target's spread (a constant source has none of its own), so it
    # takes the target's spread too; each decorrelated channel is matched alone, so RGB may leave [0.2, 0.7].
    tex = transfer_texture(const, target, levels=3, seed=0).albedo.reshape(-1, 3)
    np.testing.assert_allclose(tex.std(0), target.reshape(-1, 3).std(0), rtol=0.3)
    half = transfer_colour(const, target, t=0.5).reshape(-1, 3).mean(0)
    np.testing.assert_allclose(half, 0.5 * (0.05 + target.reshape(-1, 3).mean(0)), atol=0.02)


def test_fit_specular_checks_units_and_flags_bounds():
    from facestats.model.fitting import fit_specular

    rng = np.random.default_rng(2)
    wi, wo = hemisphere_pairs(rng, 8, 150)
    normal = np.tile([0.0, 0.0, 1.0], (8, 1))
    fs = brdf.torrance_sparrow(normal[:, None, :], wi, wo, 0.3, 0.35)
    valid = np.ones(fs.shape, bool)
    with pytest.raises(ValidationError, match="normal must hold unit vectors"):
        fit_specular(wi, wo, normal * 1.1, fs, valid, "torrance_sparrow")
    with pytest.raises(ValidationError, match="wo must hold unit vectors .* texel 0, sample 0"):
        fit_specular(wi, wo * 0.5, normal, fs, valid, "torrance_sparrow")
    plain = fit_specular(wi, wo, normal, fs, valid, "torrance_sparrow")
    np.testing.assert_allclose(plain.rho_s, 0.3, rtol=1e-3)
    assert np.all(plain.flags == 0)
    huge = fit_specular(wi, wo, normal, fs * 1e30, valid, "torrance_sparrow")
    assert np.all(huge.rho_s == 5.0) and np.all(huge.flags & FLAG_BITS["at_bound"])  # the ρs bound of DEFAULT_BOUNDS
    tiny = fit_specular(wi, wo, normal, fs * 1e-30, valid, "torrance_sparrow")
    np.testing.assert_allclose(tiny.rho_s, plain.rho_s * 1e-30, rtol=1e-5)
    np.testing.assert_allclose(tiny.lobe, plain.lobe, rtol=1e-5)
    assert np.all(tiny.flags == 0)


def _normal_incidence_albedo(m, rho_s, n=900):
    """∫ f_s cos θo dωo at normal incidence (midpoint rule in (cos θo, φ))."""
    mu = (np.arange(n) + 0.5) / n
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    mu_g, phi_g = np.meshgrid(mu, phi, indexing="ij")
    s = np.sqrt(1 - mu_g**2)
    wo = np.stack([s * np.cos(phi_g), s * np.sin(phi_g), mu_g], -1)
    n_ = np.array([0.0, 0.0, 1.0])
    f = brdf.torrance_sparrow(n_, n_, wo, rho_s, m)
    return float((f * mu_g).sum() / n * np.pi / n)


def test_the_torrance_sparrow_rho_bound_reflects_all_light():
    assert TS_RHO_S_MAX == pytest.approx(9.8068, abs=1e-4)
    assert _normal_incidence_albedo(0.1, TS_RHO_S_MAX) == pytest.approx(1.0, abs=2e-3)
    assert _normal_incidence_albedo(0.3, TS_RHO_S_MAX) == pytest.approx(1.0, abs=5e-3)
    assert _normal_incidence_albedo(0.6, TS_RHO_S_MAX) < 1.0


BAD_VALUES = {
    "ts_m": (lambda ds: ds["ts_m"].values.__imul__(-1), "'ts_m' must lie in \\(0, 10\\]"),
    "albedo": (lambda ds: ds["albedo"].values.__imul__(50), "'albedo' must lie in \\[0, 1\\]"),
    "sigma_a": (lambda ds: ds["sigma_a"].values.__setitem__(0, np.inf), "'sigma_a' must lie in \\[0, inf\\)"),
    "bp_exponent": (lambda ds: ds["bp_exponent"].values.__imul__(-1), "'bp_exponent' must lie in \\[0, inf\\)"),
    "ts_rho_s": (lambda ds: ds["ts_rho_s"].values.__iadd__(20), "'ts_rho_s' must lie in \\[0, 9.80679\\]"),
    "bp_rho_s": (lambda ds: ds["bp_rho_s"].values.__iadd__(1), "'bp_rho_s' must lie in \\[0, 1\\]"),
    "ts_flag": (lambda ds: ds["ts_flag"].values.__iadd__(64), "'ts_flag' must lie in \\[0, 63\\]"),  # the six FLAG_BITS
}


@pytest.mark.parametrize("name", list(BAD_VALUES))
def test_impossible_physics_is_refused_on_write_and_in_validate(tmp_path, monkeypatch, name):
    change, pattern = BAD_VALUES[name]
    ds = make_map_subject("P1", size=16)
    change(ds)
    with open_store(tmp_path / "s.zarr", mode="a") as st:
        with pytest.raises(SchemaError, match="subject 'P1': variable " + pattern):
            st.write_subject(ds)
        assert len(st) == 0
        monkeypatch.setattr(batch, "validate_subject", lambda ds, name=None: "maps")  # a store written without checks
        st.write_subject(ds)
        monkeypatch.undo()
        report = st.validate()
        assert not report.ok and "subject 'P1': variable " in report.problems[0] and name in report.problems[0]
        with pytest.raises(SchemaError, match=name):
            st.subject("P1")


@pytest.mark.parametrize("col, name", [(0, "m"), (1, "rho_s")])
def test_merl_import_refuses_impossible_values(tmp_path, col, name):
    d = merl_dict()
    d["ts"][4, col] = 1e300
    scipy.io.savemat(tmp_path / "ts.mat", d)
    with pytest.raises(FormatError, match=f"ts row 5: {name} \\(column {col}\\) must be <= .*got 1e\\+300"):
        read_merl(tmp_path / "ts.mat")


def test_every_error_is_a_facestats_error():
    for exc in (ValidationError, SchemaError, StoreError, FormatError):
        assert issubclass(exc, FacestatsError)


@contextlib.contextmanager
def _within(seconds):
    """Fail (instead of hanging the suite) if the block runs longer than ``seconds`` (e.g. blocked on a FIFO)."""

    def hung(signum, frame):
        raise AssertionError(f"blocked for more than {seconds} s")

    previous = signal.signal(signal.SIGALRM, hung)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def test_transfer_colour_names_empty_inputs_and_checks_bins_first():
    from facestats.edit import transfer_colour

    target = np.random.default_rng(0).uniform(0.2, 0.7, (16, 16, 3))
    for empty in ((0, 0, 3), (0, 16, 3), (16, 0, 3)):
        got = re.escape(f"must hold at least one pixel, got shape {empty}")
        with pytest.raises(ValidationError, match="^source_albedo " + got):
            transfer_colour(np.zeros(empty), target)
    for empty in ((0, 0, 3), (0, 3), (4, 0, 3)):
        with pytest.raises(
            ValidationError, match="^target " + re.escape(f"must hold at least 2 pixels, got shape {empty}")
        ):
            transfer_colour(target, np.zeros(empty))
    with pytest.raises(ValidationError, match=re.escape("target must hold at least 2 pixels, got 1 (shape (1, 3))")):
        transfer_colour(target, np.full((1, 3), 0.5))
    with pytest.raises(ValidationError, match="target must hold at least 2 pixels inside target_mask, got 0"):
        transfer_colour(target, target, target_mask=np.zeros((16, 16), bool))
    with pytest.raises(ValidationError, match=re.escape("target must have shape (..., 3), got shape (16, 16, 2)")):
        transfer_colour(target, target[..., :2])
    with pytest.raises(ValidationError, match=re.escape("bins must be an integer in [2, 65536], got 1000000000000")):
        transfer_colour(target, target, bins=10**12)  # checked before the histograms are allocated
    for bad in (0, 2.5, "abc"):
        with pytest.raises(ValidationError, match="bins must be an integer"):
            transfer_colour(target, target, bins=bad)


def test_dome_load_refuses_what_is_not_a_regular_file(tmp_path):
    from facestats.acquire.dome import Dome, default_dome

    (tmp_path / "dir.json").mkdir()
    (tmp_path / "list.json").write_text("[1, 2]")
    (tmp_path / "broken.json").write_text("{")
    (tmp_path / "empty.json").write_text("{}")
    cases = {
        tmp_path / "dir.json": "is a directory",
        tmp_path / "list.json": "must hold a JSON object, got list",
        tmp_path / "broken.json": "not valid JSON",
        tmp_path / "empty.json": "missing the key 'led_position_mm'",
        tmp_path / "missing.json": "No such file",
    }
    if hasattr(os, "mkfifo"):
        os.mkfifo(tmp_path / "fifo.json")
        cases[tmp_path / "fifo.json"] = "not a regular file"
    if os.path.exists("/dev/null"):
        cases["/dev/null"] = "not a regular file"  # a character device
    for path, words in cases.items():
        with _within(20), pytest.raises(FormatError) as info:
            Dome.load(path)
        assert str(path) in str(info.value) and words in str(info.value), str(info.value)
    for bad in (None, 3, ""):
        with pytest.raises(ValidationError, match="calibration must be the path"):
            Dome.load(bad)
    default_dome().save(tmp_path / "dome.json")
    assert Dome.load(tmp_path / "dome.json").n_leds == 150


def test_generate_neutral_map_checks_everything_before_work(tmp_path, monkeypatch):
    from facestats.io.displacement import read_displacement
    from facestats.pipeline import microstructure as pm

    def generated(*args, **kwargs):
        raise AssertionError("the map was generated before the arguments were checked")

    monkeypatch.setattr(pm, "procedural_microstructure", generated)
    (tmp_path / "dir.exr").mkdir()
    cases = [
        ({"out": "/dev/null/x.exr"}, "out must be a path that can be created, got '/dev/null/x.exr'"),
        ({"out": tmp_path / "x.png"}, "out must end in one of ['.exr']"),
        ({"out": tmp_path / "dir.exr"}, "out must be a file, got"),
        ({"out": ""}, "out must be a file system path, got ''"),
        ({"size": 0}, "size must be an integer in [2, 16384], got 0"),
        ({"size": 1}, "size must be an integer in [2, 16384], got 1"),
        ({"size": 10**6}, "size must be an integer in [2, 16384], got 1000000"),
        ({"size": 2.5}, "size must be an integer"),
        ({"texel_um": 0}, "texel_um must lie in (0, 1000] um, got 0"),
        ({"texel_um": float("nan")}, "texel_um must be finite"),
        ({"seed": -1}, "seed must be an integer in [0, inf], got -1"),
        ({"seed": "abc"}, "seed must be an integer"),
    ]
    for change, message in cases:
        kwargs = {"out": tmp_path / "n.exr", "size": 16, **change}
        with pytest.raises(ValidationError, match=re.escape(message)):
            pm.generate_neutral_map(kwargs.pop("out"), kwargs.pop("size"), **kwargs)
    assert os.listdir(tmp_path) == ["dir.exr"]
    monkeypatch.undo()
    path = pm.generate_neutral_map(tmp_path / "new" / "n.exr", 16, seed=3)  # missing folders are created
    assert path == str(tmp_path / "new" / "n.exr") and os.listdir(tmp_path / "new") == ["n.exr"]  # no temporary
    assert read_displacement(path).shape == (16, 16)


def test_the_emulators_check_their_arguments_before_creating_anything(tmp_path, monkeypatch):
    from facestats.acquire.devices import lab
    from facestats.acquire.devices.emulator import Faults

    def drawn(*args, **kwargs):
        raise AssertionError("the subject was drawn before the arguments were checked")

    monkeypatch.setattr(lab, "subject_truth", drawn)
    (tmp_path / "file").write_text("not a folder")
    hot, lab_dir = tmp_path / "new" / "hot", tmp_path / "new" / "lab"
    dome_cases = [
        ({"map_size": 0}, "map_size must be an integer in [8, inf], got 0"),
        ({"seed": -1}, "seed must be an integer in [0, inf], got -1"),
        ({"workers": 0}, "workers must be an integer in [1, inf], got 0"),
        ({"wired_leds": 0}, "wired_leds must be an integer in [1, inf], got 0"),
        ({"leds": 0}, "leds must be an integer in [1, 150], got 0"),
        ({"resolution": 4}, "resolution must be an integer in [8, 8192], got 4"),
        ({"link": tmp_path / "file"}, "link must be absent or a symlink"),
        ({"faults": "none"}, "faults must be a Faults, got str"),
        ({"cache": tmp_path / "file"}, "cache must be a directory"),
    ]
    for kwargs, message in dome_cases:
        with pytest.raises(ValidationError, match=re.escape(message)):
            lab.emulated_dome("S001", hot, lab_dir, **kwargs)
    for kwargs, message in dome_cases[:2]:
        with pytest.raises(ValidationError, match=re.escape(message)):
            lab.emulated_sensor("S001", hot, lab_dir, **kwargs)
    with pytest.raises(ValidationError, match="hot_folder must be a directory"):
        lab.emulated_dome("S001", tmp_path / "file", lab_dir)
    with pytest.raises(ValidationError, match="lab must be a path that can be created"):
        lab.emulated_sensor("S001", hot, tmp_path / "file" / "lab")
    with pytest.raises(ValidationError, match=re.escape("seed must be an integer in [0, inf], got -1")):
        Faults(seed=-1)
    assert os.listdir(tmp_path) == ["file"]


def test_an_emulator_that_fails_to_start_removes_the_folders_it_created(tmp_path, monkeypatch):
    from facestats.acquire.devices import lab

    class Broken:
        def __init__(self, *args, **kwargs):
            raise FacestatsError("the scene cannot be built")

        @classmethod
        def of(cls, *args, **kwargs):
            return cls()

    monkeypatch.setattr(lab, "subject_truth", lambda *args, **kwargs: None)
    monkeypatch.setattr(lab, "DomeScene", Broken)
    monkeypatch.setattr(lab, "SensorScene", Broken)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))  # where hot_folder=None goes
    (tmp_path / "tmp").mkdir()
    (tmp_path / "kept").mkdir()
    for start in (lab.emulated_dome, lab.emulated_sensor):
        for hot in (tmp_path / "new" / "hot", None):
            with pytest.raises(FacestatsError, match="the scene cannot be built"):
                start("S001", hot, tmp_path / "kept" / "lab")
            assert sorted(os.listdir(tmp_path)) == ["kept", "tmp"], os.listdir(tmp_path)
            assert os.listdir(tmp_path / "kept") == [] and os.listdir(tmp_path / "tmp") == []


def test_sizes_that_would_exhaust_memory_are_refused_by_name():
    """A kernel of 6e12 taps and a width giving 1.6e11 levels are refused before anything is allocated."""
    from facestats.model.fitting.quantised import MAX_LEVELS, uniform_levels
    from facestats.model.fitting.scattering_image import fit_scattering_image
    from facestats.model.microstructure import kernel_taps
    from facestats.model.microstructure.kernel import MAX_RADIUS

    with pytest.raises(ValidationError, match=r"sigma_px=1e\+12 texels needs a kernel of 6000000000001 taps"):
        kernel_taps(0.5, 1e12, 1.0)
    assert kernel_taps(0.5, MAX_RADIUS / 3.0, 1.0).size == 2 * MAX_RADIUS + 1  # the largest allowed
    p = np.random.default_rng(0).random((40, 3)) * 100
    with pytest.raises(ValidationError, match=r"width must be at least .* mm, got 1e-09 mm: it gives .* levels"):
        # Half the patches lit: not a scene under uniform light, which is refused first (even_light).
        fit_scattering_image(p, np.ones(40), np.arange(40) % 2, np.ones(40), width=1e-9)
    assert uniform_levels(1.0, MAX_LEVELS - 2).size == MAX_LEVELS
    from facestats.acquire.patches import MAX_PATCHES, mesh_patches

    tri = np.array([[0.0, 0, 0], [50, 0, 0], [0, 50, 0]]), np.array([[0, 1, 2]])
    with pytest.raises(ValidationError, match=r"spacing must be at least 0.0707 mm, got 1e-09 mm: it gives 5e\+21"):
        mesh_patches(*tri, spacing=1e-9)  # was a raw out-of-memory error (373 GiB)
    assert len(mesh_patches(*tri, spacing=0.0708)) <= MAX_PATCHES


def test_microstructure_slopes_refuse_mismatched_shapes():
    from facestats.model.microstructure.surface import normal_histogram, tangent_normals

    with pytest.raises(ValidationError, match=r"jacobian must have shape \(2, 2\) or \(4, 5, 2, 2\)"):
        tangent_normals(np.zeros((4, 5)), np.zeros((3, 5, 2, 2)))
    with pytest.raises(ValidationError, match="gx and gy must be non-empty slopes of one shape"):
        normal_histogram(np.zeros(5), np.zeros(4), extent=0.5)
    with pytest.raises(ValidationError, match="gx and gy must be non-empty"):
        normal_histogram(np.zeros(0), np.zeros(0), extent=0.5)


def test_make_field_refuses_empty_images_and_non_unit_views():
    from facestats.relight.field import make_field

    d = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    with pytest.raises(
        ValidationError, match=r"values must hold at least one light and one pixel, got shape \(2, 0, 3, 3\)"
    ):
        make_field(np.zeros((2, 0, 3, 3)), d)
    view = np.zeros((2, 3, 3), np.float32)
    view[0, 0] = (0, 0, 2)
    with pytest.raises(ValidationError, match="view must hold unit vectors .*or 0 where there is no surface.*norm 2"):
        make_field(np.zeros((2, 2, 3, 3)), d, view=view)
    view[0, 0] = (0, 0, 1)  # unit vectors on the face, 0 off it
    assert make_field(np.zeros((2, 2, 3, 3)), d, view=view, normal=view)["view"].shape == (2, 3, 3)
