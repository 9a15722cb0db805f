"""The capture folder, the photograph ingest and its bad inputs, on a tiny simulated capture (4 cameras, 6 LEDs)."""

import json
import os
import shutil
from dataclasses import replace

import numpy as np
import pytest

from facestats import FacestatsError
from facestats.acquire.dome import Dome, default_dome
from facestats.acquire.ingest import footprint_note, ingest_photographs, ingest_state, open_ingested
from facestats.acquire.photographs import CaptureFolder, bilinear_taps, open_folder
from facestats.acquire.synthetic.photographs import write_capture_photographs
from facestats.acquire.synthetic.population import synthesize_population
from facestats.face.procedural import procedural_face
from facestats.io.mesh import load_face_mesh

CAMERAS = [3, 4, 11, 12]
LEDS = [0, 1, 2, 5, 9, 14]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A 16-grid subject photographed by 4 cameras under 6 LEDs at 96² pixels, 12-bit PNG."""
    pop = synthesize_population(map_size=16, geometry=procedural_face(16), conditions=False, subjects=["S011"])
    truth = pop["S011"]
    dome = default_dome().select(leds=LEDS, cameras=CAMERAS).resized(96, 96)
    root = tmp_path_factory.mktemp("tiny")
    pc = write_capture_photographs(
        truth, root / "photos", geometry=procedural_face(16), dome=dome, seed=1, moved_frames=[(1, 2)], motion_deg=1.5
    )
    return root, pc, truth


@pytest.fixture
def copy(tiny, tmp_path):
    """A fresh copy of the tiny capture folder to damage."""
    root, pc, _ = tiny
    shutil.copytree(pc.folder.parent, tmp_path / "photos")
    return tmp_path / "photos"


def _geometry(folder):
    return load_face_mesh(folder / "face.obj", folder / "face.regions.png")


def _edit_manifest(folder, fn):
    doc = json.loads((folder / "manifest.json").read_text())
    fn(doc)
    (folder / "manifest.json").write_text(json.dumps(doc))


def test_folder_layout_and_frames(tiny):
    _, pc, truth = tiny
    f = open_folder(pc.folder.parent)
    assert isinstance(f, CaptureFolder) and f.kind == "face" and f.bits == 12
    assert (f.n_cameras, f.n_leds, f.n_exposures, f.n_poses) == (4, 6, 2, 1)
    np.testing.assert_allclose(f.times(2, 3), [1 / 60, 1 / 8])
    codes = f.read_codes(2, 3, 1, size=(96, 96))
    assert codes.dtype == np.uint16 and codes.shape == (96, 96, 3) and 0 < codes.max() <= 4095
    assert f.subject()["subject_id"] == truth.subject_id
    sensor, prof, std = f.sensor()
    assert prof.shape == (3, sensor.n_fibers, 3) and np.all(std > 0)


def test_a_sensor_file_that_is_a_fifo_or_a_link_out_is_refused_not_read(copy, tmp_path):
    """The sensor file was read with Path.read_text: a FIFO there hung the ingest (a red team)."""
    name = json.loads((copy / "manifest.json").read_text())["sensor"]
    (copy / name).rename(tmp_path / "sensor-elsewhere.json")
    os.mkfifo(copy / name)
    with pytest.raises(FacestatsError, match=f"sensor file {name} of .* cannot be read: .*not a regular file"):
        open_folder(copy).sensor()
    (copy / name).unlink()
    (copy / name).symlink_to(tmp_path / "sensor-elsewhere.json")
    with pytest.raises(FacestatsError, match=f"sensor file {name} listed in manifest.json must lie inside"):
        open_folder(copy).sensor()


def test_a_sensor_file_missing_a_key_names_the_file_and_the_key(copy):
    name = json.loads((copy / "manifest.json").read_text())["sensor"]
    doc = json.loads((copy / name).read_text())
    del doc["sensor"]["scale_e_per_s_per_mm-2"]
    (copy / name).write_text(json.dumps(doc))
    message = f"sensor file {name} of .* has .*missing the key 'scale_e_per_s_per_mm-2'"
    with pytest.raises(FacestatsError, match=message):
        open_folder(copy).sensor()


def test_bilinear_taps_interpolate_a_linear_ramp():
    img = np.add.outer(np.arange(5.0), 10 * np.arange(7.0))  # value = row + 10 col
    index, weight = bilinear_taps(np.array([[2.25, 1.5], [0.0, 0.0], [6.0, 4.0]]), (7, 5))
    vals = np.sum(img.reshape(-1)[index] * weight, axis=1)
    np.testing.assert_allclose(vals, [1.5 + 22.5, 0.0, 4.0 + 60.0])


def test_bilinear_taps_agree_with_scipy_up_to_the_image_edges(rng):
    """Against scipy.ndimage.map_coordinates (order 1, clamp to edge) everywhere an image spans, [-1/2, W - 1/2):
    within half a pixel of the left and top edges the second tap read pixel 1 (u = -0.25 gave 0.75 on f = x)."""
    from scipy.ndimage import map_coordinates

    w, h = 9, 6
    img = rng.random((h, w))
    pts = np.c_[rng.uniform(-0.5, w - 0.5, 4000), rng.uniform(-0.5, h - 0.5, 4000)]
    pts[:8] = [[-0.5, 2], [-0.25, 3], [-0.01, 0], [4, -0.5], [2, -0.3], [-0.4, -0.4], [w - 0.51, 1], [1, h - 0.51]]
    index, weight = bilinear_taps(pts, (w, h))
    got = np.sum(img.reshape(-1)[index] * weight, axis=1)
    want = map_coordinates(img, [pts[:, 1], pts[:, 0]], order=1, mode="nearest")
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)  # float32 weights


def test_ingest_recovers_the_simulated_radiance(tiny, tmp_path):
    from facestats.acquire.synthetic.simulate import DomeSimulator

    root, pc, truth = tiny
    folder = pc.folder.parent
    dome = Dome.load(pc.calibration)
    path = ingest_photographs(folder, _geometry(folder), dome, tmp_path / "cap.zarr", workers=1, min_footprint_px=1)
    cap = open_ingested(path)
    assert cap.metadata["subject_id"] == truth.subject_id and cap.provenance["source"] == "photographs"
    flags = cap.provenance["motion_flags"]
    assert [(f["camera"], f["led"]) for f in flags] == [(1, 2)]  # the one frame whose head moved, no other
    assert np.all(np.isnan(cap.array("radiance")[:, 1, 2]))  # its samples are invalid
    clean = DomeSimulator(pc.geometry, pc.true_dome, noise=False, scan_normal_noise_deg=0).simulate(truth)
    a, b = cap.array("radiance").astype(np.float64), clean.array("radiance").astype(np.float64)
    b[:, 1, 2] = np.nan  # the moved frame
    both = np.isfinite(a) & np.isfinite(b) & (b > 0.01)
    # grazing and unresolved samples are dropped, and those whose taps fall beyond the mesh's edge or on an occluder
    assert both.sum() > 0.7 * np.isfinite(b).sum()  # 0.71 (0.78 before the taps' surface test)
    ratio = a[both] / b[both]
    assert abs(np.median(ratio) - 1) < 0.01 and np.percentile(np.abs(ratio - 1), 75) < 0.05
    # An e2e red team: taps beyond the silhouette read the background, samples up to half as bright (1st percentile
    # of the ratio 0.813, 1.6 % of samples below 0.9; now 0.947 and 0.26 %)
    assert np.percentile(ratio, 1) > 0.9 and np.mean(ratio < 0.9) < 0.005
    np.testing.assert_allclose(cap.array("irradiance"), clean.array("irradiance"), rtol=0.03)  # calibration errors
    np.testing.assert_array_equal(cap.array("sensor_profile"), json_profile(folder))


def test_the_capture_counts_the_samples_the_footprint_rule_drops(tiny, tmp_path):
    """An e2e red team: ICT-FaceKit's face photographed at 160² pixels lost 98.9 % of its samples to the footprint
    rule, and the fit's error blamed max_angle_deg; the capture now records what the rule dropped."""
    _, pc, _ = tiny
    folder = pc.folder.parent
    geometry, dome = _geometry(folder), Dome.load(pc.calibration)
    paths = {
        px: ingest_photographs(folder, geometry, dome, tmp_path / f"{px}.zarr", workers=1, min_footprint_px=px)
        for px in (0, 1, 3)
    }
    records = {px: open_ingested(p).provenance["footprint"] for px, p in paths.items()}
    visible = records[0]["visible_samples"]
    assert visible > 0 and all(r["visible_samples"] == visible for r in records.values())  # the rule drops, no more
    assert records[0]["dropped_samples"] == 0 and footprint_note(open_ingested(paths[0]).provenance) == ""
    assert 0 < records[1]["dropped_samples"] < records[3]["dropped_samples"] < visible
    assert records[1]["median_px"] == records[3]["median_px"] and 1 < records[1]["median_px"] < 3  # 2.57 here
    for px, path in paths.items():
        radiance = open_ingested(path).array("radiance")
        cameras = ingest_state(path)["footprint"]
        assert [c["camera"] for c in cameras] == [0, 1, 2, 3]
        assert sum(c["dropped"] for c in cameras) == records[px]["dropped_samples"]
        assert sum(c["off_surface"] for c in cameras) == records[px]["off_surface_samples"] > 0
        for c in cameras:  # every sample kept is in the capture (camera 1 also lost its moved frame, LED 2)
            kept = int(np.isfinite(radiance[:, c["camera"]]).all(-1).sum())
            if c["camera"] == 1:
                assert kept < c["visible"] - c["dropped"] - c["off_surface"]
            else:
                assert kept == c["visible"] - c["dropped"] - c["off_surface"], (px, c)
    note = footprint_note(open_ingested(paths[3]).provenance)
    d = records[3]["dropped_samples"]
    assert note.startswith(f"the ingest dropped {d:,} of the {visible:,} lit samples its cameras see ")
    assert f"({100 * d / visible:.1f} %)" in note and "fewer than --min-footprint 3 pixels" in note


