"""Store-level appearance edits (Weyrich et al. 2006 §8): new subjects with provenance, never the source."""

import numpy as np
import pytest
import xarray as xr

import facestats
from facestats.core.published import ETA_SKIN
from facestats.edit import (
    PendingEdit,
    SubjectEdit,
    TextureStatistics,
    change_skin_type,
    select_subjects,
    subject_texture_statistics,
    transfer_brdf_subject,
    transfer_colour_subject,
    transfer_texture_subject,
)
from facestats.edit.plots import plot_subject_edit, save_edit_images
from facestats.edit.subjects import EDIT_SOURCE
from facestats.errors import StoreError, ValidationError
from facestats.io import open_store
from facestats.io.schema import provenance, set_provenance
from facestats.model import dipole
from tests.helpers import make_map_subject, make_sample_subject, with_micro_normals

SIZE = 24
# (id, skin type, condition, seed, rho_shift, person)
POP = [
    ("A2", 2, "normal", 1, 0.0, None),
    ("V1", 5, "normal", 2, 0.06, None),
    ("V2", 5, "normal", 3, 0.07, None),
    ("V5", 5, "lotion", 6, 0.20, None),  # type V but not "normal": not in the default subset
    ("N1", 3, "normal", 7, 0.0, "N1"),
    ("N1-lotion", 3, "lotion", 8, 0.10, "N1"),
]
SUBSET_V = ["V1", "V2"]


def _subjects():
    out = {}
    for sid, st, cond, seed, shift, person in POP:
        out[sid] = make_map_subject(
            sid, size=SIZE, skin_type=st, condition=cond, seed=seed, rho_shift=shift, person_id=person
        )
    # An earlier edit of type V with wild values: subsets must never include it.
    e = make_map_subject("E1", size=SIZE, skin_type=5, seed=9, rho_shift=0.5)
    e["albedo"] = e["albedo"] * 0.2
    set_provenance(e, source=EDIT_SOURCE)
    out["E1"] = e
    out["M1"] = make_sample_subject("M1", skin_type=1)
    return out


@pytest.fixture(scope="module")
def pop(tmp_path_factory):
    path = tmp_path_factory.mktemp("edit") / "pop.zarr"
    subjects = _subjects()
    with open_store(path, mode="a") as st:
        st.write_subjects(list(subjects.values()))
    return path, subjects


@pytest.fixture(scope="module")
def skin_v(pop):
    """The source before the edit and the type II -> V edit of A2 (t = 1), made once."""
    with open_store(pop[0], mode="r+") as st:
        before = st.subject("A2")
        generation = st.index_entries()["A2"]["generation"]
        return before, generation, change_skin_type(st, "A2", "V")


@pytest.fixture
def store(pop):
    st = open_store(pop[0], mode="r+")
    yield st
    st.close()


def _face(ds):
    return ds["region"].values > 0


def _pooled(subjects, ids, var, region=None):
    """Independent pooled samples: unflagged texels of the subjects' maps (all regions or one)."""
    parts = []
    for sid in ids:
        ds = subjects[sid]
        reg = ds["region"].values
        sel = (reg > 0) if region is None else (reg == region)
        if var != "albedo":
            flag = ds[("ts" if var.startswith("ts") else "bp") + "_flag"].values
            sel &= flag == 0
        parts.append(ds[var].values[sel])
    return np.concatenate(parts).astype(np.float64)


def test_select_subjects_excludes_edits_and_the_source(store):
    assert select_subjects(store, {"skin_type": 5}) == SUBSET_V  # not E1 (an edit) nor V5 (lotion)
    q = store.query(skin_type=5, condition="normal")
    assert "E1" not in q.subject_ids and q.n_edits_left_out == 1  # nor does the query, unless asked
    assert "E1" in store.query(skin_type=5, condition="normal", edits=True).subject_ids
    assert "left out: 1 edited subject(s)" in q.to_table()
    assert select_subjects(store, {"skin_type": "II"}) == ["A2", "M1"]  # I and II grouped; sample subjects count
    assert select_subjects(store, {"skin_type": "V"}, exclude=["V2"]) == ["V1"]
    assert select_subjects(store, {"skin_type": 5, "condition": None}) == ["V1", "V2", "V5"]
    assert select_subjects(store, {"skin_type": 5, "condition": " Any"}) == ["V1", "V2", "V5"]  # as query's 'any'
    assert select_subjects(store, {"condition": "lotion"}) == ["N1-lotion", "V5"]
    with pytest.raises(ValidationError, match="target query keys must be among"):
        select_subjects(store, {"skin": 5})


