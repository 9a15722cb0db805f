"""The texture sample: six 512² subjects built once into the cache, on which the paper's 7-level transfer runs."""

import json
import os
import pathlib

import numpy as np
import pytest
from scipy import ndimage

import facestats
from facestats.acquire.synthetic.population import synthesize_population
from facestats.edit import transfer_texture_subject
from facestats.errors import StoreError, ValidationError
from facestats.pipeline import texture_sample as ts


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FACESTATS_CACHE_DIR", str(folder))
        (folder / "texture-sample-0123456789abcdef.zip").write_bytes(b"made by other code")
        yield folder, ts.texture_sample(quiet=True)


def _fine_structure(ds):
    """Std of the grey albedo minus its Gaussian blur (σ = 2 texels) inside the face: pores, freckles."""
    grey = ds["albedo"].values.mean(axis=-1)
    inner = ndimage.binary_erosion(ds["region"].values > 0, iterations=4)
    return float((grey - ndimage.gaussian_filter(grey, 2))[inner].std())


@pytest.mark.slow  # builds the 512² sample (8 s)
def test_one_subject_per_skin_type_at_512_with_the_population_s_draws(cache):
    _, path = cache
    with facestats.open_store(path) as store:
        assert sorted(store.ids()) == sorted(ts.TEXTURE_SAMPLE_SUBJECTS)
        subjects = {sid: store.subject(sid) for sid in store.ids()}
    assert sorted(ds.attrs["skin_type"] for ds in subjects.values()) == [1, 2, 3, 4, 5, 6]
    # The same draws as the population at any size: ids, metadata and features agree with the 48² population.
    small = synthesize_population(map_size=48, conditions=False, subjects=list(ts.TEXTURE_SAMPLE_SUBJECTS))
    features = {}
    for sid, ds in subjects.items():
        assert ds["albedo"].shape == (512, 512, 3) and ds["region"].shape == (512, 512)
        truth = small[sid]
        assert {k: ds.attrs[k] for k in truth.metadata()} == truth.metadata()
        prov = json.loads(ds.attrs["provenance"])
        assert prov["source"].endswith("(ground truth, not fitted)") and prov["map_size"] == 512
        assert prov["features"]["freckles"] == truth.features["freckles"]
        assert prov["features"]["moles"] == truth.features["moles"]
        features[sid] = prov["features"]
        np.testing.assert_allclose(ds["albedo_avg"].values, ds["albedo"].values[ds["region"].values > 0].mean(0), 1e-5)
    assert sum(f["freckles"] for f in features.values()) == 3 and sum(f["moles"] > 0 for f in features.values()) == 5
    # Freckles are fine structure: every freckled subject holds more of it than any unfreckled one.
    fine = {sid: _fine_structure(ds) for sid, ds in subjects.items()}
    freckled = [fine[s] for s in fine if features[s]["freckles"]]
    plain = [fine[s] for s in fine if not features[s]["freckles"]]
    assert min(freckled) > 2 * max(plain) and min(plain) > 0


@pytest.mark.slow  # builds the 512² sample (8 s)
def test_sample_subjects_export_on_the_head_they_were_drawn_on(cache, tmp_path):
    """The provenance names the procedural head, so export rebuilds its mesh without --mesh."""
    from facestats.io.gltf import read_gltf_summary
    from facestats.io.mesh import subject_mesh
    from facestats.io.subject_export import export_subject

    _, path = cache
    with facestats.open_store(path) as store:
        ds = store.subject("S001")
    mesh = subject_mesh(ds)
    assert mesh.geometry["name"] == f"procedural-{ts.TEXTURE_SAMPLE_SIZE}" and mesh.geometry["kind"] == "procedural"
    out = export_subject(ds, tmp_path / "gltf", "gltf")
    summary = read_gltf_summary(tmp_path / "gltf" / next(f for f in out["files"] if f.endswith((".gltf", ".glb"))))
    assert summary["n_vertices"] == len(mesh.vertices)


@pytest.mark.slow  # builds the 512² sample (8 s)
def test_built_once_keyed_by_the_sources_and_old_samples_removed(cache):
    folder, path = cache
    assert (
        path.parent == folder and path.name == f"texture-sample-{facestats.core.version.source_fingerprint()[:16]}.zip"
    )
    assert [p.name for p in folder.glob("texture-sample-*.zip")] == [path.name]  # the other code's copy is gone
    stamp = path.stat().st_mtime_ns
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FACESTATS_CACHE_DIR", str(folder))
        assert ts.texture_sample() == path and path.stat().st_mtime_ns == stamp  # reused, not rebuilt
    assert not [p for p in folder.iterdir() if p.name.startswith(".texture-sample-")]  # no temporary left


def test_the_same_code_writes_the_same_subjects_bit_for_bit(tmp_path):
    paths = [ts.build_texture_sample(tmp_path / f"{n}.zip", size=32, subjects=("S030", "S015")) for n in "ab"]
    with facestats.open_store(paths[0]) as a, facestats.open_store(paths[1]) as b:
        assert a.ids() == b.ids() == ["S015", "S030"]
        for sid in a.ids():
            x, y = a.subject(sid), b.subject(sid)
            assert x.attrs == y.attrs and set(x.data_vars) == set(y.data_vars)
            for var in x.data_vars:
                np.testing.assert_array_equal(x[var].values, y[var].values, err_msg=f"{sid} {var}")


def test_an_unwritable_cache_is_a_clear_error(tmp_path, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    monkeypatch.setenv("FACESTATS_CACHE_DIR", str(blocker / "cache"))
    with pytest.raises(StoreError, match="cannot write the texture sample to .*set FACESTATS_CACHE_DIR"):
        ts.texture_sample(quiet=True)
    assert blocker.read_text() == "not a directory"


def test_cache_dir_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv("FACESTATS_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert ts.cache_dir() == tmp_path / "facestats"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert ts.cache_dir() == pathlib.Path(os.path.expanduser("~/.cache/facestats"))


@pytest.mark.slow  # builds the 512² sample (8 s)
def test_seven_level_transfer_runs_on_the_sample_and_carries_the_freckles(cache, tmp_path):
    _, path = cache
    with (
        facestats.open_store() as default,
        pytest.raises(ValidationError, match=r"levels must be at most 3 for a map of shape \(48, 48\).*512"),
    ):
        transfer_texture_subject(
            default, "S001", "S030", levels=7, out_store=facestats.open_store(tmp_path / "x.zarr", "a")
        )
    with facestats.open_store(path) as sample, facestats.open_store(tmp_path / "out.zarr", mode="a") as out:
        edit = transfer_texture_subject(sample, "S001", "S030", levels=7, seed=1, out_store=out)
        assert edit.edit["parameters"]["levels"] == 7
        before, target = _fine_structure(sample.subject("S001")), _fine_structure(sample.subject("S030"))
        after = _fine_structure(out.subject(edit.subject_id))
    assert edit.texture.distance[-1] < 0.8 * edit.texture.distance[0]
    assert after > 3 * before and abs(after - target) < 0.25 * target  # S030's freckles, on S001
