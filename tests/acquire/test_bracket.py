"""A camera's response from a bracket of photographs on disk: files, EXIF, the result file, the dome."""

import json
import pathlib
import re
from dataclasses import replace

import numpy as np
import pytest

from facestats import FacestatsError
from facestats.acquire.bracket import RESPONSE_FORMAT, calibrate_response, read_bracket, read_response
from facestats.acquire.dome import default_dome
from facestats.acquire.response import ResponseCurve
from facestats.acquire.synthetic.photographs import encode_frame
from facestats.io.exif import read_exposure_time
from facestats.io.png import encode_png

UNIS = pathlib.Path(__file__).resolve().parents[1] / "data" / "unis-bracket"
TIMES = (1 / 500, 1 / 125, 1 / 30, 1 / 8)  # steps of 4, 4.2 and 3.75: not one constant ratio


def _scene(h=96, w=128):
    """Electrons per second over four decades, RGB ratios 1 : 0.8 : 0.6."""
    yy, xx = np.mgrid[0:h, 0:w]
    return np.exp(np.log(2e3) + 9.5 * (xx / w) + 0.4 * np.sin(yy / 9))[..., None] * np.array([1.0, 0.8, 0.6])


@pytest.fixture(scope="module")
def bracket(tmp_path_factory):
    """Four 8-bit PNGs with EXIF exposure times, written by the simulator's frame encoder; the camera."""
    camera = ResponseCurve(bits=8)
    rng = np.random.default_rng(3)
    folder = tmp_path_factory.mktemp("bracket")
    files = []
    for k, t in enumerate(TIMES):
        path = folder / f"frame{k}.png"
        path.write_bytes(encode_frame(camera.encode(_scene() * t, rng), t))
        files.append(path)
    return files, camera


def test_recovers_the_true_curve_from_png_files_and_exif(bracket, tmp_path):
    files, camera = bracket
    res = calibrate_response(files[::-1])  # any order
    np.testing.assert_allclose(res.exposure_times, TIMES[::-1], rtol=1e-6)  # EXIF rationals
    true = camera.log_exposure() - camera.log_exposure()[128]
    z = np.arange(20, 236)
    assert np.abs(res.log_response[z] - true[z, None]).max() < 0.02
    assert res.agreement.shape == (3, 2) and np.all(res.agreement[:, 0] < 0.03)  # shot noise of the frames
    res.save(tmp_path / "g.json")
    d = json.loads((tmp_path / "g.json").read_text())
    assert d["format"] == RESPONSE_FORMAT and d["bits"] == 8 and len(d["frames"]) == 4
    np.testing.assert_array_equal(read_response(tmp_path / "g.json")[1:], res.log_response[1:])
    text = res.to_text()
    assert "1/500 s -> 1/125 s" in text and text.count("%") == 6


def test_the_response_goes_into_a_dome_calibration(bracket):
    res = calibrate_response(bracket[0])
    dome = default_dome()
    every = res.apply(dome)
    assert every.camera_log_response.shape == (16, 256, 3)
    np.testing.assert_array_equal(every.camera_log_response[5], res.log_response)
    two = res.apply(every, cameras=[0, 3])  # a dome with responses: only these cameras change
    np.testing.assert_array_equal(two.camera_log_response[3], res.log_response)
    with pytest.raises(FacestatsError, match=r"no camera responses yet: give every camera \(0-15\), got \[0, 3\]"):
        res.apply(dome, cameras=[0, 3])
    with pytest.raises(FacestatsError, match=r"cameras must be in \[0, 16\), got \[16\]"):
        res.apply(every, cameras=[16])
    twelve = replace(dome, camera_log_response=np.linspace(-5, 2, 4096)[None, :, None].repeat(16, 0).repeat(3, 2))
    with pytest.raises(FacestatsError, match=r"have 4096 levels, this one 256 \(8-bit\)"):
        res.apply(twelve)


def test_the_real_cc0_bracket_through_the_files():
    """tests/data/unis-bracket (README there): EXIF times, and exposures that agree (3.3 %, 3.6 %)."""
    res = calibrate_response(sorted(UNIS.glob("UNIS_EV*.jpg")))
    assert sorted(res.exposure_times) == [0.0008, 0.003125, 0.025]
    assert np.all(res.agreement[:, 0] < 0.05)
    assert np.all(np.diff(res.log_response[1:-1], axis=0) > 0)