def test_change_skin_type_moves_albedo_and_brdf_to_the_subset(store, pop, skin_v):
    _, subjects = pop
    src = subjects["A2"]
    before_src, generation, e = skin_v
    assert isinstance(e, SubjectEdit) and e.subject_id.startswith("A2.skin-V-") and e.subject_id in store
    assert list(e.targets) == SUBSET_V
    new = store.subject(e.subject_id)
    assert new.attrs["skin_type"] == 5 and new.attrs["condition"] == "normal" and new.attrs["person_id"] == "A2"

    # Provenance in the store.
    p = provenance(new)
    assert p["source"] == EDIT_SOURCE and p["source_subject"] == "A2" and p["source_store"] == store.label
    assert p["edit"]["name"] == "change_skin_type"
    assert p["edit"]["parameters"]["skin_type"] == 5 and p["edit"]["parameters"]["t"] == 1.0
    assert p["edit"]["target"]["subjects"] == SUBSET_V
    assert p["edit"]["target"]["query"] == {"skin_type": 5, "condition": "normal"}
    assert p["source_provenance"] == provenance(before_src)  # the stored source's, with its software_version
    assert store.subjects().loc[e.subject_id, "source"] == EDIT_SOURCE

    # The source is untouched, bit for bit, in the same generation.
    xr.testing.assert_identical(store.subject("A2"), before_src)
    assert store.index_entries()["A2"]["generation"] == generation

    face = _face(src)
    alb0, alb1 = src["albedo"].values[face].mean(0), new["albedo"].values[face].mean(0)
    target = _pooled(subjects, SUBSET_V, "albedo").reshape(-1, 3).mean(0)
    # The face's mean colour lands on the subset's (decorrelated marginals matched; the basis is linear).
    np.testing.assert_allclose(alb1, target, rtol=0.01)
    assert np.all(np.abs(alb1 - target) < 0.03 * np.abs(alb0 - target))
    np.testing.assert_array_equal(new["albedo"].values[~face], src["albedo"].values[~face])

    reg = src["region"].values
    for var in ("ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent"):
        for r in range(1, 11):
            sel = reg == r
            tgt = _pooled(subjects, SUBSET_V, var, r).mean()
            b, a = src[var].values[sel].mean(), new[var].values[sel].mean()
            # Quantiles of the pooled target at the region's rank levels: the mean is the target's.
            assert a == pytest.approx(tgt, rel=0.02), (var, r)
            assert e.target_means[var][r] == pytest.approx(tgt, rel=1e-12)
            if var == "ts_rho_s":
                assert abs(a - tgt) < 0.25 * abs(b - tgt), (var, r)  # rho_shift 0.06-0.08 vs 0
    table = e.region_means()
    row = table[(table.variable == "ts_rho_s") & (table.region == 7)].iloc[0]
    assert row["after"] == pytest.approx(new["ts_rho_s"].values[reg == 7].mean())
    assert row["target"] == pytest.approx(_pooled(subjects, SUBSET_V, "ts_rho_s", 7).mean())


def test_translucency_follows_the_new_albedo(store, pop):
    _, subjects = pop
    src = subjects["A2"]
    e = change_skin_type(store, "A2", 5, brdf=False, new_id="A2-typeV-colour")
    new = store.subject("A2-typeV-colour")
    face = _face(src)
    np.testing.assert_array_equal(new["sigma_tr"].values, src["sigma_tr"].values)  # σtr is kept
    avg = np.clip(new["albedo"].values[face].astype(np.float64), 1e-4, 1 - 1e-4).mean(0)
    np.testing.assert_allclose(new["albedo_avg"].values, avg, rtol=1e-6)
    assert np.all(new["albedo_avg"].values < 0.8 * src["albedo_avg"].values)  # type II -> V is darker
    sp, sa = new["sigma_s_prime"].values, new["sigma_a"].values
    # The dipole of (σ's, σa) reflects exactly the new average albedo (eq. 16) with the same σtr (eq. 15).
    np.testing.assert_allclose(dipole.total_diffuse_reflectance(sp, sa, 1.38), new["albedo_avg"].values, rtol=1e-8)
    np.testing.assert_allclose(np.sqrt(3 * sa * (sa + sp)), src["sigma_tr"].values, rtol=1e-10)
    assert np.all(sa > src["sigma_a"].values)  # darker skin absorbs more
    # BRDF untouched when brdf=False; sensor data copied.
    for var in ("ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent", "site_sigma_tr", "sensor_profile"):
        np.testing.assert_array_equal(new[var].values, src[var].values)
    assert set(e.variables) == {"albedo", "albedo_avg", "sigma_s_prime", "sigma_a"}


