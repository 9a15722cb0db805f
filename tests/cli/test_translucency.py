"""``facestats translucency``: a pyramid rendered to an OpenEXR image, estimated from the files."""

import json
import re

import numpy as np
import pytest

from facestats.acquire.lights import save_lights
from facestats.acquire.scene import write_radiance_image
from facestats.acquire.synthetic.patch_image import render_patch_image
from facestats.acquire.synthetic.scenes import pyramid_scene, square_pyramid
from facestats.model.irradiance import radiance_from_exitance
from facestats.pipeline.suzuki_studies import render_scene
from tests.helpers import run_cli


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory):
    import trimesh

    d = tmp_path_factory.mktemp("translucency")
    scene = pyramid_scene(2.5, "edge", image_size=300)
    r = render_scene(scene)
    p = r.patches
    to_cam = scene.camera.position - p.centre
    cos = np.clip(np.einsum("mk,mk->m", p.normal, to_cam) / np.linalg.norm(to_cam, axis=1), 0, 1)
    lo = radiance_from_exitance(np.repeat(r.exitance[:, None], 3, 1), cos, 1.3)
    write_radiance_image(d / "pyramid.exr", render_patch_image(scene.camera, p, lo))
    v, f = square_pyramid(50, 25)
    trimesh.Trimesh(v, f[:4], process=False).export(d / "pyramid.obj")  # the four faces the scene patches
    save_lights(d / "lights.json", scene.lights, eta=1.3)
    scene.camera.save(d / "camera.json")
    return d


def test_cli_prints_the_estimate_interval_and_rank_and_plots(scene_files):
    d = scene_files
    plot, out = d / "fig5.png", d / "fit.json"
    r = run_cli(
        "translucency",
        d / "pyramid.obj",
        "--lights",
        d / "lights.json",
        "--camera",
        d / "camera.json",
        "--image",
        d / "pyramid.exr",
        "--spacing",
        "2.5",
        "--plot",
        plot,
        "--json",
        out,
    )
    assert r.returncode == 0, r.stderr
    line = next(x for x in r.stdout.splitlines() if x.startswith("R:"))
    s, a = (float(x) for x in re.findall(r"sigma_s' = ([\d.]+).*sigma_a = ([\d.]+)", line)[0])
    assert abs(s - 2.19) <= 0.05 and abs(a - 0.0021) <= 0.0003
    assert "rank" in r.stdout and "condition" in r.stdout and "width" in r.stdout
    fits = json.loads(out.read_text())
    assert set(fits) == {"R", "G", "B"} and fits["R"]["rank"] <= fits["R"]["n_levels"]
    assert plot.exists() and plot.stat().st_size > 10_000


def test_cli_rejects_a_missing_image_and_a_bad_width(scene_files, capsys):
    from facestats.cli import main

    d = scene_files
    base = ["translucency", str(d / "pyramid.obj"), "--lights", str(d / "lights.json")]
    base += ["--camera", str(d / "camera.json")]
    assert main(base + ["--image", str(d / "missing.exr")]) == 2
    assert "image must name an existing file" in capsys.readouterr().err
    out, plot = d / "failed.json", d / "failed.png"
    assert (
        main(base + ["--image", str(d / "pyramid.exr"), "--width", "-1", "--json", str(out), "--plot", str(plot)]) == 2
    )
    assert "width must lie in" in capsys.readouterr().err
    assert not out.exists() and not plot.exists()  # a failed command writes nothing


def test_bad_inputs_are_named_by_file_and_field_before_the_fit(scene_files, tmp_path):
    d = scene_files
    cam = json.loads((d / "camera.json").read_text())
    lights = json.loads((d / "lights.json").read_text())
    cases = [
        ("camera", dict(cam, matrix=[[0, 0, 150], [0, 0, 150], [0, 0, 1]]), "matrix must be pinhole intrinsics"),
        ("camera", dict(cam, rotation=[[-1, 0, 0], [0, -1, 0], [0, 0, -1]]), r"proper rotation \(det R = \+1\)"),
        ("camera", dict(cam, image_size=[300.9, 300.2]), "image_size must be .* whole pixels"),
        ("camera", [], "camera description must be a JSON object, got list"),
        ("lights", {"lights": ["x"]}, "is malformed"),
        ("lights", dict(lights, eta="abc"), "eta must be numeric"),
        ("lights", dict(lights, eta=0.5), r"eta must lie in \[1, 3\], got 0.5"),
    ]
    for kind, doc, message in cases:
        path = tmp_path / f"{kind}.json"
        path.write_text(json.dumps(doc))
        files = {"camera": d / "camera.json", "lights": d / "lights.json", kind: path}
        r = run_cli("translucency", d / "pyramid.obj", "--lights", files["lights"], "--camera", files["camera"],
                    "--image", d / "pyramid.exr", "--spacing", "2.5")  # fmt: skip
        assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
        assert re.search(f"{kind if kind == 'camera' else 'light description'}.*{kind}.json: ", r.stderr) or (
            "is malformed" in message and f"{kind}.json is malformed" in r.stderr
        ), r.stderr
        assert re.search(message, r.stderr), r.stderr
    base = ["translucency", d / "pyramid.obj", "--lights", d / "lights.json", "--camera", d / "camera.json",
            "--image", d / "pyramid.exr", "--spacing", "2.5"]  # fmt: skip
    r = run_cli(*base, "--eta", "0.5")
    assert r.returncode == 2 and "--eta must lie in [1, 3], got 0.5" in r.stderr
    r = run_cli(*base, "--json", tmp_path / "o.json", "--plot", tmp_path / "f.xyz")
    assert r.returncode == 2 and "--plot must end in one of" in r.stderr and not (tmp_path / "o.json").exists()


def test_quantisation_warnings_are_held_back_as_notes(capsys, recwarn):
    """The fits' notes repeat their quantisation warnings: the command prints notes, not Python warnings; a failed
    fit's warnings go to stderr before its error; other warnings pass on."""
    import warnings

    from facestats.cli.translucency import _with_notes
    from facestats.errors import FitError, QuantisationWarning

    def fit(fail):
        warnings.warn("levels 3 and 4 merged", QuantisationWarning)
        warnings.warn("something else", UserWarning)
        if fail:
            raise FitError("only 2 supported levels remain")
        return "fits"

    assert _with_notes(fit, False) == "fits"
    assert [str(w.message) for w in recwarn] == ["something else"] and capsys.readouterr().err == ""
    with pytest.raises(FitError, match="only 2"):
        _with_notes(fit, fail=True)
    assert capsys.readouterr().err == "note: levels 3 and 4 merged\n"