def test_a_fit_left_without_samples_says_how_many_the_footprint_rule_dropped(tiny, tmp_path):
    from facestats.pipeline.photographs import ingest_subject

    _, pc, _ = tiny
    folder = pc.folder.parent
    all_kept = ingest_photographs(
        folder, _geometry(folder), pc.calibration, tmp_path / "all.zarr", workers=1, min_footprint_px=0
    )
    visible = open_ingested(all_kept).provenance["footprint"]["visible_samples"]
    store = tmp_path / "s.zarr"
    with pytest.raises(FacestatsError) as info:
        ingest_subject(folder, folder / "face.obj", pc.calibration, store, "PH001", workers=1, min_footprint_px=1000)
    msg = str(info.value)
    assert msg.startswith("no face lumitexel of the capture has the 30 usable samples a fit needs"), msg
    assert f"; the ingest dropped {visible:,} of the {visible:,} lit samples its cameras see (100.0 %)" in msg
    assert "fewer than --min-footprint 1000 pixels" in msg
    assert not store.exists() and not (tmp_path / "s.zarr.ingest").exists()  # a failed ingest leaves nothing


def test_a_resume_under_another_footprint_or_motion_rule_is_refused(tiny, tmp_path):
    """Both rules decide which samples of a camera are kept: a resume under others would mix two in one capture."""
    import zarr

    _, pc, _ = tiny
    folder = pc.folder.parent
    geometry, dome = _geometry(folder), Dome.load(pc.calibration)
    a = ingest_photographs(folder, geometry, dome, tmp_path / "a.zarr", workers=1, min_footprint_px=1)
    with pytest.raises(FacestatsError, match=r"a\.zarr holds an ingest of other inputs \(min_footprint_px differ\)"):
        ingest_photographs(folder, geometry, dome, a, workers=1, min_footprint_px=2)
    with pytest.raises(FacestatsError, match=r"a\.zarr holds an ingest of other inputs \(motion_tolerance differ\)"):
        ingest_photographs(folder, geometry, dome, a, workers=1, min_footprint_px=1, motion_tolerance=0.01)
    assert ingest_photographs(folder, geometry, dome, a, workers=1, min_footprint_px=1) == str(a)  # the same
    group = zarr.open_group(str(a), mode="r+")  # an ingest begun before the rules were part of the key
    state = json.loads(group.attrs["ingest"])
    del state["fingerprint"]["min_footprint_px"], state["fingerprint"]["motion_tolerance"]
    group.attrs["ingest"] = json.dumps(state)
    assert ingest_photographs(folder, geometry, dome, a, workers=1, min_footprint_px=2) == str(a)  # unknown: kept