def test_translucency_from_the_face_texels_equals_that_of_the_whole_masked_map(pop):
    """follow_translucency averages the face texels alone (the whole map in float64 held ~400 MB beside a 2048²
    subject): the same values in the same order as the whole map masked by the face, so the same bits."""
    from facestats.edit.translucency import follow_translucency
    from facestats.model.fitting import scattering_parameters

    ds = pop[1]["V1"].copy()
    face = _face(ds)
    alb = np.clip(np.asarray(ds["albedo"].values, np.float64), 1e-4, 1 - 1e-4)
    want = scattering_parameters(np.where(face[..., None], alb, 0.0), face, ds["sigma_tr"].values, ETA_SKIN)[:3]
    assert follow_translucency(ds, keep=False) == ["albedo_avg", "sigma_s_prime", "sigma_a"]
    for name, value in zip(("albedo_avg", "sigma_s_prime", "sigma_a"), want):
        np.testing.assert_array_equal(ds[name].values, value, err_msg=name)


def test_keep_translucency(store, pop):
    src = pop[1]["A2"]
    change_skin_type(store, "A2", 5, brdf=False, keep_translucency=True, new_id="A2-typeV-keep")
    new = store.subject("A2-typeV-keep")
    for var in ("albedo_avg", "sigma_s_prime", "sigma_a", "sigma_tr"):
        np.testing.assert_array_equal(new[var].values, src[var].values)
    assert not np.array_equal(new["albedo"].values, src["albedo"].values)
    assert provenance(new)["edit"]["parameters"]["keep_translucency"] is True


def test_interpolation_half_way_and_determinism(store, pop, skin_v):
    src = pop[1]["A2"]
    full = skin_v[2].dataset
    half = change_skin_type(store, "A2", 5, t=0.5, new_id="A2-t05")
    again = change_skin_type(store, "A2", 5, t=0.5, new_id="A2-t05-again")
    for var in half.dataset.data_vars:  # no randomness: bit-identical
        np.testing.assert_array_equal(again.dataset[var].values, half.dataset[var].values)
    assert half.dataset.attrs["skin_type"] == 2  # only t = 1 relabels
    reg = src["region"].values
    for var in ("ts_rho_s", "bp_exponent"):
        x0, x1, xh = (np.asarray(d[var].values, np.float64) for d in (src, full, half.dataset))
        face = reg > 0
        # x' = (1 - t) x + t Q(u): per texel exactly half-way between the source and the t = 1 result.
        np.testing.assert_allclose(xh[face], 0.5 * (x0[face] + x1[face]), rtol=1e-6)
    a0, a1, ah = (d["albedo"].values[reg > 0].mean(0) for d in (src, full, half.dataset))
    np.testing.assert_allclose(ah, 0.5 * (a0 + a1), rtol=0.01)


def test_brdf_transfer_normal_to_lotion_half_way(store, pop):
    _, subjects = pop
    src = subjects["N1"]
    e = transfer_brdf_subject(store, "N1", {"condition": "lotion", "skin_type": 3}, t=0.5)
    assert e.subject_id.startswith("N1.brdf-") and list(e.targets) == ["N1-lotion"]
    new = store.subject(e.subject_id)
    p = provenance(new)["edit"]
    assert p["name"] == "transfer_brdf" and p["parameters"] == {"t": 0.5, "model": "both", "regions": None}
    assert p["target"]["query"] == {"condition": "lotion", "skin_type": 3}
    assert new.attrs["condition"] == "normal"  # t < 1: still the source's condition
    reg = src["region"].values
    for var in ("ts_rho_s", "ts_m"):
        for r in (2, 6, 7):
            sel = reg == r
            b, a = src[var].values[sel].mean(), new[var].values[sel].mean()
            tgt = _pooled(subjects, ["N1-lotion"], var, r).mean()
            assert a == pytest.approx(0.5 * (b + tgt), abs=0.05 * abs(tgt - b) + 1e-6), (var, r)
    for var in ("albedo", "albedo_avg", "sigma_a", "normal" if "normal" in new else "albedo"):
        np.testing.assert_array_equal(new[var].values, src[var].values)
    full = transfer_brdf_subject(store, "N1", {"condition": "lotion"}, t=1.0, model="ts")
    assert full.dataset.attrs["condition"] == "lotion"
    assert set(full.variables) == {"ts_rho_s", "ts_m"}
    np.testing.assert_array_equal(full.dataset["bp_rho_s"].values, src["bp_rho_s"].values)


