"""Subjects that hold region samples (``facestats import-merl``) in the web app: no preview, maps or EXR set, 4xx."""

from __future__ import annotations

import html

import pytest

pytest.importorskip("flask", reason="Flask is not installed (web extra)")

MESSAGE = "facestats: error: subject 'merl-001' holds region samples, not maps: {} needs a map subject"


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    from facestats.io.merl import import_merl
    from facestats.io.store import open_store
    from facestats.web import create_app
    from tests.helpers import merl_dict, save_mat

    tmp = tmp_path_factory.mktemp("webmerl")
    store = tmp / "merl.zarr"
    import_merl(save_mat(tmp, merl_dict()), store)
    with open_store(None) as src, open_store(store, mode="a") as dst:
        dst.write_subject(src.subject("S001"))  # one map subject beside the samples
    app = create_app(store, preload=False)
    return app.test_client()


def test_sample_subject_page_has_no_preview_maps_or_exr_link(client):
    page = client.get("/subject/merl-001")
    assert page.status_code == 200
    text = page.data.decode()
    assert 'id="preview"' not in text and 'id="dl-exr"' not in text and "/exr.zip" not in text
    assert 'id="dl-gltf"' not in text and "/gltf.zip" not in text
    assert 'id="samples-note"' in text and "holds region samples" in text
    doc = client.get("/api/subject/merl-001").get_json()
    assert doc["kind"] == "samples" and doc["maps"] == []
    maps_page = client.get("/subject/S001").data.decode()  # a map subject keeps them
    assert 'id="preview"' in maps_page and 'id="dl-exr"' in maps_page and 'id="samples-note"' not in maps_page
    assert 'id="dl-gltf"' in maps_page
    assert client.get("/api/subject/S001").get_json()["kind"] == "maps"


@pytest.mark.parametrize(
    "path, what",
    [("preview.png", "the relit preview"), ("exr.zip", "an EXR texture set"), ("gltf.zip", "a glTF asset")],
)  # fmt: skip
def test_sample_subject_preview_and_exr_set_are_400_with_a_message(client, path, what):
    r = client.get(f"/subject/merl-001/{path}")
    assert r.status_code == 400
    assert MESSAGE.format(what) in html.unescape(r.data.decode())
    assert client.get(f"/subject/S001/{path}").status_code == 200
    assert client.head(f"/subject/merl-001/{path}").status_code == 400