def json_profile(folder):
    return np.asarray(json.loads((folder / "sensor.json").read_text())["profile"])


# -- bad input -------------------------------------------------------------------------------------------------
def test_missing_frame(copy):
    (copy / "cam02" / "led003_e1.png").unlink()
    with pytest.raises(FacestatsError, match=r"frame cam02/led003_e1\.png listed in manifest\.json is missing"):
        open_folder(copy)


def test_checksum_mismatch_names_the_file(copy, tiny):
    _, pc, _ = tiny
    shutil.copy(copy / "cam01" / "led000_e0.png", copy / "cam01" / "led004_e0.png")
    f = open_folder(copy)
    with pytest.raises(
        FacestatsError, match=r"frame cam01/led004_e0\.png: field 'sha256' of manifest\.json is [0-9a-f]{64}"
    ):
        f.read_codes(1, 4, 0)
    with pytest.raises(FacestatsError, match=r"led004_e0\.png: field 'sha256'"):
        ingest_photographs(copy, _geometry(copy), Dome.load(pc.calibration), copy.parent / "c.zarr", workers=1)


def test_wrong_image_size_and_camera_count(copy, tiny):
    _, pc, _ = tiny
    dome = Dome.load(pc.calibration)
    with pytest.raises(
        FacestatsError, match=r"frame cam00/led000_e0\.png is 96×96 pixels, the calibration's .* 128×128"
    ):
        ingest_photographs(copy, _geometry(copy), dome.resized(128, 128), copy.parent / "a.zarr", workers=1)
    with pytest.raises(FacestatsError, match=r"manifest\.json field 'n_cameras' is 4, the calibration has 3 cameras"):
        ingest_photographs(copy, _geometry(copy), dome.select(cameras=[0, 1, 2]), copy.parent / "b.zarr")


def test_camera_count_mismatch_names_the_calibration_file(copy, tiny):
    """Given the calibration's file, the ingest names it in the camera-count error (and reads it)."""
    _, pc, _ = tiny
    three = copy.parent / "three-cameras.json"
    Dome.load(pc.calibration).select(cameras=[0, 1, 2]).save(three)
    with pytest.raises(
        FacestatsError,
        match=r"photos/manifest\.json field 'n_cameras' is 4, the calibration .*three-cameras\.json has 3 cameras "
        r"\(field 'cameras'\)",
    ):
        ingest_photographs(copy, _geometry(copy), three, copy.parent / "b.zarr")
    with pytest.raises(FacestatsError, match=r"dome must be a Dome calibration or the path of its file, got dict"):
        ingest_photographs(copy, _geometry(copy), Dome.load(pc.calibration).to_dict(), copy.parent / "c.zarr")


def test_wrong_bit_depth(copy, tiny):
    _, pc, _ = tiny
    _edit_manifest(copy, lambda d: d.update(bits=10))
    f = open_folder(copy)
    with pytest.raises(
        FacestatsError, match=r"frame cam\d\d/led\d{3}_e\d\.png holds code \d+, above 1023 of field 'bits' = 10"
    ):
        for led in range(6):
            f.read_codes(0, led, 1)
    with pytest.raises(
        FacestatsError,
        match=r"field 'camera_log_response' of the calibration .*dome.*\.json has 4096 levels, .*manifest\.json "
        r"field 'bits' is 10",
    ):
        ingest_photographs(copy, _geometry(copy), pc.calibration, copy.parent / "a.zarr")
    import cv2

    cv2.imwrite(str(copy / "cam00" / "led001_e0.png"), np.zeros((96, 96, 3), np.uint8))
    f = open_folder(copy)
    f.sha256[0, 0, 1, 0] = __import__("hashlib").sha256((copy / "cam00" / "led001_e0.png").read_bytes()).hexdigest()
    f.bits = 12
    with pytest.raises(
        FacestatsError, match=r"frame cam00/led001_e0\.png is a 8-bit file, field 'bits' of manifest\.json is 12"
    ):
        f.read_codes(0, 1, 0)