def test_brdf_transfer_from_a_subject_in_some_regions(store, pop):
    _, subjects = pop
    src = subjects["A2"]
    e = transfer_brdf_subject(store, "A2", "V1", regions=[2, "cheeks"], model="ts", new_id="A2-brdf-V1")
    assert provenance(e.dataset)["edit"]["regions_edited"] == {"ts": [2, 7]}
    assert provenance(e.dataset)["edit"]["target"] == {"subject": "V1"}
    reg = src["region"].values
    inside = np.isin(reg, [2, 7])
    for var in ("ts_rho_s", "ts_m"):
        np.testing.assert_array_equal(e.dataset[var].values[~inside], src[var].values[~inside])
        for r in (2, 7):  # equal region sizes, one flagged texel outside: exactly V1's unflagged values
            np.testing.assert_allclose(
                np.sort(e.dataset[var].values[reg == r]), np.sort(_pooled(subjects, ["V1"], var, r)), rtol=1e-6
            )


def test_colour_transfer_within_a_region(store, pop):
    _, subjects = pop
    src = subjects["A2"]
    e = transfer_colour_subject(store, "A2", "V1", regions=["cheeks"], new_id="A2-colour-cheeks")
    reg = src["region"].values
    inside = reg == 7
    np.testing.assert_array_equal(e.dataset["albedo"].values[~inside], src["albedo"].values[~inside])
    target = subjects["V1"]["albedo"].values[subjects["V1"]["region"].values == 7].mean(0)
    np.testing.assert_allclose(e.dataset["albedo"].values[inside].mean(0), target, rtol=0.01)
    assert e.edit["target"]["n_albedo_samples"] == int(inside.sum())


def test_texture_transfer_in_regions_is_deterministic_and_leaves_the_outside(store, pop):
    src = pop[1]["A2"]
    kw = dict(regions=[2, 6, 7], iterations=2, seed=11)
    a = transfer_texture_subject(store, "A2", "V1", new_id="A2-tex-a", **kw)
    transfer_texture_subject(store, "A2", "V1", new_id="A2-tex-b", **kw)
    transfer_texture_subject(store, "A2", "V1", new_id="A2-tex-c", **{**kw, "seed": 12})
    sa, sb, sc = (store.subject(x)["albedo"].values for x in ("A2-tex-a", "A2-tex-b", "A2-tex-c"))
    np.testing.assert_array_equal(sa, sb)  # same seed, same subject bit for bit
    assert not np.array_equal(sa, sc)
    reg = src["region"].values
    outside = ~np.isin(reg, [2, 6, 7])
    np.testing.assert_array_equal(sa[outside], src["albedo"].values[outside])
    assert np.abs(sa[~outside] - src["albedo"].values[~outside]).max() > 1e-3
    p = provenance(store.subject("A2-tex-a"))["edit"]
    assert p["parameters"]["seed"] == 11 and p["parameters"]["regions"] == [2, 6, 7]
    assert p["parameters"]["levels"] == 2  # the most a 24 x 24 map supports
    assert a.texture.distance.shape == (3,) and p["final_distance"] == pytest.approx(a.texture.distance[-1])
    assert a.dataset["albedo_avg"].values == pytest.approx(np.clip(sa[reg > 0], 1e-4, 1 - 1e-4).mean(0), rel=1e-6)


def test_texture_from_saved_statistics(store, pop, tmp_path):
    stats = subject_texture_statistics(store, "V1", regions=["cheeks"])
    assert isinstance(stats, TextureStatistics) and stats.levels == 2
    path = stats.save(tmp_path / "v1_cheeks")
    e1 = transfer_texture_subject(store, "A2", str(path), regions=[7], seed=1, iterations=1, new_id="A2-tex-file")
    e3 = transfer_texture_subject(store, "A2", stats, regions=[7], seed=1, iterations=1, new_id="A2-tex-obj")
    np.testing.assert_array_equal(e1.dataset["albedo"].values, e3.dataset["albedo"].values)
    assert e1.edit["target"]["file"] == str(path) and e1.edit["target"]["statistics"] == e3.edit["target"]["statistics"]
    assert e1.targets == ()
    # Colour transfer from the same statistics: their image histograms and colour basis.
    c = transfer_colour_subject(store, "A2", stats, regions=[7], new_id="A2-colour-stats")
    cheek = pop[1]["A2"]["region"].values == 7
    v1 = pop[1]["V1"]
    np.testing.assert_allclose(
        c.dataset["albedo"].values[cheek].mean(0), v1["albedo"].values[v1["region"].values == 7].mean(0), rtol=0.01
    )
    assert c.targets == () and c.edit["target"] == e3.edit["target"]
    with pytest.raises(StoreError, match="neither a subject of store"):
        transfer_texture_subject(store, "A2", str(tmp_path / "missing.npz"))