def test_bad_brackets_name_the_file_and_the_field(bracket, tmp_path):
    files, camera = bracket
    bare = tmp_path / "no-exif.png"
    bare.write_bytes(encode_png(camera.encode(_scene() * 0.01)))
    with pytest.raises(FacestatsError, match=r"no EXIF ExposureTime in .*no-exif\.png: give the exposure times"):
        read_bracket([files[0], bare])
    images, times, bits = read_bracket([files[0], bare], [0.002, 0.01])  # given times: fine
    assert bits == 8 and times.tolist() == [0.002, 0.01] and images[1].shape == (96, 128, 3)
    small = tmp_path / "small.png"
    small.write_bytes(encode_frame(camera.encode(_scene(48, 64) * 0.01), 0.01))
    with pytest.raises(FacestatsError, match=r"share size and bit depth, got .*frame0\.png: 128×96, 8-bit, .*64×48"):
        read_bracket([files[0], small])
    with pytest.raises(FacestatsError, match="a bracket needs at least two photographs, got 1"):
        calibrate_response(files[:1])
    with pytest.raises(FacestatsError, match=r"one time per photograph \(2\), got 3"):
        read_bracket(files[:2], [0.1, 0.2, 0.3])
    with pytest.raises(FacestatsError, match="at least two distinct exposure times"):
        calibrate_response(files[:2], [0.1, 0.1])
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"format": "something/1"}))
    with pytest.raises(FacestatsError, match=r"other\.json field 'format' must be 'facestats.camera-response/1'"):
        read_response(other)


def test_exposures_that_disagree_are_warned_about(bracket, tmp_path):
    """A bracket whose frames do not follow their times (here the same frame at twice the time) passed with
    exposure agreements of 48-100 % and no word (a user's run on a real bracket: 45-147 %)."""
    import shutil
    import subprocess

    from tests.helpers import facestats_exe

    files, _ = bracket
    assert calibrate_response(files).warnings() == []  # agreements of 2 %
    twin = tmp_path / "twin.png"
    shutil.copy(files[1], twin)
    times = [TIMES[0], TIMES[1], 2 * TIMES[1], TIMES[2], TIMES[3]]
    res = calibrate_response([files[0], files[1], twin, files[2], files[3]], exposure_times=times)
    said = res.warnings()
    assert len(said) == 2 and said[0].startswith("exposures 1/125 s -> 1/62.5 s disagree by a median 100.0% (over 10%")
    argv = [*facestats_exe(), "calibrate", "response", str(files[0]), str(files[1]), str(twin), str(files[2]),
            str(files[3]), "--times", *map(str, times)]  # fmt: skip
    cli = subprocess.run(argv, capture_output=True, text=True)
    assert cli.returncode == 0 and cli.stderr.count("facestats: warning: exposures") == 2, cli.stderr


def test_pixels_in_a_gap_of_the_bracket_are_told_apart_from_saturated_ones_and_kept_within_their_bounds(
    bracket, tmp_path
):
    """Two exposures 4,000× apart: pixels dark in the short one and clipped in the long one were counted as
    "saturated in every exposure" and given the image's largest radiance, hundreds of times their own (a red
    team). They lie between exp(g(1))/Δt_short and exp(g(255))/Δt_long, get the geometric mean of the two and a
    warning naming the exposures; the same pixels merged from the full bracket lie within those bounds."""
    from facestats.acquire.bracket import merge_bracket

    files, camera = bracket
    calibrate_response(files).save(tmp_path / "g.json")
    g = read_response(tmp_path / "g.json")
    full = merge_bracket(files, tmp_path / "g.json").radiance
    rng = np.random.default_rng(5)
    short, long = 1 / 4000, 1.0
    pair = []
    for k, t in enumerate((short, long)):
        pair.append(tmp_path / f"far{k}.png")
        pair[-1].write_bytes(encode_frame(camera.encode(_scene() * t, rng), t))
    merged = merge_bracket(pair, tmp_path / "g.json")
    images, _, _ = read_bracket(pair)
    gap = (images[0] == 0) & (images[1] == 255)
    clipped = images[0] == 255
    assert gap.any(-1).sum() == merged.gap_pixels > 100 and merged.saturated_pixels == clipped.any(-1).sum()
    low, high = (np.broadcast_to(b, gap.shape) for b in (np.exp(g[255]) / long, np.exp(g[1]) / short))
    np.testing.assert_allclose(merged.radiance[gap], np.sqrt(low * high)[gap], rtol=1e-6)
    seen = gap & np.isfinite(full)  # what the full bracket measured there lies within the bounds (noise aside)
    assert seen.sum() > 100 and np.all(full[seen] >= 0.9 * low[seen]) and np.all(full[seen] <= 1.1 * high[seen])
    said = merged.warnings()[0]
    assert f"{merged.gap_pixels} pixel(s) dark in the shorter exposures" in said
    assert "most dark at 1/4000 s and clipped at 1 s" in said and "add exposures between these" in said


