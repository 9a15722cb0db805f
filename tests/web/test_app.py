"""The web app's HTTP behaviour through Flask's test client: same JSON as the CLI, safe errors, limits."""

from __future__ import annotations

import io
import json
import os
import zipfile

import numpy as np
import pytest

from facestats.cli import main as cli_main

pytest.importorskip("flask", reason="Flask is not installed (web extra)")


@pytest.fixture(scope="module")
def store_path(tmp_path_factory):
    from tests.helpers import store_from_default

    return store_from_default(tmp_path_factory.mktemp("webapi") / "small.zarr", ids=("S001", "S002", "S003"))


@pytest.fixture(scope="module")
def client(store_path):
    from facestats.web import create_app

    app = create_app(store_path)
    app.config["FACESTATS"]["samples"].wait(60)
    return app.test_client()


def test_query_json_is_the_cli_json(client, store_path, capsys):
    capsys.readouterr()
    assert cli_main(["query", "--store", store_path, "--format", "json", "--gender", "M", "--age", "20-40"]) == 0
    cli = json.loads(capsys.readouterr().out)
    r = client.get("/api/query?gender=M&age=20-40")
    assert r.status_code == 200 and r.get_json() == cli
    assert list(r.get_json()) == list(cli)  # the documented key order
    csv = client.get("/api/query.csv?gender=M&age=20-40")
    assert csv.status_code == 200 and csv.mimetype == "text/csv" and csv.data.decode().startswith("section,")


def test_errors_carry_the_api_text_and_4xx_never_a_traceback(client, store_path, capsys, monkeypatch):
    from facestats.errors import FacestatsError
    from facestats.io import open_store
    from facestats.web.app import error_text

    with open_store(store_path) as st, pytest.raises(FacestatsError) as api:
        st.query(skin_type="VII")
    r = client.get("/api/query?skin_type=VII")
    assert r.status_code == 400 and r.get_json()["error"] == error_text(api.value)
    assert error_text(api.value) == "facestats: error: skin type must be I-VI or 1-6, got 'VII'"
    capsys.readouterr()  # the command line prints the same, naming the option typed
    assert cli_main(["query", "--store", store_path, "--skin-type", "VII"]) == 2
    assert capsys.readouterr().err.strip() == "facestats: error: --skin-type must be I-VI or 1-6, got 'VII'"
    assert client.get("/api/query?evil=1").status_code == 400
    assert client.get("/api/query?age=" + "1" * 40).status_code == 400
    assert client.get("/api/query?gender=M&x=" + "a" * 2000).status_code == 414
    assert client.post("/api/query").status_code == 405
    r = client.get("/api/subject/S999")
    assert r.status_code == 404 and "is not in store" in r.get_json()["error"]
    for bad in ("/subject/..%2F..%2Fetc", "/subject/%2Fetc%2Fpasswd/exr.zip", "/subject/.hidden"):
        r = client.get(bad)
        assert r.status_code in (400, 404) and b"Traceback" not in r.data
    assert client.get("/subject/S001/map/..%2Fzarr.json.png").status_code in (400, 404)
    import facestats.web.data as data

    monkeypatch.setattr(data, "preview_radiance", lambda ds: 1 / 0)
    r = client.get("/subject/S001/preview.png")
    assert r.status_code == 500 and b"ZeroDivisionError" not in r.data and b"internal error" in r.data