def test_ids_are_new_and_existing_ids_refused(store, pop):
    e = transfer_brdf_subject(store, "A2", "V2", model="bp")
    with pytest.raises(StoreError, match="already exists"):
        transfer_brdf_subject(store, "A2", "V2", model="bp")  # same edit, same default id
    again = transfer_brdf_subject(store, "A2", "V2", model="bp", overwrite=True)
    assert again.subject_id == e.subject_id
    other = transfer_brdf_subject(store, "A2", "V2", model="bp", t=0.3)
    assert other.subject_id != e.subject_id  # the digest covers the parameters
    with pytest.raises(ValidationError, match="never overwrites its source"):
        transfer_brdf_subject(store, "A2", "V2", new_id="A2", overwrite=True)
    with pytest.raises(StoreError, match="already exists"):
        transfer_brdf_subject(store, "A2", "V2", new_id="V1")
    # overwrite replaces earlier edits only: never a measured subject, never the edit's own target
    with pytest.raises(StoreError, match="'V1' of store .* is a measured subject, not an earlier edit"):
        transfer_brdf_subject(store, "A2", "V2", new_id="V1", overwrite=True)
    with pytest.raises(ValidationError, match="new_id must differ from the edit's target subjects, got 'V2'"):
        transfer_brdf_subject(store, "A2", "V2", new_id="V2", overwrite=True)
    assert provenance(store.subject("V1")).get("source") != EDIT_SOURCE
    xr.testing.assert_identical(store.subject("A2"), store.subject("A2"))
    np.testing.assert_array_equal(store.subject("A2")["bp_rho_s"].values, pop[1]["A2"]["bp_rho_s"].values)


def test_errors(store, pop, tmp_path):
    with pytest.raises(ValidationError, match="subject must be a map subject"):
        change_skin_type(store, "M1", 2)
    with pytest.raises(ValidationError, match=r"target query \(skin type I, condition cold\) matches no subject"):
        transfer_brdf_subject(store, "A2", {"skin_type": 1, "condition": "cold"})
    with pytest.raises(ValidationError, match="target must differ"):
        transfer_brdf_subject(store, "A2", "A2")
    with pytest.raises(ValidationError, match="region must be 1-10 or one of"):
        transfer_brdf_subject(store, "A2", "V1", regions=["knee"])
    with pytest.raises(ValidationError, match="t must lie in"):
        transfer_brdf_subject(store, "A2", "V1", t=1.5)
    with pytest.raises(ValidationError, match="brdf and colour"):
        change_skin_type(store, "A2", 5, brdf=False, colour=False)
    with pytest.raises(StoreError, match="no subject 'nobody'"):
        change_skin_type(store, "nobody", 5)
    ro = open_store(pop[0])
    with pytest.raises(StoreError, match="read-only.*out_store"):
        change_skin_type(ro, "A2", 5)


def test_default_store_is_read_only_and_edits_go_to_another_store(tmp_path):
    default = facestats.open_store(None)
    with pytest.raises(StoreError, match="embedded default store is read-only.*out_store=open_store"):
        transfer_brdf_subject(default, "S008", {"condition": "lotion"}, t=0.5)
    out = open_store(tmp_path / "edits.zarr", mode="a")
    e = transfer_brdf_subject(default, "S008", {"condition": "lotion"}, t=0.5, out_store=out)
    assert e.subject_id in out and e.subject_id not in default and list(e.targets) == ["S008-lotion"]
    assert provenance(out.subject(e.subject_id))["source_store"] == "default"
    src, lot = default.subject("S008"), default.subject("S008-lotion")
    reg = src["region"].values
    for var in ("ts_rho_s", "ts_m"):
        for r in (2, 7):
            sel = reg == r
            b, tgt = src[var].values[sel].mean(), lot[var].values[sel & (lot["ts_flag"].values == 0)].mean()
            a = e.dataset[var].values[sel].mean()
            assert abs(a - 0.5 * (b + tgt)) < 0.05 * abs(tgt - b), (var, r)

    # Before/after images: sRGB-encoded albedo, enlarged by pixel repetition; one summary figure.
    import colour
    from matplotlib.image import imread

    files = save_edit_images(e, tmp_path / "img")
    names = {f.name for f in files}
    sid = e.subject_id
    assert {
        f"{sid}_albedo_before.png",
        f"{sid}_albedo_after.png",
        f"{sid}_ts_m_after.png",
        f"{sid}_bp_exponent_before.png",
        f"{sid}_summary.png",
    } <= names
    img = imread(tmp_path / "img" / f"{sid}_albedo_before.png")[..., :3]
    assert img.shape == (288, 288, 3)  # 48 x 6
    expect = np.clip(colour.cctf_encoding(np.clip(src["albedo"].values.astype(np.float64), 0, 1)), 0, 1)
    np.testing.assert_allclose(img[::6, ::6], expect, atol=1 / 255 + 1e-6)
    fig = plot_subject_edit(e)
    assert len([ax for ax in fig.axes if ax.images]) == 3 * 4  # 4 BRDF maps (albedo unchanged), before/after/diff