def test_a_bracket_is_merged_with_a_saved_response_and_saturation_is_filled(bracket, tmp_path):
    """There was no command to merge a bracket, and the merge's NaN (saturated in every exposure) could not be
    written (a user's run on a real bracket)."""
    import subprocess

    from facestats.acquire.bracket import merge_bracket
    from facestats.acquire.response import merge_photographs
    from facestats.io.images import read_exr, read_image
    from tests.helpers import facestats_exe

    files, camera = bracket
    calibrate_response(files).save(tmp_path / "g.json")
    images, times, _ = read_bracket(files)
    want = merge_photographs(images, times, read_response(tmp_path / "g.json"))
    argv = [*facestats_exe(), "calibrate", "merge", *map(str, files), "--response", str(tmp_path / "g.json"),
            "--out", str(tmp_path / "m.exr")]  # fmt: skip
    cli = subprocess.run(argv, capture_output=True, text=True)
    lost = ~np.isfinite(want)  # the scene's brightest pixels clip even in the shortest exposure
    assert cli.returncode == 0 and f"{lost.any(-1).sum()} pixel(s) saturated in every exposure" in cli.stderr
    got = read_image(tmp_path / "m.exr")
    np.testing.assert_array_equal(got[~lost], want[~lost])  # float32 EXR: the same values
    # the printed ranges are those of what was written, per channel (a mean over channels was printed before:
    # "12.86 to 5893" for a file holding 0.92 to 7214)
    said = re.findall(r"([RGB]) (\S+) to (\S+) \(median (\S+)\)", cli.stdout)
    assert [c for c, *_ in said] == ["R", "G", "B"], cli.stdout
    flat = got.reshape(-1, 3).astype(np.float64)
    printed = np.array([[float(v) for v in vals] for _, *vals in said]).T  # (min, max, median) x channel
    np.testing.assert_allclose(printed, [flat.min(0), flat.max(0), np.median(flat, 0)], rtol=5e-4)
    assert f"overall {flat.min():.4g} to {flat.max():.4g}" in cli.stdout
    top = np.where(lost, -np.inf, want).reshape(-1, 3).max(0)
    bound = np.exp(read_response(tmp_path / "g.json")[255]) / min(TIMES)  # what code 255 at the shortest proves
    np.testing.assert_allclose(got[lost], np.broadcast_to(bound, want.shape)[lost], rtol=1e-6)  # clip: that bound,
    assert np.all(bound >= top)  # which is at least every measured radiance of its channel
    zero = merge_bracket(files, tmp_path / "g.json", saturated="zero")
    assert zero.saturated_pixels == lost.any(-1).sum() > 0 and zero.warnings() == []
    assert np.all(zero.radiance[lost] == 0) and np.isfinite(zero.radiance).all()
    assert json.loads(read_exr(tmp_path / "m.exr")[1]["exposure_times_s"]) == list(TIMES)  # EXIF rationals
    twin = tmp_path / "twin.png"  # frames that do not follow their times: warned about, as by calibrate response
    twin.write_bytes(files[1].read_bytes())
    times = [TIMES[0], TIMES[1], 2 * TIMES[1], TIMES[2], TIMES[3]]
    said = merge_bracket([files[0], files[1], twin, files[2], files[3]], tmp_path / "g.json", times).warnings()
    assert said and said[0].startswith("exposures 1/125 s -> 1/62.5 s disagree by a median")
    deep = json.loads((tmp_path / "g.json").read_text())  # a 12-bit response: 8-bit codes pass its code checks
    deep["log_response"] = [np.interp(np.arange(4096) / 16, np.arange(256), [v if v is not None else -30 for v in ch])
                            .tolist() for ch in deep["log_response"]]  # fmt: skip
    deep["bits"] = 12
    (tmp_path / "g12.json").write_text(json.dumps(deep))
    with pytest.raises(FacestatsError, match=r"the frames hold 8-bit codes, and the response .*g12\.json has 4096"):
        merge_bracket(files, tmp_path / "g12.json")  # silently wrong radiance before (a review)
    argv[-1] = str(files[0])  # an output that is an input: refused before any work
    cli = subprocess.run(argv, capture_output=True, text=True)
    assert cli.returncode == 2 and "--out" in cli.stderr, cli.stderr


