"""Issue 16 item 4 end to end: the simulator writes a capture as photographs; ``facestats ingest`` fits it.

The default subject S001 at a small size (16² lumitexel grid, 160² 12-bit PNG frames, 16 cameras, every fifth LED,
calibration with small errors, two frames with head motion), against its truth and against the in-memory path on the
same subject and rig.  The full-size run (48² grid, 1024² frames, all 150 LEDs) is ``benchmarks/bench_photos.py``
(``ingest``); its figures are in ``docs/photographs.md``.  Each test runs the console script; the refusals and
repeats after its first run call :func:`facestats.cli.main` in the test's process (:func:`tests.helpers.run_main`).
"""

import json
import shutil

import numpy as np
import pytest

from benchmarks.inputs import fit_errors
from facestats.acquire.dome import Dome
from tests.helpers import run_cli, run_main

pytestmark = pytest.mark.slow  # end to end: a whole subject through the pipeline

MOVED = [(4, 7), (11, 3)]


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    from facestats.acquire.dome import default_dome
    from facestats.acquire.synthetic.photographs import write_capture_photographs
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.acquire.synthetic.simulate import DomeSimulator
    from facestats.face.procedural import procedural_face
    from facestats.pipeline import fit_subject

    truth = synthesize_population(map_size=16, geometry=procedural_face(16), subjects=["S001"])["S001"]
    dome = default_dome().select(leds=np.arange(0, 150, 5)).resized(160, 160)
    root = tmp_path_factory.mktemp("e2e")
    pc = write_capture_photographs(truth, root / "photos", geometry=procedural_face(16), dome=dome, moved_frames=MOVED)
    memory = fit_subject(DomeSimulator(pc.geometry, dome).simulate(truth))
    return root, pc, truth, memory


@pytest.mark.slow
def test_ingest_command_fits_the_photographed_subject(case):
    from facestats.io import open_store

    root, pc, truth, memory = case
    folder = pc.folder.parent
    args = ["ingest", folder, "--mesh", pc.mesh, "--calibration", pc.calibration, "--store", root / "s.zarr"]
    args += ["--subject", "S001"]
    r = run_cli(*args)
    assert r.returncode == 0, r.stderr
    assert "ingested S001" in r.stdout and "frames flagged for head motion: 2" in r.stdout
    assert "ingest photos" in r.stderr  # the progress bar
    with open_store(root / "s.zarr") as st:
        ds = st.subject("S001")
    prov = json.loads(ds.attrs["provenance"])["capture_provenance"]
    assert sorted((f["camera"], f["led"]) for f in prov["motion_flags"]) == MOVED  # exactly the moved frames
    photo, mem = fit_errors(ds, truth), fit_errors(memory, truth)
    for name in ("albedo", "ts_rho_s", "ts_m"):
        assert photo[name][0] <= 0.03, (name, photo[name])  # issue 16: median relative error ≤ 3 %
        assert photo[name][1] <= 0.08, (name, photo[name])  # p90 (measured 3.2 %, 2.9 %, 2.2 % at cf69114)
        # the in-memory path on the same subject: measured ratios 1.82, 1.15, 1.23 at this size (cf69114, 2026-12-07)
        assert photo[name][0] <= 2.0 * mem[name][0], (name, photo[name], mem[name])
    again = run_main(*args)
    assert again.returncode == 0 and "already in" in again.stdout
    # The finished work capture is S001's: it never becomes another subject's.
    work = root / "s.zarr.ingest" / "S001" / "capture.zarr"
    other = ["ingest", folder, "--mesh", pc.mesh, "--calibration", pc.calibration, "--store", root / "t.zarr"]
    r = run_main(*other, "--subject", "S002", "--work", work, "--quiet")
    assert r.returncode == 2 and "holds an ingest of other inputs (subject_id differ)" in r.stderr
    assert not (root / "t.zarr").exists()


def test_ingest_never_writes_over_a_folder_that_is_not_its_capture(case, tmp_path):
    _, pc, _, _ = case
    photos = tmp_path / "photos"
    shutil.copytree(pc.folder.parent, photos)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "important.txt").write_text("keep")
    n_files = sum(1 for _ in photos.rglob("*"))
    for work in (tmp_path / "mine", photos):  # a folder of the user's, the photographs themselves
        r = run_cli("ingest", photos, "--mesh", photos / "face.obj", "--calibration", photos / "dome.json",
                    "--store", tmp_path / "s.zarr", "--subject", "S001", "--work", work, "--quiet")  # fmt: skip
        assert r.returncode == 2 and "is not empty and holds no ingest" in r.stderr, r.stderr
    assert (tmp_path / "mine" / "important.txt").read_text() == "keep"
    assert sum(1 for _ in photos.rglob("*")) == n_files and not (tmp_path / "s.zarr").exists()
    man = json.loads((photos / "manifest.json").read_text())
    man["subject"]["age"] = "old"
    (photos / "manifest.json").write_text(json.dumps(man))
    r = run_main("ingest", photos, "--mesh", photos / "face.obj", "--calibration", photos / "dome.json",
                 "--store", tmp_path / "s.zarr", "--subject", "S001", "--quiet")  # fmt: skip
    assert r.returncode == 2 and "manifest.json field 'subject': attribute age must be an integer" in r.stderr
    assert not (tmp_path / "s.zarr").exists()