def test_a_planar_16_bit_tiff_frame_reads_the_codes_it_holds(copy):
    """A camera writing 16-bit TIFF with separate colour planes (PlanarConfiguration 2): the same codes as the PNG."""
    import hashlib

    tifffile = pytest.importorskip("tifffile")
    want = open_folder(copy).read_codes(1, 2, 1)
    tif = copy / "cam01" / "led002_e1.tif"
    tifffile.imwrite(tif, np.ascontiguousarray(np.moveaxis(want, -1, 0)), photometric="rgb", planarconfig="separate")
    digest = hashlib.sha256(tif.read_bytes()).hexdigest()

    def point(d):
        for fr in d["frames"]:
            if (fr["camera"], fr["led"], fr["exposure"]) == (1, 2, 1):
                fr.update(file="cam01/led002_e1.tif", sha256=digest)

    _edit_manifest(copy, point)
    got = open_folder(copy).read_codes(1, 2, 1, size=(96, 96))
    assert got.dtype == np.uint16 and got.shape == (96, 96, 3)
    np.testing.assert_array_equal(got, want)


def test_non_monotonic_exposure_times_and_exif_disagreement(copy):
    def swap(d):
        for fr in d["frames"]:
            if fr["camera"] == 1 and fr["led"] == 2:
                fr["exposure_s"] = {0: 0.2, 1: 0.1}[fr["exposure"]]

    _edit_manifest(copy, swap)
    with pytest.raises(
        FacestatsError, match=r"frame cam01/led002_e1\.png: field 'exposure_s' 0\.1 s is not longer than"
    ):
        open_folder(copy)

    def stretch(d):
        for fr in d["frames"]:
            if fr["camera"] == 1 and fr["led"] == 2:
                fr["exposure_s"] = {0: 1 / 60, 1: 0.15}[fr["exposure"]]

    _edit_manifest(copy, stretch)
    with pytest.raises(
        FacestatsError, match=r"led002_e1\.png: EXIF ExposureTime 0\.125 s disagrees with field 'exposure_s' 0\.15"
    ):
        open_folder(copy).read_codes(1, 2, 1)


def test_bad_manifests(copy):
    original = (copy / "manifest.json").read_text()
    _edit_manifest(copy, lambda d: d.update(format="something/2"))
    with pytest.raises(FacestatsError, match=r"field 'format' must be 'facestats.capture-folder/1', got 'something/2'"):
        open_folder(copy)
    _edit_manifest(copy, lambda d: d.update(format="facestats.capture-folder/1", frames=d["frames"][:-1]))
    with pytest.raises(FacestatsError, match=r"lists no frame for pose 0, camera 3, LED 5, exposure 1"):
        open_folder(copy)
    _edit_manifest(copy, lambda d: d["frames"].append(dict(d["frames"][0], led=9)))
    with pytest.raises(FacestatsError, match=r"frames\[\d+\] field 'led' has an invalid value 9"):
        open_folder(copy)
    with pytest.raises(FacestatsError, match="has no readable manifest.json"):
        open_folder(copy / "cam00")
    # A second full set of frames as pose 1: an ingest reads pose 0, so they were ignored without a word.
    (copy / "manifest.json").write_text(original)
    _edit_manifest(copy, lambda d: d["frames"].extend([dict(f, pose=1) for f in d["frames"]]))
    with pytest.raises(FacestatsError, match=r"frames of a face capture must all be pose 0 .*got poses 0\.\.1"):
        open_folder(copy)


@pytest.mark.parametrize(
    "edit, message",
    [
        (lambda d: d["frames"][0].update(pose=2**62), r"fewer than the \d+ that its fields ask for"),
        (lambda d: d["frames"][0].update(exposure=10**12), r"fewer than the \d+ that its fields ask for"),
        (lambda d: d.update(n_leds=10**6), r"fewer than the \d+ that its fields ask for"),
        (lambda d: d["frames"][0].update(file="/etc/hostname"), r"frames\[0\] field 'file' has an invalid value"),
        (lambda d: d.update(sensor="/etc/hostname"), "naming the contact-sensor file inside the folder"),
    ],
)
def test_hostile_manifest_fields_are_refused_before_any_allocation_or_read(copy, edit, message):
    _edit_manifest(copy, edit)
    with pytest.raises(FacestatsError, match=message):
        open_folder(copy).sensor()


def _edit_sensor(folder, fn):
    path = folder / json.loads((folder / "manifest.json").read_text())["sensor"]
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))


def _set(field, at, value):
    return lambda doc: doc[field][at[0]][at[1]].__setitem__(at[2], value)


@pytest.mark.parametrize(
    "edit, message",
    [
        (_set("profile", (1, 2, 0), None), r"'profile' and 'profile_std' must both be null .* \(1, 2, 0\)"),
        (_set("profile_std", (0, 3, 2), None), r"must both be null .*got .* and nan at .* \(0, 3, 2\)"),
        (_set("profile", (2, 1, 1), float("inf")), r"field 'profile' must be finite .*inf at .*\(2, 1, 1\)"),
        (_set("profile_std", (2, 0, 0), -1e-9), r"'profile_std' must be finite and >= 0 .*\(2, 0, 0\)"),
    ],
)
def test_sensor_profiles_are_finite_or_null_in_both_fields(copy, edit, message):
    _edit_sensor(copy, edit)
    with pytest.raises(FacestatsError, match=message):
        open_folder(copy).sensor()