def test_host_names_bodies_and_repeated_filters_are_checked(store_path):
    from facestats.errors import ValidationError
    from facestats.web import create_app, make_server

    app = create_app(store_path, preload=False, allowed_hosts=("127.0.0.1", "localhost", "::1"))
    c = app.test_client()
    assert c.get("/api/query", headers={"Host": "localhost:8000"}).status_code == 200
    assert c.get("/api/query", headers={"Host": "[::1]:8000"}).status_code == 200
    r = c.get("/api/query", headers={"Host": "evil.example.com"})  # DNS rebinding: another name for this address
    assert r.status_code == 400 and "unexpected Host header" in r.get_json()["error"]
    r = c.get("/api/query", headers={"Host": "localhost"}, data=b"\0" * 5000)
    assert r.status_code == 413
    r = c.get("/api/query?skin_type=III&skin_type=IV", headers={"Host": "localhost"})
    assert r.status_code == 400 and "filter skin_type must be given once" in r.get_json()["error"]
    for host in ("", " ", "127.0.0.1 "):
        with pytest.raises(ValidationError, match="host must be an address"):
            make_server(app, host, 0)
    with pytest.raises(ValidationError, match="host 'no.such.host.invalid' is not an address of this machine"):
        make_server(app, "no.such.host.invalid", 0)


def test_subject_pages_maps_and_exr_download(client):
    assert client.get("/subject/S002").status_code == 200
    doc = client.get("/api/subject/S002").get_json()
    assert {"albedo", "normal", "ts_m", "modulation"} <= set(doc["maps"])
    png = client.get("/subject/S002/map/albedo.png")
    assert png.status_code == 200 and png.data[:8] == b"\x89PNG\r\n\x1a\n"
    z = zipfile.ZipFile(io.BytesIO(client.get("/subject/S002/exr.zip").data))
    names = set(z.namelist())
    assert {"albedo.exr", "ts_m.exr", "region.exr", "mesh.obj", "manifest.json"} <= names
    assert json.loads(z.read("manifest.json"))["subject"]["subject_id"] == "S002"
    assert all(i.compress_type == zipfile.ZIP_STORED for i in z.infolist())  # EXR files are compressed already
    r = client.get("/subject/S002/exr.zip")
    assert r.headers["Content-Disposition"] == "attachment; filename=S002-exr.zip"