def test_ingest_command_reports_bad_input_without_a_traceback(case, tmp_path):
    _, pc, _, _ = case
    bad = tmp_path / "photos"
    shutil.copytree(pc.folder.parent, bad)
    (bad / "cam05" / "led003_e1.png").unlink()
    store = tmp_path / "s.zarr"

    def ingest(calibration, run=run_cli):
        args = ["ingest", bad, "--mesh", bad / "face.obj", "--calibration", calibration, "--store", store]
        return run(*args, "--subject", "S001", "--quiet")

    r = ingest(bad / "dome.json")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "frame cam05/led003_e1.png listed in manifest.json is missing" in r.stderr
    assert not any((tmp_path / "s.zarr.ingest").rglob("zarr.json"))  # nothing was started
    # A calibration of another rig: the error names its file.
    (bad / "cam05" / "led003_e1.png").write_bytes((pc.folder.parent / "cam05" / "led003_e1.png").read_bytes())
    Dome.load(bad / "dome.json").select(cameras=[0, 1]).save(bad / "two.json")
    r = ingest(bad / "two.json", run=run_main)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "two.json has 2 cameras" in r.stderr, r.stderr


def test_a_failed_ingest_empties_the_work_folder_it_was_given_and_links_out_are_refused(case, tmp_path):
    """A red team: with --work an existing empty folder, a corrupt frame in the last camera left the 15 cameras
    already ingested in it; a frame that is a symbolic link out of the photo folder was read."""
    import hashlib
    import os

    _, pc, _, _ = case
    photos = tmp_path / "photos"
    shutil.copytree(pc.folder.parent, photos)
    man = json.loads((photos / "manifest.json").read_text())
    last = max(man["frames"], key=lambda f: f["camera"])
    frame = photos / last["file"]
    data = frame.read_bytes()[:200]  # truncated: undecodable, with the manifest's checksum made to match
    frame.write_bytes(data)
    last["sha256"] = hashlib.sha256(data).hexdigest()
    (photos / "manifest.json").write_text(json.dumps(man))
    work = tmp_path / "work"
    work.mkdir()
    args = ["--mesh", photos / "face.obj", "--calibration", photos / "dome.json", "--subject", "S001", "--quiet"]
    r = run_cli("ingest", photos, *args, "--store", tmp_path / "s.zarr", "--work", work)
    assert r.returncode == 2 and f"frame {last['file']} cannot be decoded" in r.stderr, r.stderr
    assert work.is_dir() and os.listdir(work) == [] and not (tmp_path / "s.zarr").exists()

    outside = tmp_path / "elsewhere.png"
    first = photos / man["frames"][0]["file"]
    shutil.copyfile(first, outside)  # the same bytes: the checksum alone cannot tell
    first.unlink()
    first.symlink_to(outside)
    r = run_main("ingest", photos, *args, "--store", tmp_path / "t.zarr")
    assert r.returncode == 2 and f"frame {man['frames'][0]['file']} listed in manifest.json must lie inside" in r.stderr


def test_16_bit_tiff_frames_hold_the_png_codes_and_ingest(case, tmp_path):
    """The same capture written as 16-bit TIFF: an independent reader (tifffile) sees the PNG frames' codes
    exactly, and ``facestats ingest`` fits the TIFF folder within the issue's 3 % median error."""
    import cv2
    import tifffile

    from facestats.acquire.dome import default_dome
    from facestats.acquire.synthetic.photographs import write_capture_photographs
    from facestats.face.procedural import procedural_face
    from facestats.io import open_store

    _, pc, truth, _ = case
    dome = default_dome().select(leds=np.arange(0, 150, 5)).resized(160, 160)
    tif = write_capture_photographs(
        truth, tmp_path / "photos", geometry=procedural_face(16), dome=dome, moved_frames=MOVED, extension=".tif"
    )
    manifest = json.loads((tif.folder.parent / "manifest.json").read_text())
    frames = manifest["frames"]
    assert frames and all(f["file"].endswith(".tif") for f in frames)
    for f in frames[:: max(1, len(frames) // 40)]:  # 40 frames spread over cameras, LEDs and exposures
        codes = tifffile.imread(tif.folder.parent / f["file"])
        png = cv2.imread(str(pc.folder.parent / f["file"].replace(".tif", ".png")), cv2.IMREAD_UNCHANGED)
        assert codes.dtype == np.uint16 and 0 < codes.max() < 4096  # 12-bit codes in 16-bit samples
        np.testing.assert_array_equal(codes, png[..., ::-1], err_msg=f["file"])  # OpenCV reads BGR
    args = ["ingest", tif.folder.parent, "--mesh", tif.mesh, "--calibration", tif.calibration]
    r = run_cli(*args, "--store", tmp_path / "s.zarr", "--subject", "S001", "--quiet")
    assert r.returncode == 0, r.stderr
    with open_store(tmp_path / "s.zarr") as st:
        errors = fit_errors(st.subject("S001"), truth)
    for name, (median, p90) in errors.items():
        assert median <= 0.03 and p90 <= 0.08, (name, median, p90)
