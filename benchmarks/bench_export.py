"""Export and web app speed (issue 18): EXR texture set of a 2048² subject, and the web app's query and page.

Baselines: the EXR set against saving the same maps as raw ``.npy`` files
(``numpy.save``, no compression, headers, manifest or mesh: the I/O floor); the web app's
``/api/query`` against calling ``Store.query(...).to_dict()`` directly (the
CLI's code path), so the ratio is the HTTP/JSON overhead.  Targets: EXR
export of a 2048² subject ≤ 10 s; page load with the default store ≤ 1 s; a
filter change ≤ 200 ms server time.
"""

from __future__ import annotations

import os
import tempfile
import time

import numpy as np


def _subject(size):
    import facestats

    with facestats.open_store() as st:
        ds = st.subject("S001")
    return ds.interp(u=(np.arange(size) + 0.5) / size, v=(np.arange(size) + 0.5) / size, method="nearest")


def bench_exr_set(size=2048, repeat=1):
    """Seconds to write the EXR texture set (maps + mesh + manifest) of a size² subject, against OpenCV."""
    from facestats.io.exr_set import write_exr_set
    from facestats.io.mesh import subject_mesh

    ds = _subject(size)
    mesh = subject_mesh(ds)
    best = best_cv = np.inf
    for _ in range(repeat):
        with tempfile.TemporaryDirectory() as d:
            t = time.perf_counter()
            write_exr_set(ds, d, mesh=mesh)
            best = min(best, time.perf_counter() - t)
        with tempfile.TemporaryDirectory() as d:
            t = time.perf_counter()
            for var in ds.data_vars:
                if tuple(ds[var].dims[:2]) == ("v", "u"):
                    np.save(os.path.join(d, var + ".npy"), np.asarray(ds[var].values))
            best_cv = min(best_cv, time.perf_counter() - t)
    return {"size": size, "facestats_s": best, "npy_maps_only_s": best_cv, "ratio": best / best_cv}


def bench_web_query(n=20):
    """Server time of the population page and of a filter change, against Store.query directly."""
    import facestats
    from facestats.web import create_app

    app = create_app(None, preload=False)
    client = app.test_client()
    t = time.perf_counter()
    client.get("/")
    client.get("/api/query")
    page = time.perf_counter() - t
    filters = ["skin_type=IV", "skin_type=III&gender=F", "age=30s", "condition=normal&region=6"]
    t = time.perf_counter()
    for i in range(n):
        client.get("/api/query?" + filters[i % len(filters)])
    web = (time.perf_counter() - t) / n
    st = facestats.open_store()
    kw = [
        {"skin_type": "IV"},
        {"skin_type": "III", "gender": "F"},
        {"age": "30s"},
        {"condition": "normal", "region": 6},
    ]
    t = time.perf_counter()
    for i in range(n):
        st.query(**kw[i % len(kw)]).to_dict()
    direct = (time.perf_counter() - t) / n
    return {"page_load_s": page, "filter_change_s": web, "store_query_s": direct, "ratio": web / direct}


BENCHMARKS = [("exr_set", bench_exr_set), ("web_query", bench_web_query)]

SMOKE = {"exr_set": {"size": 64}, "web_query": {"n": 2}}

if __name__ == "__main__":
    for name, fn in BENCHMARKS:
        print(name, fn())