def _null_fibres(fibres, site=0):
    """An edit of the sensor file: ``fibres`` of ``site`` have no reading (clipped in every exposure)."""

    def edit(doc):
        for f in fibres:
            doc["profile"][site][f] = doc["profile_std"][site][f] = [None, None, None]

    return edit


def test_a_fibre_without_a_reading_is_ingested_as_nan_and_left_out_of_the_fit(tiny, copy, tmp_path):
    """A device session writes null where a fibre clipped in every exposure; the ingest refused such a folder while
    read_bracket and the fit accepted it. Both readers now keep it as a missing reading."""
    from facestats.pipeline.subject import fit_sensor

    _, pc, _ = tiny
    full = open_ingested(
        ingest_photographs(pc.folder.parent, _geometry(copy), pc.calibration, tmp_path / "a.zarr", min_footprint_px=1)
    )
    _edit_sensor(copy, _null_fibres([0, 1]))
    _, prof, std = open_folder(copy).sensor()
    assert np.isnan(prof[0, :2]).all() and np.isnan(std[0, :2]).all() and np.isfinite(prof[1:]).all()
    path = ingest_photographs(copy, _geometry(copy), pc.calibration, tmp_path / "b.zarr", min_footprint_px=1)
    cap = open_ingested(path)
    np.testing.assert_array_equal(cap.array("sensor_profile"), prof)
    a, b = fit_sensor(full), fit_sensor(cap)
    np.testing.assert_array_equal(b.sigma_tr[1:], a.sigma_tr[1:])  # the other sites' fits are untouched
    assert np.isfinite(b.sigma_tr[0]).all() and not np.array_equal(b.sigma_tr[0], a.sigma_tr[0])
    np.testing.assert_allclose(b.sigma_tr[0], a.sigma_tr[0], rtol=0.01)  # 26 of 28 fibres: nearly the same fit (0.1 %)


def test_a_site_with_fewer_than_three_readings_is_refused_before_any_work(copy, tiny):
    _, pc, _ = tiny
    n = len(json.loads((copy / json.loads((copy / "manifest.json").read_text())["sensor"]).read_text())["profile"][0])
    _edit_sensor(copy, _null_fibres(range(n - 2), site=2))
    with pytest.raises(FacestatsError, match="has 2 readings for site neck channel R .*at least 3.*shorter exposures"):
        ingest_photographs(copy, _geometry(copy), pc.calibration, copy.parent / "a.zarr")
    assert not (copy.parent / "a.zarr").exists()


def test_a_nan_profile_is_written_as_null_and_read_back_as_nan(copy):
    """write_sensor_file wrote NaN as the bare token NaN, which strict JSON readers refuse (a reviewer)."""
    from facestats.acquire.photographs import write_sensor_file

    path = copy / json.loads((copy / "manifest.json").read_text())["sensor"]
    sensor, profile, std = open_folder(copy).sensor()
    profile[1, 2, 0] = std[1, 2, 0] = np.nan
    write_sensor_file(path, sensor, profile, std)

    def refuse(token):
        raise ValueError(f"not strict JSON: {token}")

    doc = json.loads(path.read_text(), parse_constant=refuse)
    assert doc["profile"][1][2][0] is None and doc["profile_std"][1][2][0] is None
    _, back, back_std = open_folder(copy).sensor()
    np.testing.assert_array_equal(back, profile)  # NaN where it was, equal elsewhere
    np.testing.assert_array_equal(back_std, std)


def test_mesh_without_face_region(copy):
    from facestats.pipeline.photographs import find_region_image

    np.save(copy / "empty.npy", np.zeros((16, 16), np.uint8))
    geometry = _geometry(copy)
    n_vertices = len(geometry.mesh_vertices)
    with pytest.raises(
        FacestatsError,
        match=rf"no mesh vertex falls on a labelled face region of the region image: mesh .*face\.obj has {n_vertices} "
        r"vertices with UV u in \[0\.\d+, 0\.\d+\], v in \[0\.\d+, 0\.\d+\] \(image convention, v down\); region image "
        r".*empty\.npy is 16×16 pixels with 0 labelled \(label 1-10\); 0 vertices land on labelled pixels$",
    ):
        load_face_mesh(copy / "face.obj", copy / "empty.npy")
    with pytest.raises(FacestatsError, match=r"region image \(an array\) is 16×16 pixels with 0 labelled"):
        load_face_mesh(copy / "face.obj", np.zeros((16, 16), np.uint8))
    (copy / "junk.png").write_bytes(b"\x89PNG not really")  # one line naming the file, not a plugin list
    unreadable = r"^cannot read the region image .*junk\.png: .*could not be decoded[^\n]*$"
    with pytest.raises(FacestatsError, match=unreadable):
        load_face_mesh(copy / "face.obj", copy / "junk.png")
    (copy / "labels.exr").write_bytes(b"")  # the formats listed are those a label image can be: .npy among them
    with pytest.raises(
        FacestatsError, match=r"labels\.exr' has the extension '\.exr'; expected one of \('\.npy', '\.png'"
    ):
        load_face_mesh(copy / "face.obj", copy / "labels.exr")
    (copy / "face.regions.png").unlink()
    with pytest.raises(
        FacestatsError, match=r"mesh .*face\.obj has no face-region image \(looked for face\.regions\.png"
    ):
        find_region_image(copy / "face.obj")