def test_map_images_hold_their_scale_in_their_png_text(skin_v, tmp_path):
    """Each map's PNG is a plain image (no colour bar): its text chunks give the values at the colour map's ends,
    the 1st and 99th percentiles of the face texels of before and after; decoding its pixels with them gives the map
    back; ``stage_edit_images`` returns the same scale in words (what ``facestats edit`` prints)."""
    from matplotlib import colormaps
    from PIL import Image

    from facestats.core.outputs import OutputSet
    from facestats.edit.plots import SCALE_KEYS, stage_edit_images

    before, _, e = skin_v
    with OutputSet(tmp_path) as out:
        scales = stage_edit_images(e, out)
    sid, face = e.subject_id, before["region"].values > 0
    assert sorted(scales) == sorted(f.name for f in out.written) and len(scales) == 2 + 2 * 4 + 1
    lut = colormaps["viridis"](np.arange(256), bytes=True)[:, :3].astype(int)  # the 256 colours an 8-bit PNG holds
    for var in e.brdf_variables:
        maps = {"before": before[var].values, "after": e.dataset[var].values}
        lo, hi = np.percentile(np.concatenate([maps["before"][face], maps["after"][face]]).astype(np.float32), [1, 99])
        for when, values in maps.items():
            png = Image.open(tmp_path / f"{sid}_{var}_{when}.png")
            text = png.text
            assert set(SCALE_KEYS) <= set(text) and text["facestats:variable"] == var
            assert (text["facestats:colormap"], text["facestats:units"], text["facestats:texel_pixels"]) == (
                "viridis", "1", "11"
            )  # fmt: skip
            vmin, vmax = float(text["facestats:vmin"]), float(text["facestats:vmax"])
            assert (vmin, vmax) == (lo, hi) and vmin < vmax, (var, when)
            assert f"viridis from {vmin:.4g} (dark purple) to {vmax:.4g} (yellow)" in text["Description"]
            assert scales[png.filename.rsplit("/", 1)[1]] in text["Description"]
            rgb = np.asarray(png.convert("RGB"))[5::11, 5::11]  # one pixel per texel (24 x 11 pixels)
            # colour k of 256 stands for [vmin + k/256 (vmax - vmin), vmin + (k + 1)/256 (vmax - vmin)); two pairs of
            # neighbouring viridis colours are equal in 8 bits: a colour stands for the bins of all its indices
            same = np.all(rgb[:, :, None, :] == lut[None, None], axis=-1)  # (24, 24, 256)
            first, last = np.argmax(same, axis=-1), 255 - np.argmax(same[..., ::-1], axis=-1)
            step, eps = (vmax - vmin) / 256, 1e-6 * (vmax - vmin)
            inside = face & (values >= vmin) & (values <= vmax)
            assert inside.sum() > 0.9 * face.sum() and same[inside].any(axis=-1).all()
            assert np.all(vmin + first[inside] * step - eps <= values[inside]), (var, when)
            assert np.all(values[inside] <= vmin + (last[inside] + 1) * step + eps), (var, when)
            assert np.all(rgb[~face] == 0)
    for when in ("before", "after"):
        text = Image.open(tmp_path / f"{sid}_albedo_{when}.png").text
        assert (text["facestats:colormap"], text["facestats:vmin"], text["facestats:vmax"]) == ("sRGB", "0.0", "1.0")
    assert "colour bars" in scales[f"{sid}_summary.png"]


