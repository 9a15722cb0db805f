"""The web app's findings of an HTTP red team (2026-12-06): each was served wrong or unclear before."""

from __future__ import annotations

import html
import json
import os
import pathlib

import pytest

pytest.importorskip("flask", reason="Flask is not installed (web extra)")


def _client(path, **kw):
    from facestats.web import create_app

    return create_app(path, preload=False, **kw).test_client()


def test_a_subject_rewritten_or_removed_by_another_process_is_not_served_from_the_cache(tmp_path):
    from facestats.io.store import open_store
    from tests.helpers import store_from_default

    path = store_from_default(tmp_path / "s.zarr", ids=("S001", "S002"))
    client = _client(path)
    before = client.get("/api/subject/S001").get_json()["coefficients"]["sigma_a"]["R"]
    with open_store(path, mode="a") as st:  # as another process would (a re-fit, an edit)
        ds = st.subject("S001")
        ds["sigma_a"] = ds["sigma_a"] * 2
        st.write_subject(ds, overwrite=True)
        st.delete_subject("S002")
    after = client.get("/api/subject/S001").get_json()["coefficients"]["sigma_a"]["R"]
    assert after == pytest.approx(2 * before, rel=1e-6)  # the cache served `before` again
    assert client.get("/api/subject/S002").status_code == 404  # and served a removed subject with 200


def test_store_files_that_are_links_out_of_the_store_are_refused(tmp_path):
    from facestats.errors import StoreError
    from facestats.io.index import INDEX_NAME
    from facestats.web import create_app
    from tests.helpers import store_from_default

    path = pathlib.Path(store_from_default(tmp_path / "s.zarr", ids=("S001",)))
    outside = tmp_path / "elsewhere.json"
    os.replace(path / INDEX_NAME, outside)
    os.symlink(outside, path / INDEX_NAME)  # was followed: the app served the index of another folder
    with pytest.raises(StoreError, match=r"index\.json: a symbolic link \(a store's files are never links\)"):
        create_app(path, preload=False)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # numpy's, as a server would print it
def test_pca_of_values_that_overflow_is_strict_json(tmp_path):
    from facestats.io.index import INDEX_NAME
    from tests.helpers import store_from_default

    path = pathlib.Path(store_from_default(tmp_path / "s.zarr", ids=("S001", "S002", "S003")))
    doc = json.loads((path / INDEX_NAME).read_text())
    entry = doc["subjects"]["S001"]["row"]
    key = next(k for k in entry if k.startswith("ts_rho_s") and isinstance(entry[k], float))
    entry[key] = 1.7e308  # finite, so the index accepts it; the pooled moments overflow
    (path / INDEX_NAME).write_text(json.dumps(doc))
    r = _client(str(path)).get("/api/pca")
    assert r.status_code == 200
    text = r.data.decode()
    assert "Infinity" not in text and "NaN" not in text  # a browser's res.json() refused them
    json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))


def test_one_unreadable_subject_spoils_only_the_selections_that_hold_it(tmp_path):
    from facestats.web.data import RegionSamples, pca_document
    from tests.helpers import store_from_default

    path = store_from_default(tmp_path / "s.zarr", ids=("S001", "S002", "S003"))
    gen = next((pathlib.Path(path) / "subjects" / "S002").glob("g*"))
    chunk = next(p for p in (gen / "ts_m").rglob("*") if p.is_file() and p.name != "zarr.json")
    chunk.write_bytes(chunk.read_bytes()[:5])  # a truncated chunk
    from facestats.io.store import open_store

    with open_store(path) as st:
        samples = RegionSamples(st, start=False)
        samples.from_index = False  # a store written before the index held the (ρs, m) covariances
        samples._load()
        assert set(samples.failed) == {"S002"} and samples.error is None
        bad = pca_document(samples, ["S001", "S002"])
        assert bad["status"] == "error" and "['S002']" in bad["error"] and "ts_m" in bad["error"]
        good = pca_document(samples, ["S001", "S003"])  # an error for every selection before
        assert good["status"] == "ok" and good["n_subjects"] == 2


def test_long_path_values_host_headers_405_and_sample_subject_maps(tmp_path):
    from facestats.io.merl import import_merl
    from tests.helpers import merl_dict, save_mat, store_from_default

    client = _client(store_from_default(tmp_path / "s.zarr", ids=("S001",)), allowed_hosts=["localhost"])
    r = client.get("/api/subject/" + "A" * 60000, headers={"Host": "localhost"})
    assert r.status_code == 400 and len(r.get_json()["error"]) < 400  # 60 kB echoed back before
    assert "... (60000 characters)" in r.get_json()["error"]
    r = client.get("/api/query", headers={"Host": "localhost:evil"})
    assert r.status_code == 400 and "unexpected Host header 'localhost:evil'" in r.get_json()["error"]  # '' before
    r = client.get("/subject/S001/exr.zip", headers={"Host": "localhost"})
    assert r.status_code == 200 and int(r.headers["Content-Length"]) == len(r.data) > 0  # no length before
    r = client.post("/api/query", headers={"Host": "localhost"})
    assert r.status_code == 405 and set(r.headers["Allow"].replace(" ", "").split(",")) == {"GET", "HEAD"}
    merl = tmp_path / "merl.zarr"
    import_merl(save_mat(tmp_path, merl_dict()), merl)
    r = _client(str(merl)).get("/subject/merl-001/map/albedo.png")
    assert r.status_code == 400  # "map must be one of [], got 'albedo'" before
    assert "holds region samples, not maps: a map image needs a map subject" in html.unescape(r.data.decode())


def test_the_printed_address_of_an_ipv6_host_is_bracketed(monkeypatch):
    import facestats.web as web

    urls = []

    class _Server:
        server_port = 8123

        def serve_forever(self):
            raise KeyboardInterrupt

        def server_close(self):
            pass

    monkeypatch.setattr(web, "create_app", lambda *a, **k: None)
    monkeypatch.setattr(web, "make_server", lambda *a, **k: _Server())
    with pytest.raises(KeyboardInterrupt):
        web.serve(None, host="::1", port=8123, ready=urls.append)
    assert urls == ["http://[::1]:8123/"]  # http://::1:8123/ before, which no browser opens