def test_times_that_do_not_match_the_frames_give_a_falling_response_which_is_refused(tmp_path):
    """The real CC0 bracket with an auto-bracket's order (0, -2, +2 EV) and its times given ascending: g fell at
    130 of 254 steps, the exposures disagreed by 554 %, and the file was written (a red team); now refused, and a
    dome calibration holding a falling g is refused when loaded."""
    files = [UNIS / "UNIS_EV0.jpg", UNIS / "UNIS_EV-2.jpg", UNIS / "UNIS_EV2.jpg"]
    with pytest.raises(FacestatsError, match=r"must rise with the code .* falls at \d+ of \d+ steps .*\(their order"):
        calibrate_response(files, exposure_times=[0.0008, 0.003125, 0.025])
    good = calibrate_response(files)  # the EXIF times: the same frames give a rising g
    falling = good.log_response.copy()
    falling[100:140] = falling[100:140][::-1]
    with pytest.raises(FacestatsError, match=r"camera_log_response of camera 0 must rise with the code"):
        replace(default_dome(), camera_log_response=np.repeat(falling[None], 16, 0))


def test_a_bracket_that_varies_iso_with_the_time_is_refused(tmp_path):
    """ISO 100/200/400 with 1/100, 1/50, 1/25 s read as time alone gave g at half the truth with a perfect
    agreement (a red team): another ISO, aperture or camera across the EXIF of a bracket is refused."""
    from facestats.io.exif import embed_exif, exif_payload

    camera, rng = ResponseCurve(bits=8), np.random.default_rng(1)
    files = []
    for k, (t, iso) in enumerate([(1 / 100, 100), (1 / 50, 200), (1 / 25, 400)]):
        png = encode_png(camera.encode(_scene() * t * iso / 100, rng))
        files.append(tmp_path / f"f{k}.png")
        files[-1].write_bytes(embed_exif(png, exif_payload(t, f_number=2.8, iso=iso)))
    with pytest.raises(FacestatsError, match=r"vary only the exposure time, got another ISO .*f0.png: 100, f1.png"):
        read_bracket(files)
    _, times, _ = read_bracket(files, [0.01, 0.04, 0.16])  # the user's effective exposures t·ISO/100: not checked
    assert times.tolist() == [0.01, 0.04, 0.16]


def test_a_response_file_that_falls_or_misstates_its_bits_is_refused_by_the_merge(bracket, tmp_path):
    """A hand-edited response whose g falls was merged with only agreement warnings, and a file's 'bits' field
    was never compared with its curve (a red team)."""
    from facestats.acquire.bracket import merge_bracket

    files, _ = bracket
    calibrate_response(files).save(tmp_path / "g.json")
    doc = json.loads((tmp_path / "g.json").read_text())
    falling = dict(doc, log_response=[ch[:1] + ch[1:][::-1] for ch in doc["log_response"]])
    (tmp_path / "falling.json").write_text(json.dumps(falling))
    with pytest.raises(FacestatsError, match=r"falling\.json field 'log_response' must rise with the code"):
        merge_bracket(files, tmp_path / "falling.json")
    (tmp_path / "bits.json").write_text(json.dumps(dict(doc, bits=12)))
    with pytest.raises(FacestatsError, match=r"bits\.json field 'bits' is 12, but its 'log_response' has 256 levels"):
        merge_bracket(files, tmp_path / "bits.json")
    assert merge_bracket(files, tmp_path / "g.json").radiance.shape == (96, 128, 3)


@pytest.mark.parametrize("ext", [".jpeg", ".JPG", ".JPEG"])
def test_every_spelling_of_jpeg_gets_quality_95_and_the_exif_exposure_time(tmp_path, ext):
    """encode_frame embedded EXIF (and set quality 95) for ".jpg" only: ".jpeg" frames had no exposure time."""
    codes = ResponseCurve(bits=8).encode(_scene(48, 64) * 0.01)
    data = encode_frame(codes, 0.01, ext)
    assert data == encode_frame(codes, 0.01, ".jpg")
    path = tmp_path / f"frame{ext}"
    path.write_bytes(data)
    assert read_exposure_time(path) == pytest.approx(0.01)