def test_interrupted_ingest_leaves_no_subject_and_resumes(tiny, tmp_path, monkeypatch):
    from facestats.io import open_store
    from facestats.pipeline import FitSettings
    from facestats.pipeline.photographs import ingest_subject

    _, pc, truth = tiny
    folder = pc.folder.parent
    store = tmp_path / "s.zarr"
    read = CaptureFolder.read_stack
    calls = []

    def failing(self, camera, led, pose=0, size=None):
        calls.append(camera)
        if camera == 2 and led == 3:
            raise KeyboardInterrupt("power cut")
        return read(self, camera, led, pose, size)

    monkeypatch.setattr(CaptureFolder, "read_stack", failing)
    args = (folder, folder / "face.obj", pc.calibration, store, "PH001")
    few = FitSettings(min_samples=4, micro_normals=False)  # 4 cameras × 6 LEDs: at most 24 samples a lumitexel
    with pytest.raises(KeyboardInterrupt):
        ingest_subject(*args, workers=1, settings=few, min_footprint_px=1)
    with open_store(store) as st:
        assert "PH001" not in st  # a partial ingest never becomes a subject
    work = tmp_path / "s.zarr.ingest" / "PH001" / "capture.zarr"
    state = ingest_state(work)
    assert state["cameras_done"] == [0, 1] and not state["complete"]
    with pytest.raises(FacestatsError, match=r"is a partial ingest \(2 camera\(s\) done\); rerun the ingest"):
        open_ingested(work)
    calls.clear()
    monkeypatch.setattr(
        CaptureFolder,
        "read_stack",
        lambda self, c, l, pose=0, size=None: calls.append(c) or read(self, c, l, pose, size),
    )
    report = ingest_subject(*args, workers=1, settings=few, min_footprint_px=1)
    assert sorted(set(calls)) == [2, 3]  # finished cameras are skipped
    assert report.subject_id == "PH001" and "ingested PH001" in report.to_text()
    with open_store(store) as st:
        ds = st.subject("PH001")
    prov = json.loads(ds.attrs["provenance"])
    assert prov["capture_provenance"]["source"] == "photographs" and ds.attrs["age"] == truth.age
    assert ingest_subject(*args).skipped  # rerunning a finished ingest does nothing


def test_an_ingest_interrupted_while_it_sets_its_capture_up_starts_it_again(tiny, tmp_path, monkeypatch):
    """The capture recorded its ingest state before its per-lumitexel arrays: a rerun resumed a capture without
    them and failed on a missing chunk, every time (a red team). The state is written last now."""
    from facestats.acquire.capture import CaptureWriter
    from facestats.io import open_store
    from facestats.pipeline import FitSettings
    from facestats.pipeline.photographs import ingest_subject

    _, pc, _ = tiny
    folder = pc.folder.parent
    store = tmp_path / "s.zarr"
    write_block = CaptureWriter.write_block

    def cut(self, start, arrays):
        write_block(self, start, dict(list(arrays.items())[:3]))  # half the arrays, then Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(CaptureWriter, "write_block", cut)
    args = (folder, folder / "face.obj", pc.calibration, store, "PH002")
    few = FitSettings(min_samples=4, micro_normals=False)
    with pytest.raises(KeyboardInterrupt):
        ingest_subject(*args, workers=1, settings=few, min_footprint_px=1)
    work = tmp_path / "s.zarr.ingest" / "PH002" / "capture.zarr"
    assert ingest_state(work) is None and os.listdir(work)  # begun, but not an ingest to resume
    monkeypatch.setattr(CaptureWriter, "write_block", write_block)
    report = ingest_subject(*args, workers=1, settings=few, min_footprint_px=1)
    assert report.subject_id == "PH002" and ingest_state(work)["complete"]
    with open_store(store) as st:
        assert "PH002" in st


def test_8_bit_jpeg_frames_with_exif(tmp_path):
    """The simulator's 8-bit JPEG option: frames decode as 8-bit, carry their exposure time, and ingest."""
    from facestats.io.exif import read_exposure_time

    truth = synthesize_population(map_size=16, geometry=procedural_face(16), conditions=False, subjects=["S011"])[
        "S011"
    ]
    dome = default_dome().select(leds=[0, 1, 5], cameras=[3, 11]).resized(96, 96)
    pc = write_capture_photographs(truth, tmp_path / "jpg", geometry=procedural_face(16), dome=dome, extension=".jpg")
    f = open_folder(tmp_path / "jpg")
    assert f.bits == 8 and f.files[0, 1, 2, 1].endswith(".jpg")
    assert read_exposure_time(tmp_path / "jpg" / f.files[0, 1, 2, 1]) == 0.125
    assert f.read_codes(1, 2, 1).dtype == np.uint8
    dome_cal = Dome.load(pc.calibration)
    assert dome_cal.camera_log_response.shape == (2, 256, 3)
    cap = open_ingested(ingest_photographs(f, pc.geometry, dome_cal, tmp_path / "c.zarr", min_footprint_px=1))
    assert np.isfinite(cap.array("radiance")).mean() > 0.05


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_fifo_manifest_or_frame_is_refused_not_read(copy):
    """A FIFO where the manifest or a frame should be would block a plain read forever; it is refused at once."""
    frame = sorted((copy / "cam01").glob("*.png"))[0]
    frame.unlink()
    os.mkfifo(frame)
    with pytest.raises(FacestatsError, match=r"frame cam01/\S+\.png listed in manifest\.json is not a regular file"):
        open_folder(copy)  # checked when the folder is opened; reads refuse it too (io.layout.read_regular_file)
    frame.unlink()
    (copy / "manifest.json").unlink()
    os.mkfifo(copy / "manifest.json")
    with pytest.raises(FacestatsError, match=r"has no readable manifest\.json: not a regular file"):
        open_folder(copy)