def test_the_gltf_asset_downloads_as_export_subject_writes_it(client, store_path, tmp_path):
    """The subject page offers the glTF 2.0 asset beside the EXR set: the files of ``facestats export-subject
    --format gltf`` (the same code), zipped; the buffer and textures read back as the exporter's."""
    from facestats.io.gltf import read_gltf_summary
    from facestats.io.subject_export import export_subject

    assert 'id="dl-gltf"' in client.get("/subject/S002").data.decode()
    r = client.get("/subject/S002/gltf.zip")
    assert r.status_code == 200 and r.mimetype == "application/zip"
    assert r.headers["Content-Disposition"] == "attachment; filename=S002-gltf.zip"
    assert int(r.headers["Content-Length"]) == len(r.data)
    z = zipfile.ZipFile(io.BytesIO(r.data))
    assert all(i.compress_type == zipfile.ZIP_STORED for i in z.infolist())
    z.extractall(tmp_path / "web")
    export_subject("S002", tmp_path / "cli", "gltf", store=store_path)
    assert sorted(z.namelist()) == sorted(os.listdir(tmp_path / "cli"))
    for name in z.namelist():  # byte for byte the exporter's files
        assert (tmp_path / "web" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
    summary = read_gltf_summary(tmp_path / "web" / "face.gltf")
    assert summary["n_vertices"] > 0 and "skin S002" in z.read("face.gltf").decode()
    head = client.head("/subject/S002/gltf.zip")
    assert head.status_code == 200 and head.data == b"" and "Content-Length" not in head.headers
    assert client.head("/subject/S999/gltf.zip").status_code == 404


def test_map_images_carry_their_scale_in_text_chunks_as_the_edit_images_do(client):
    """Each map PNG says what it shows and on which scale (the ``edit`` PNGs' :data:`SCALE_KEYS`), so the colours
    can be read back as values: the viridis ends are the face's 2nd and 98th percentiles of the map."""
    from PIL import Image

    from facestats.io.png import SCALE_KEYS

    ds = client.application.config["FACESTATS"]["subjects"].get("S002")
    face = np.asarray(ds["region"].values) > 0
    want = {
        "albedo": ("sRGB", 0.0, 1.0, "1"),
        "modulation": ("sRGB", 0.0, 2.0, "1"),
        "normal": ("(n + 1) / 2", -1.0, 1.0, "1"),
        "region": ("tab10", 1.0, 10.0, "1"),
        "ts_error": ("viridis", *np.percentile(np.asarray(ds["ts_error"].values)[face], [2, 98]), "sr-1"),
        "ts_m": ("viridis", *np.percentile(np.asarray(ds["ts_m"].values)[face], [2, 98]), "1"),
    }
    for name, (cmap, lo, hi, units) in want.items():
        png = Image.open(io.BytesIO(client.get(f"/subject/S002/map/{name}.png").data))
        text = png.text
        assert set(SCALE_KEYS) <= set(text), name
        assert (text["facestats:variable"], text["facestats:colormap"], text["facestats:units"]) == (name, cmap, units)
        np.testing.assert_allclose([float(text["facestats:vmin"]), float(text["facestats:vmax"])], [lo, hi], rtol=1e-12)
        assert text["facestats:texel_pixels"] == "4" and png.size == (4 * 48, 4 * 48)  # a 48² map shown 4×
        assert text["facestats:subject_id"] == "S002" and text["facestats:texel_step"] == "1"
        assert text["Description"].startswith(f"{name} (") and "black outside the face" in text["Description"]
    # a texel's colour reads back as its value: viridis at (value − lo) / (hi − lo)
    from matplotlib import colormaps

    png = np.asarray(Image.open(io.BytesIO(client.get("/subject/S002/map/ts_m.png").data)).convert("RGB"))
    v, u = np.argwhere(face)[len(np.argwhere(face)) // 2]
    _, lo, hi, _ = want["ts_m"]
    value = float(ds["ts_m"].values[v, u])
    expected = np.round(255 * np.asarray(colormaps["viridis"](np.clip((value - lo) / (hi - lo), 0, 1))[:3]))
    np.testing.assert_allclose(png[4 * v + 1, 4 * u + 1], expected, atol=1)


def test_head_of_the_exr_set_answers_without_building_it(client, monkeypatch):
    """HEAD ran the GET view whole: seconds of CPU and a temporary copy for a download manager's probe."""
    import sys

    import facestats.io.exr_set

    def refuse(*args, **kwargs):
        raise AssertionError("HEAD built the EXR set")

    monkeypatch.setattr(facestats.io.exr_set, "write_exr_set", refuse)
    r = client.head("/subject/S002/exr.zip")
    assert r.status_code == 200 and r.data == b"" and "Content-Length" not in r.headers
    assert r.headers["Content-Disposition"] == "attachment; filename=S002-exr.zip"
    assert r.mimetype == "application/zip"
    assert client.head("/subject/S999/exr.zip").status_code == 404  # the same checks as a GET
    monkeypatch.setitem(sys.modules, "OpenEXR", None)
    assert client.head("/subject/S002/exr.zip").status_code == 424


def _png_size(data):
    """(width, height) from a PNG's IHDR chunk."""
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def test_heavy_requests_are_bounded_and_images_enlarged_only_up_to_a_limit(client):
    from facestats.web.app import MAX_HEAVY
    from facestats.web.data import MAX_IMAGE_SIDE, map_png

    ctx = client.application.config["FACESTATS"]
    heavy = ctx["heavy"]
    for _ in range(MAX_HEAVY):  # as if MAX_HEAVY exports were running
        assert heavy.acquire(blocking=False)
    ctx["heavy_wait"], wait = 0.2, ctx["heavy_wait"]  # a short turn to wait for, then 503
    try:
        for url in ("/subject/S002/map/albedo.png", "/subject/S002/preview.png", "/subject/S002/exr.zip"):
            r = client.get(url)
            assert r.status_code == 503 and b"image or export requests are running; try again" in r.data
        assert client.get("/api/query").status_code == 200  # the statistics still answer
    finally:
        ctx["heavy_wait"] = wait
        for _ in range(MAX_HEAVY):
            heavy.release()
    small = client.get("/subject/S002/map/albedo.png")
    assert small.status_code == 200 and _png_size(small.data) == (4 * 48, 4 * 48)  # a 48² map shown 4×
    ds = client.application.config["FACESTATS"]["subjects"].get("S002")
    big = ds[["albedo", "region"]].isel(u=np.arange(48).repeat(12), v=np.arange(48).repeat(12))  # 576²
    assert _png_size(map_png(big, "albedo")) == (576, 576)  # 4× would be 2304 > MAX_IMAGE_SIDE: not enlarged
    assert MAX_IMAGE_SIDE // 576 == 1


def test_pca_and_scatter_documents(client):
    pca = client.get("/api/pca?skin_type=IV").get_json()
    assert pca["status"] == "ok" and len(pca["regions"]) == 10
    for r in pca["regions"]:
        assert r["half_axes"][0] >= r["half_axes"][1] > 0 and abs(r["axis"][0] ** 2 + r["axis"][1] ** 2 - 1) < 1e-9
    q = client.get("/api/query?skin_type=IV").get_json()
    sc = client.get("/api/scatter?skin_type=IV").get_json()
    assert len(sc["points"]) == 3 * q["count"]
    by_ch = {p["channel"]: p["sigma_a"] for p in sc["points"] if p["subject_id"] == q["subject_ids"][0]}
    assert by_ch["B"] > by_ch["R"]  # blue is absorbed most (Fig. 14)


def test_a_store_that_cannot_be_opened_is_a_cli_error(tmp_path, capsys):
    from facestats.web import create_app

    bad = tmp_path / "not-a-store"
    bad.mkdir()
    with pytest.raises(Exception, match="is not a facestats store"):
        create_app(bad)
    assert cli_main(["serve", "--store", str(bad), "--port", "0"]) == 2
    assert "facestats: error: store" in capsys.readouterr().err


def test_missing_openexr_is_424_with_the_install_hint(client, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # import OpenEXR now raises ImportError
    r = client.get("/subject/S002/exr.zip")
    assert r.status_code == 424  # an HTML page (not under /api/) with the API's text, as the CLI prints it
    assert b"facestats: error: the OpenEXR package is not installed" in r.data and b"pip install OpenEXR" in r.data
    assert b"Traceback" not in r.data
    assert client.get("/subject/S002/map/albedo.png").status_code == 200  # the rest of the app works


def test_a_damaged_map_is_409_and_the_others_still_serve(tmp_path):
    import pathlib

    from facestats.web import create_app
    from tests.helpers import store_from_default

    path = store_from_default(tmp_path / "damaged.zarr", ids=("S001", "S002"))
    gen = next((pathlib.Path(path) / "subjects" / "S002").glob("g*"))
    (gen / "albedo" / "c" / "0" / "0" / "0").unlink()  # a lost chunk
    client = create_app(path, preload=False).test_client()
    # Subjects are opened lazily (an eager read held every map of 8 cached subjects): each map is verified as it
    # is read, so the damaged map is a 409 with the store's message, and the subject's other maps still serve.
    assert client.get("/api/subject/S002").status_code == 200  # attributes and names only
    r = client.get("/subject/S002/map/albedo.png")
    assert r.status_code == 409 and b"variable &#39;albedo&#39; does not match its checksum" in r.data, r.data[-600:]
    assert b"Traceback" not in r.data
    assert client.get("/subject/S002/preview.png").status_code == 409  # the preview reads the albedo too
    assert client.get("/subject/S002/map/ts_m.png").status_code == 200
    assert client.get("/api/subject/S001").status_code == 200


def test_edited_subjects_are_left_out_unless_asked_for_as_in_the_cli(tmp_path, capsys):
    from facestats.web import create_app
    from tests.helpers import store_from_default

    path = store_from_default(tmp_path / "edits.zarr", ids=("S001", "S006"))  # S006: skin type V
    assert cli_main(["edit", "skin-type", "S001", "V", "--store", path, "--images", str(tmp_path / "img")]) == 0
    client = create_app(path, preload=False).test_client()
    capsys.readouterr()
    for value, flag in (("", []), ("include", ["--edits"]), ("1", ["--edits"]), ("no", [])):
        doc = client.get(f"/api/query?edits={value}").get_json()
        assert cli_main(["query", "--store", path, "--format", "json", *flag]) == 0
        assert doc == json.loads(capsys.readouterr().out)
        assert doc["count"] == (3 if flag else 2)
    r = client.get("/api/query?edits=maybe")
    assert r.status_code == 400 and "filter edits must be one of ['0', '1', 'false', 'include'" in r.get_json()["error"]


def test_images_of_large_maps_are_strided_to_the_image_size(tmp_path):
    """A 1,030² subject: its map images are 515 pixels a side (every 2nd texel: at most MAX_IMAGE_SIDE = 1024),
    its preview 344 texels a side (every 3rd: PREVIEW_SIDE = 512, then enlarged twice to 688 pixels), and both
    equal the images of the strided subject itself.
    At full size a 2048² preview took 5.2 s and 1.4 GB (the speed red team)."""
    import cv2

    from facestats.io import open_store
    from facestats.web import create_app
    from facestats.web.data import map_png, preview_png
    from tests.helpers import make_map_subject

    path = tmp_path / "big.zarr"
    ds = make_map_subject("B1", size=1030, seed=3)
    with open_store(path, mode="a") as st:
        st.write_subject(ds)
    client = create_app(path, preload=False).test_client()
    for url, side, strided, make in (
        ("/subject/B1/map/ts_m.png", 515, ds.isel(v=slice(None, None, 2), u=slice(None, None, 2)), map_png),
        ("/subject/B1/preview.png", 688, ds.isel(v=slice(None, None, 3), u=slice(None, None, 3)), preview_png),
    ):
        r = client.get(url)
        assert r.status_code == 200
        img = cv2.imdecode(np.frombuffer(r.data, np.uint8), cv2.IMREAD_COLOR)
        assert img.shape == (side, side, 3)
        args = (strided, "ts_m") if make is map_png else (strided,)
        ref = cv2.imdecode(np.frombuffer(make(*args), np.uint8), cv2.IMREAD_COLOR)
        np.testing.assert_array_equal(img, ref)


def test_a_subject_replaced_while_a_request_reads_it_is_read_again(tmp_path):
    """Subjects are read lazily: a writer that replaces one while a request reads it removes the files the request
    was about to read, which read as a damaged chunk.  The request reads the new generation instead of answering a
    false 409 (the review of 2026-12-07); a subject damaged at its current generation still fails."""
    from facestats.errors import StoreError
    from facestats.io import open_store
    from facestats.web import create_app
    from facestats.web.data import map_png
    from tests.helpers import make_map_subject

    path = tmp_path / "s.zarr"
    with open_store(path, mode="a") as st:
        st.write_subject(make_map_subject("B1", size=32, seed=3))
    cache = create_app(path, preload=False).config["FACESTATS"]["subjects"]
    seen = []

    def work(ds):  # a request: its subject is replaced after it opened it, before it reads the maps
        if not seen:
            with open_store(path, mode="a") as w:
                w.write_subject(make_map_subject("B1", size=32, seed=4), overwrite=True)
        seen.append(ds)
        return map_png(ds, "albedo")

    png = cache.read("B1", work)
    assert len(seen) == 2 and seen[0] is not seen[1] and png[:4] == b"\x89PNG"
    with open_store(path) as st:
        gen = path / "subjects" / "B1" / st.index_entries()["B1"]["generation"]
    (gen / "albedo" / "c" / "0" / "0" / "0").unlink()  # damaged where it is
    with pytest.raises(StoreError, match="albedo"):
        cache.read("B1", lambda ds: map_png(ds, "albedo"))