def test_an_edit_made_with_commit_false_is_written_by_its_commit_only(store, tmp_path):
    """``commit=False`` makes the whole edit and writes nothing (``facestats edit`` saves its images first); the
    pending edit's ``commit()`` writes exactly what the default call writes, once, and is refused, with nothing
    replaced, when another writer took the id meanwhile."""
    out = open_store(tmp_path / "out.zarr", mode="a")
    pending = transfer_brdf_subject(store, "A2", "V1", t=0.5, out_store=out, new_id="P1", commit=False)
    assert isinstance(pending, PendingEdit) and not pending.committed and pending.edit.subject_id == "P1"
    assert out.ids() == [] and pending.edit.store == out.label
    done = transfer_brdf_subject(store, "A2", "V1", t=0.5, out_store=out, new_id="P2")  # the default: written
    assert isinstance(done, SubjectEdit) and out.ids() == ["P2"]
    e = pending.commit()
    assert e is pending.edit and pending.committed and out.ids() == ["P1", "P2"]
    assert pending.commit() is e and out.ids() == ["P1", "P2"]  # written once
    p1, p2, src = out.subject("P1"), out.subject("P2"), store.subject("A2")
    face = src["region"].values > 0
    assert not np.allclose(p1["ts_rho_s"].values[face], src["ts_rho_s"].values[face])  # the edit is in it
    for var in ("ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent", "albedo"):
        np.testing.assert_array_equal(p1[var].values, e.dataset[var].values)
        np.testing.assert_array_equal(p1[var].values, p2[var].values)
    assert provenance(p1)["edit"] == provenance(p2)["edit"] and provenance(p1)["source_subject"] == "A2"
    # Another writer takes the id between the edit and its commit: refused, its subject kept.
    p3 = transfer_brdf_subject(store, "A2", "V1", out_store=out, new_id="P3", commit=False)
    out.write_subject(make_map_subject("P3", size=SIZE, seed=21))
    with pytest.raises(StoreError, match=r"\['P3'\] already exist"):
        p3.commit()
    assert not p3.committed and provenance(out.subject("P3"))["source"] == "tests.helpers"  # not the edit
    out.close()


@pytest.mark.parametrize("overwrite", [False, True])
def test_a_commit_from_two_threads_writes_once_and_both_get_the_edit(store, tmp_path, monkeypatch, overwrite):
    """Two threads committing one pending edit both wrote it: the second failed on the id the first had taken
    ("already exist"), or, with overwrite, wrote a second generation.  The second now waits for the first and
    gets its result."""
    import threading

    out = open_store(tmp_path / "out.zarr", mode="a")
    pending = transfer_brdf_subject(store, "A2", "V1", out_store=out, new_id="P4", overwrite=overwrite, commit=False)
    real, calls, inside = type(out).write_subject, [], threading.Event()

    def write_subject(self, ds, **kwargs):
        calls.append(ds.attrs["subject_id"])
        inside.set()
        threading.Event().wait(0.3)  # the first writer is still writing when the second commits
        return real(self, ds, **kwargs)

    monkeypatch.setattr(type(out), "write_subject", write_subject)
    results = []

    def commit():
        try:
            results.append(pending.commit())
        except StoreError as exc:
            results.append(exc)

    first = threading.Thread(target=commit)
    first.start()
    assert inside.wait(10)
    commit()  # the second caller, while the first is inside write_subject
    first.join()
    assert calls == ["P4"] and len(results) == 2 and all(r is pending.edit for r in results) and pending.committed
    assert out.ids() == ["P4"] and len(out.index_entries()) == 1
    out.close()


def test_every_edit_leaves_the_source_it_read_unchanged_in_memory(store):
    """An edit works on a shallow copy of the source (a deep one held every map twice): each edit must replace
    whole variables, never write into the source's arrays.  The edit's ``source`` stays equal, bit for bit, to a
    fresh read of the stored subject after each kind of edit."""
    edits = [
        lambda: change_skin_type(store, "A2", 5, new_id="A2-shallow-skin"),
        lambda: transfer_colour_subject(store, "A2", "V1", regions=["cheeks"], new_id="A2-shallow-colour"),
        lambda: transfer_brdf_subject(store, "A2", "V1", regions=[2, "cheeks"], model="ts", new_id="A2-shallow-brdf"),
        lambda: transfer_texture_subject(store, "A2", "V1", new_id="A2-shallow-tex", levels=2, iterations=2),
    ]
    for make in edits:
        e = make()
        xr.testing.assert_identical(e.source, store.subject("A2"))
        changed = [v for v in e.variables if v in e.source]
        assert changed and any(not np.array_equal(e.source[v].values, e.dataset[v].values) for v in changed)


def _generations(path):
    return sorted(str(p.relative_to(path)) for p in (path / "subjects").glob("*/g*"))


