"""``Store.validate`` (and repair's checks) on maps of many bands: one band of a large map in memory at a time,
with the checks and messages of a full read (facestats.io.integrity.open_generation(..., banded=True))."""

import json
import re
import tracemalloc

import numpy as np
import pytest

from facestats.errors import SchemaError
from facestats.io import open_store
from facestats.io import store as store_mod
from tests.helpers import make_map_subject, with_micro_normals


def _subject(sid="B1", rows=150, width=None, cameras=2, seed=6):
    """A map subject of ``rows`` rows of v (bands of 64: the last one partial) with micro-normals; ``width``
    columns of u from the middle (a crop keeps its texels' positions), default all."""
    ds = make_map_subject(sid, size=rows, seed=seed)
    if width is not None:
        ds = ds.isel(u=slice(rows // 2 - width // 2, rows // 2 + width // 2))
    return with_micro_normals(ds, cameras=cameras, seed=seed)


def _write(path, ds, monkeypatch=None):
    """Write ``ds`` into a new store at ``path``; with ``monkeypatch``, without the write's schema check (a store
    written by a faulty writer); returns the generation folder."""
    with open_store(path, mode="a") as st:
        if monkeypatch is not None:
            monkeypatch.setattr("facestats.io.batch.validate_subject", lambda ds, **kw: "maps")
        st.write_subject(ds)
        if monkeypatch is not None:
            monkeypatch.undo()
    return next((path / "subjects" / ds.attrs["subject_id"]).glob("g*"))


def _problems(path):
    with open_store(path) as st:
        return st.validate().problems


def _full_read_error(path, sid="B1"):
    """The message of a full read of ``sid`` (every variable loaded at once, then checked)."""
    with open_store(path) as st, pytest.raises(SchemaError) as err:
        st.subject(sid)
    return str(err.value)


def test_validate_holds_bands_of_a_large_map_not_the_subject(tmp_path):
    """1024 rows of v (16 bands) and 16 micro-normal cameras: 29 MiB of subject, 24 MiB of micro-normals, 1.5 MiB a band
    of them.  Loading every variable first (before 2026-12-07) traced a 38 MiB peak, more than the subject; reading
    large maps band by band, 6.9 MiB (the band as read, its face texels, the domain test's blocks, and the index row's
    per-region samples).  The bound, a third of the subject, is five bands of the micro-normals."""
    ds = _subject(rows=1024, width=128, cameras=16, seed=1)
    subject = sum(v.nbytes for v in ds.variables.values())
    band = ds["micro_normal"].nbytes * 64 // 1024
    _write(tmp_path / "s.zarr", ds)
    del ds
    with open_store(tmp_path / "s.zarr") as st:
        assert st.validate().problems == []  # the modules a validation imports, imported
        tracemalloc.start()
        try:
            report = st.validate()
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
    assert report.problems == [] and report.n_checked == 1
    assert subject > 28 * 2**20 and band == 1.5 * 2**20
    assert peak < subject / 3, (peak, subject)


def test_banded_variables_are_the_maps_of_more_than_one_band_but_the_region(tmp_path):
    """A map of one band (the default store's 48²) is loaded as in a full read; the face mask is loaded whole."""
    import xarray as xr

    from facestats.io.integrity import banded_variables

    banded = {}
    for sid, rows in (("B1", 65), ("B2", 64)):
        gen = _write(tmp_path / f"{sid}.zarr", _subject(sid, rows=rows))
        ds = xr.open_zarr(gen, consolidated=False, zarr_format=3, chunks=None)
        manifest = json.loads(ds.attrs[store_mod.STORE_ATTR])["manifest"]
        banded[sid] = banded_variables(ds, manifest)
    maps = {n for n, v in ds.data_vars.items() if "v" in v.dims} - {"region"}
    assert set(banded["B1"]) == maps and "micro_normal" in maps and len(maps) == 10
    assert banded["B2"] == []


def test_a_damaged_band_of_a_map_is_caught_with_the_message_of_a_full_read(tmp_path):
    """A chunk file removed from the last band of one camera (it would read as fill values)."""
    gen = _write(tmp_path / "s.zarr", _subject())
    (gen / "micro_normal" / "c" / "1" / "2" / "0" / "0").unlink()  # camera 1, rows 128..149
    want = _full_read_error(tmp_path / "s.zarr")
    assert "'micro_normal' does not match its checksum (a chunk file is missing" in want
    assert _problems(tmp_path / "s.zarr") == [want]


def test_an_undecodable_band_is_damage_with_the_message_of_a_full_read(tmp_path):
    gen = _write(tmp_path / "s.zarr", _subject())
    (gen / "ts_m" / "c" / "1" / "0").write_bytes(b"not a blosc frame")  # the middle band of ts_m
    want = _full_read_error(tmp_path / "s.zarr")
    assert "'ts_m' cannot be read (truncated or corrupt chunk)" in want
    assert _problems(tmp_path / "s.zarr") == [want]


def test_a_damaged_chunk_checksum_of_a_banded_map_names_the_band(tmp_path):
    """The bytes match the variable's checksum, one band's checksum in the manifest does not: a damaged manifest,
    named by band and rows as when the variable was loaded whole (banded=False)."""
    gen = _write(tmp_path / "s.zarr", _subject())
    meta_path = gen / "zarr.json"
    meta = json.loads(meta_path.read_text())
    attr = json.loads(meta["attributes"][store_mod.STORE_ATTR])
    crcs = attr["manifest"]["micro_normal"]["chunk_crc32"]
    crcs[2] = (crcs[2] + 1) % 2**32
    meta["attributes"][store_mod.STORE_ATTR] = json.dumps(attr)
    meta_path.write_text(json.dumps(meta))
    assert _problems(tmp_path / "s.zarr") == [
        "subject 'B1': variable 'micro_normal': chunk_crc32[2] of its manifest (rows 128-149 of v) does not match the "
        "data, which match the variable's checksum: the manifest is damaged"
    ]
    with open_store(tmp_path / "s.zarr") as st:
        plan = st.plan_repair()
    assert ("quarantine-generation", gen.name) in [(a.kind, a.source) for a in plan.actions]


@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")  # the faulty write's summary of inf
@pytest.mark.parametrize(
    "name, index, value, words",
    [
        (
            "micro_normal",
            (1, 140, 75, 2),
            1.5,
            r"'micro_normal' must lie in \[-1, 1\] or be NaN \(missing\), got 1.5 \(1",
        ),
        ("albedo", (140, 75, 0), np.inf, r"'albedo' has 1 non-finite face texel\(s\)"),
        ("ts_m", (100, 75), 0.0, r"'ts_m' must lie in \(0, 10\], got 0.0 \(1 value"),
    ],
)
def test_values_outside_their_domain_in_a_late_band_are_caught_as_by_a_full_read(
    tmp_path, monkeypatch, name, index, value, words
):
    ds = _subject()
    assert ds["region"].values[index[-3] if name == "micro_normal" else index[0], 75] > 0  # a face texel
    bad = ds[name].values.copy()
    bad[index] = value
    _write(tmp_path / "s.zarr", ds.assign({name: (ds[name].dims, bad)}), monkeypatch)
    want = _full_read_error(tmp_path / "s.zarr")
    assert _problems(tmp_path / "s.zarr") == [want]
    assert re.search(words, want), want


def test_a_stale_index_entry_of_a_banded_subject_is_reported_and_its_recomputed_row_is_the_writes(tmp_path):
    """The index row and histograms are recomputed from maps left on disk, as the write computed them from memory."""
    path = tmp_path / "s.zarr"
    _write(path, _subject())
    doc = json.loads((path / "index.json").read_text())
    written = doc["subjects"]["B1"]
    hist = np.asarray(written["albedo_hist"])
    k = int(np.argmax(hist[0]))
    hist[0, k], hist[0, k - 1] = hist[0, k] - 1, hist[0, k - 1] + 1  # one texel moved to the bin below
    doc["subjects"]["B1"] = {**written, "albedo_hist": hist.tolist()}
    (path / "index.json").write_text(json.dumps(doc))
    assert _problems(path) == ["subject 'B1': index albedo histogram disagrees with the data"]
    with open_store(path) as st:
        plan = st.plan_repair()
    (action,) = plan.actions
    assert action.entry["row"] == written["row"] and action.entry["albedo_hist"] == written["albedo_hist"]


def test_a_subject_replaced_between_its_checksums_and_its_schema_check_is_checked_in_its_new_version(
    tmp_path, monkeypatch
):
    """A writer replaces the subject (and removes the old generation) after validate read the checksums of its maps,
    before the schema reads them again: the new version is checked, no problem reported (the reads of the old one
    fail as "replaced", a StoreError, which validate looks up again as it does a damaged read)."""
    from facestats.io import integrity

    path = tmp_path / "s.zarr"
    first = _write(path, _subject(seed=6))
    check = integrity.validate_subject
    replaced = []

    def replace_then_check(ds, **kw):
        if not replaced:
            with open_store(path, mode="r+") as writer:
                writer.write_subject(_subject(seed=7), overwrite=True)
            replaced.append(True)
        return check(ds, **kw)

    monkeypatch.setattr(integrity, "validate_subject", replace_then_check)
    with open_store(path) as st:
        report = st.validate()
        assert report.problems == [] and report.n_checked == 1 and replaced
        assert st.index_entries()["B1"]["generation"] != first.name and not first.exists()


def test_validate_reads_each_chunk_of_the_subject_once(tmp_path, monkeypatch):
    """Every chunk file is read from the store once by ``validate``: the checksums, the chunk checksums, the schema's
    checks and the recomputed index row of a map of many bands all come from that one read (the schema's finite and
    domain checks and the index row read ``ts_m`` again before 2026-12-08: each of its chunks four times)."""
    import collections

    from zarr.storage import LocalStore

    _write(tmp_path / "s.zarr", _subject())
    reads = collections.Counter()
    get = LocalStore.get

    async def counted(self, key, *args, **kwargs):
        reads[key] += 1
        return await get(self, key, *args, **kwargs)

    monkeypatch.setattr(LocalStore, "get", counted)
    assert _problems(tmp_path / "s.zarr") == []
    chunks = {key: n for key, n in reads.items() if "/c/" in key}
    for name, bands in (("ts_m", 3), ("albedo", 3), ("micro_normal", 6)):  # 150 rows: bands of 64, 64, 22
        assert len([key for key in chunks if key.startswith(f"{name}/c/")]) == bands, name
    assert chunks and set(chunks.values()) == {1}, {k: n for k, n in chunks.items() if n != 1}


def test_damaged_bands_of_two_maps_are_reported_in_the_order_of_a_full_read(tmp_path):
    """The maps the index row reads are read after the others (their face texels are not held meanwhile), yet with
    ``micro_normal`` and ``ts_m`` both damaged the message is the full read's, which reaches ``ts_m`` first."""
    gen = _write(tmp_path / "s.zarr", _subject())
    meta = json.loads((gen / "zarr.json").read_text())
    order = list(json.loads(meta["attributes"][store_mod.STORE_ATTR])["manifest"])
    assert order.index("ts_m") < order.index("micro_normal")
    (gen / "micro_normal" / "c" / "1" / "2" / "0" / "0").unlink()
    (gen / "ts_m" / "c" / "2" / "0").write_bytes(b"not a blosc frame")  # the last band of ts_m
    want = _full_read_error(tmp_path / "s.zarr")
    assert "'ts_m' cannot be read (truncated or corrupt chunk)" in want
    assert _problems(tmp_path / "s.zarr") == [want]
    (gen / "ts_m" / "c" / "2" / "0").unlink()  # now a checksum mismatch of ts_m (its last band reads as NaN)
    want = _full_read_error(tmp_path / "s.zarr")
    assert "'ts_m' does not match its checksum" in want
    assert _problems(tmp_path / "s.zarr") == [want]


def test_validate_does_not_hold_one_subjects_gathered_texels_while_checking_the_next(tmp_path):
    """The face texels gathered for a subject's index row (``GATHERED_TEXELS``) go with its Dataset: validating a
    store of two subjects peaks as one does.  The checking loop kept the previous subject's Dataset bound while it
    opened the next (before 2026-12-08): the second peaked higher by the first one's gathered texels."""
    from facestats.io.summary import SUMMARY_MAPS

    subjects = [make_map_subject(f"S{i}", size=384, seed=i) for i in range(2)]
    face = int((subjects[0]["region"] > 0).sum())
    gathered = sum(face * v.nbytes // v["v"].size // v["u"].size for n, v in subjects[0].items() if n in SUMMARY_MAPS)
    peaks = []
    for n in (1, 2):
        path = tmp_path / f"{n}.zarr"
        with open_store(path, mode="a") as st:
            for ds in subjects[:n]:
                st.write_subject(ds)
        with open_store(path) as st:
            assert st.validate().problems == []  # the modules a validation imports, imported
            tracemalloc.start()
            try:
                report = st.validate()
                peaks.append(tracemalloc.get_traced_memory()[1])
            finally:
                tracemalloc.stop()
        assert report.problems == [] and report.n_checked == n
    assert gathered > 2**20
    assert peaks[1] < peaks[0] + gathered / 4, (peaks, gathered)