def test_a_duplicated_camera_is_refused_before_any_work(copy, tiny):
    """ "cameras": [0, 0, 1, 2] hid camera 3's absence; the ingest crashed with a TypeError after the other cameras."""
    _, pc, _ = tiny

    def duplicate(d):
        d["cameras"] = [0, 0, 1, 2]
        d["frames"] = [fr for fr in d["frames"] if fr["camera"] != 3]

    _edit_manifest(copy, duplicate)
    with pytest.raises(FacestatsError, match=r"field 'cameras' must list each camera once, got camera 0 twice"):
        open_folder(copy)
    with pytest.raises(FacestatsError, match=r"got camera 0 twice"):
        ingest_photographs(copy, _geometry(copy), pc.calibration, copy.parent / "a.zarr")
    assert not (copy.parent / "a.zarr").exists()
    _edit_manifest(copy, lambda d: d.update(cameras=[0, 1, 2]))  # the distinct set decides whether it is a subset
    with pytest.raises(
        FacestatsError,
        match=r"field 'cameras' must list every camera 0\.\.3 \(a subset for targets only\), got 3 "
        r"without \[3\]",
    ):
        open_folder(copy)
    _edit_manifest(copy, lambda d: d.update(kind="target", cameras=[2, 0, 1, 1]))
    with pytest.raises(FacestatsError, match=r"got camera 1 twice"):
        open_folder(copy)
    _edit_manifest(copy, lambda d: d.update(cameras=[2, 0, 1]))
    assert open_folder(copy).cameras == [0, 1, 2]


def test_exposure_times_must_be_the_calibrations(copy, tiny):
    """Times in milliseconds (frames without EXIF cannot tell) divided the radiance by 1000 without a word."""
    from facestats.acquire.photographs import check_exposures

    _, pc, _ = tiny
    dome = Dome.load(pc.calibration)
    np.testing.assert_allclose(dome.exposure_times, [1 / 60, 1 / 8])
    _edit_manifest(copy, lambda d: [fr.update(exposure_s=fr["exposure_s"] * 1000) for fr in d["frames"]])
    with pytest.raises(
        FacestatsError,
        match=r"frame cam00/led000_e0\.png: field 'exposure_s' 16\.6667 s of manifest\.json differs by more than "
        r"1 % from exposure 0 of the calibration .*dome.*\.json \(field 'exposure_times_s': 0\.0166667 s\)",
    ):
        ingest_photographs(copy, _geometry(copy), pc.calibration, copy.parent / "a.zarr")
    assert not (copy.parent / "a.zarr").exists()

    def scale(factor):
        def edit(d):
            for fr in d["frames"]:
                fr["exposure_s"] = float(dome.exposure_times[fr["exposure"]])
                if (fr["camera"], fr["led"], fr["exposure"]) == (2, 3, 1):
                    fr["exposure_s"] *= factor

        return edit

    _edit_manifest(copy, scale(1.009))  # within the 1 % that the EXIF and device checks allow
    check_exposures(open_folder(copy), dome)
    _edit_manifest(copy, scale(1.02))
    with pytest.raises(FacestatsError, match=r"cam02/led003_e1\.png: field 'exposure_s' 0\.1275 s .* exposure 1 "):
        check_exposures(open_folder(copy), dome)
    three = replace(dome, exposure_times=np.array([1 / 60, 1 / 8, 1.0]))
    with pytest.raises(
        FacestatsError,
        match=r"manifest\.json frames have 2 exposures \(0\.\.1\), the calibration field 'exposure_times_s' has 3",
    ):
        check_exposures(open_folder(copy), three)