def test_micro_normals_go_from_the_source_files_to_the_new_subject_band_by_band(tmp_path, monkeypatch):
    """No edit reads the micro-normals (session.ON_DISK): they stay on disk as dask arrays of one stored band each,
    are CRC-verified and validated when written, and arrive bit for bit.  A source whose micro-normals are damaged
    on disk, or out of their domain under valid checksums (a hostile writer), makes the edit fail and writes
    nothing."""
    from facestats.edit.session import read_map_subject

    path = tmp_path / "mn.zarr"
    src = with_micro_normals(make_map_subject("MN", size=70, seed=11), cameras=4)
    with open_store(path, mode="a") as st:
        st.write_subjects([src, make_map_subject("T", size=70, skin_type=5, seed=12)])
        ds, _ = read_map_subject(st, "MN")
        assert ds["micro_normal"].chunks == ((4,), (64, 6), (70,), (3,))  # lazy, one task per stored band
        assert ds["albedo"].chunks is None  # what edits read is in memory
        e = transfer_colour_subject(st, "MN", "T")
        new = st.subject(e.subject_id)
    np.testing.assert_array_equal(new["micro_normal"].values, src["micro_normal"].values)
    np.testing.assert_array_equal(e.dataset["micro_normal"].values, src["micro_normal"].values)
    assert not np.array_equal(new["albedo"].values, src["albedo"].values)

    hostile = src["micro_normal"].values.copy()
    hostile[2, 66, 30, 1] = 1.5  # a face texel of the second band
    assert src["region"].values[66, 30] > 0
    with open_store(path, mode="r+") as st:
        monkeypatch.setattr("facestats.io.batch.validate_subject", lambda ds, **kw: "maps")  # a writer that skips it
        st.write_subject(src.assign(micro_normal=(src["micro_normal"].dims, hostile)), overwrite=True)
        monkeypatch.undo()
        ids, gens = st.ids(), _generations(path)
        match = r"'micro_normal' must lie in .*got 1.5 \(1 value.*edit of subject 'MN'.*nothing was written"
        with pytest.raises(facestats.errors.SchemaError, match=match):
            transfer_colour_subject(st, "MN", "T", new_id="MN-hostile")
        assert st.ids() == ids and _generations(path) == gens

        gen = next((path / "subjects" / "MN").glob("g*"))
        (gen / "micro_normal" / "c" / "1" / "1" / "0" / "0").unlink()  # camera 1, rows 64..69
        with pytest.raises(facestats.errors.SchemaError, match=r"'MN'.*'micro_normal'.*checksum, chunk\(s\) \[1\]"):
            transfer_colour_subject(st, "MN", "T", new_id="MN-damaged")
        assert st.ids() == ids and _generations(path) == gens


def test_a_source_replaced_before_its_micro_normals_are_copied_fails_the_edit_as_no_damage(tmp_path):
    """The micro-normals an edit leaves on disk need the source's generation: a writer that replaces the source
    first makes the edit fail with a StoreError saying so (not a checksum error inviting a repair); nothing is
    written, and the store validates clean."""
    from facestats.edit.session import EditSession

    path = tmp_path / "mn.zarr"
    src = with_micro_normals(make_map_subject("MN", size=70, seed=11), cameras=2)
    with open_store(path, mode="a") as st:
        st.write_subjects([src, make_map_subject("T", size=70, skin_type=5, seed=12)])
        e = transfer_colour_subject(st, "MN", "T")
        session = EditSession(st).open("MN")
        session.assign_id("test", {"name": "test"})
        st.write_subject(src, overwrite=True)  # another writer: the source's generation is gone
        ids, gens = st.ids(), _generations(path)
        with pytest.raises(StoreError, match="'MN'.*'micro_normal'.*replaced or deleted.*not damaged"):
            session.write({"name": "test"}, variables=[])
        with pytest.raises(StoreError, match="'MN'.*'micro_normal'.*replaced or deleted"):
            e.source["micro_normal"].values
        assert st.ids() == ids and _generations(path) == gens
        assert st.validate().ok
        np.testing.assert_array_equal(st.subject(e.subject_id)["micro_normal"].values, src["micro_normal"].values)


def test_micro_normals_of_a_generation_without_chunk_checksums_are_loaded(tmp_path):
    """A generation written before chunk checksums existed verifies a variable only whole: streaming it band by band
    would read it whole for every band, so on_disk loads it (a helper's red team: 96 whole reads of 805 MB)."""
    import json

    from facestats.edit.session import read_map_subject
    from facestats.io.integrity import STORE_ATTR

    path = tmp_path / "old.zarr"
    src = with_micro_normals(make_map_subject("MN", size=70, seed=11), cameras=2)
    with open_store(path, mode="a") as st:
        st.write_subjects([src, make_map_subject("T", size=70, skin_type=5, seed=12)])
    group = next((path / "subjects" / "MN").glob("g*")) / "zarr.json"
    meta = json.loads(group.read_text())
    attr = json.loads(meta["attributes"][STORE_ATTR])
    for entry in attr["manifest"].values():
        entry.pop("chunk_rows", None), entry.pop("chunk_crc32", None)
    meta["attributes"][STORE_ATTR] = json.dumps(attr)
    group.write_text(json.dumps(meta))
    with open_store(path, mode="r+") as st:
        ds, _ = read_map_subject(st, "MN")
        assert ds["micro_normal"].chunks is None
        e = transfer_colour_subject(st, "MN", "T")
        np.testing.assert_array_equal(st.subject(e.subject_id)["micro_normal"].values, src["micro_normal"].values)