def test_the_calibrations_black_level_is_what_the_ingest_merges_with(tiny, tmp_path):
    """``camera_black_level`` of the dome calibration: JSON round trip, set by a response's ``apply``, and the
    default of ``ingest_photographs`` (the same capture as passing it explicitly)."""
    from facestats.acquire.bracket import ResponseCalibration

    _, pc, _ = tiny
    folder = pc.folder.parent
    dome = Dome.load(pc.calibration)
    assert dome.camera_black_level == 0 and "camera_black_level" not in dome.to_dict()  # older files unchanged
    levels = dome.camera_log_response.shape[1]
    resp = ResponseCalibration(dome.camera_log_response[0], 12, np.array([1 / 60, 1 / 8]), np.zeros((1, 2)))
    with_pedestal = replace(resp, black_level=64).apply(dome)
    assert with_pedestal.camera_black_level == 64
    assert Dome.from_dict(json.loads(json.dumps(with_pedestal.to_dict()))).camera_black_level == 64
    with pytest.raises(FacestatsError, match=rf"camera_black_level must be an integer in \[0, {levels // 2 - 1}\]"):
        replace(dome, camera_black_level=levels // 2)
    with pytest.raises(FacestatsError, match=r"black_level must be the calibration's camera_black_level \(64\)"):
        resp.apply(with_pedestal, cameras=[0])  # the cameras share one pedestal
    geometry = _geometry(folder)
    kw = dict(workers=1, min_footprint_px=1)
    a = ingest_photographs(folder, geometry, with_pedestal, tmp_path / "a.zarr", **kw)
    b = ingest_photographs(folder, geometry, dome, tmp_path / "b.zarr", black_level=64, **kw)
    c = ingest_photographs(folder, geometry, dome, tmp_path / "c.zarr", **kw)
    ra, rb, rc = (open_ingested(p).array("radiance") for p in (a, b, c))
    np.testing.assert_array_equal(ra, rb)
    assert not np.array_equal(ra, rc, equal_nan=True)  # the pedestal changes the merge


def test_the_calibrations_white_level_is_what_the_ingest_merges_with(tiny, tmp_path):
    """``camera_white_level`` of the dome calibration (DN, Z_max of Debevec & Malik 1997 eq. 4): JSON round trip,
    set by a response's ``apply``, the default of ``ingest_photographs`` (overridden by passing one), and part of the
    resume key (an ingest begun before it was keeps resuming with the top code)."""
    import zarr

    from facestats.acquire.bracket import ResponseCalibration

    _, pc, _ = tiny
    folder = pc.folder.parent
    dome = Dome.load(pc.calibration)
    assert dome.camera_white_level is None and "camera_white_level" not in dome.to_dict()  # older files unchanged
    resp = ResponseCalibration(
        dome.camera_log_response[0], 12, np.array([1 / 60, 1 / 8]), np.zeros((1, 2)), ["e0.png", "e1.png"]
    )
    assert resp.to_dict()["white_level"] is None and "white level" not in resp.to_text()
    clipping = replace(resp, white_level=2500)
    assert clipping.to_dict()["white_level"] == 2500 and "12-bit codes, white level 2500:" in clipping.to_text()
    clipped = clipping.apply(dome)
    assert clipped.camera_white_level == 2500 and clipped.to_dict()["camera_white_level"] == 2500
    assert Dome.from_dict(json.loads(json.dumps(clipped.to_dict()))).camera_white_level == 2500
    assert Dome.from_dict(dict(dome.to_dict(), camera_white_level=None)).camera_white_level is None
    for bad in (2048, 4096, 2500.5):
        with pytest.raises(
            FacestatsError, match=rf"camera_white_level must be an integer( in \[2049, 4095\])?, got {bad!r}"
        ):
            replace(dome, camera_white_level=bad)
    with pytest.raises(
        FacestatsError,
        match=r"white_level must be the calibration's camera_white_level \(2500\) when only cameras \[0\] take this "
        r"response \(the cameras share one\), got None: the top code 4095",
    ):
        resp.apply(clipped, cameras=[0])  # the cameras share one white level
    assert replace(resp, white_level=4095).apply(dome, cameras=[0]).camera_white_level == 4095  # None ≡ top code
    assert resp.apply(clipped).camera_white_level is None  # every camera: the new response's
    geometry = _geometry(folder)
    kw = dict(workers=1, min_footprint_px=1)
    a = ingest_photographs(folder, geometry, clipped, tmp_path / "a.zarr", **kw)  # the calibration's 2500
    c = ingest_photographs(folder, geometry, clipped, tmp_path / "c.zarr", white_level=4095, **kw)  # overridden
    ra, rc = (open_ingested(p).array("radiance") for p in (a, c))
    assert not np.array_equal(ra, rc, equal_nan=True)  # the white level changes the merge
    with pytest.raises(FacestatsError, match=r"a\.zarr holds an ingest of other inputs \(white_level differ\)"):
        ingest_photographs(folder, geometry, clipped, a, white_level=3000, **kw)
    assert ingest_photographs(folder, geometry, clipped, a, white_level=2500, **kw) == str(a)  # the same: resumed
    with pytest.raises(FacestatsError, match=r"white_level must be an integer in \[2049, 4095\], got 2048"):
        ingest_photographs(folder, geometry, dome, tmp_path / "d.zarr", white_level=2048, **kw)
    group = zarr.open_group(str(c), mode="r+")  # an ingest begun before the white level was part of the key
    state = json.loads(group.attrs["ingest"])
    del state["fingerprint"]["white_level"]
    group.attrs["ingest"] = json.dumps(state)
    assert ingest_photographs(folder, geometry, clipped, c, white_level=4095, **kw) == str(c)  # the top code
    with pytest.raises(FacestatsError, match=r"\(white_level differ\)"):
        ingest_photographs(folder, geometry, clipped, c, **kw)


def test_the_repr_of_a_photo_capture_is_counts_not_arrays(tmp_path):
    """``print(write_capture_photographs(...))`` dumped the true dome's and the face's arrays (thousands of lines, a
    walkthrough): the repr names the files and gives the rig and the face as counts."""
    from facestats.acquire.dome import default_dome
    from facestats.acquire.synthetic.photographs import PhotoCapture
    from facestats.face.procedural import procedural_face

    dome, face = default_dome().select(leds=np.arange(0, 150, 5)).resized(160, 120), procedural_face(16)
    folder = tmp_path / "photos"
    pc = PhotoCapture(folder / "manifest.json", folder / "dome.json", folder / "face.obj", folder / "face.regions.png",
                      dome, [(4, 7), (11, 3)], face)  # fmt: skip
    text = repr(pc)
    assert "array(" not in text and len(text.replace(str(folder), "F")) < 400, text  # 70 kB before
    assert text.startswith(f"PhotoCapture(folder={str(folder)!r}, calibration={str(folder / 'dome.json')!r}")
    assert "<Dome: 30 LEDs, 16 cameras, 160x120 px>" in text
    mesh = f"mesh of {len(face.mesh_vertices)} vertices and {len(face.mesh_faces)} faces"
    assert f"<FaceGeometry {face.name!r}: {face.n_points} lumitexels, 16x16 maps, {mesh}>" in text
    assert text.endswith("moved_frames=[(4, 7), (11, 3)] (2))")
