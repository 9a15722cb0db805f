"""Full-disk scenarios, run as a script inside a private mount namespace on a small tmpfs.

``python -m tests.reliability.full_disk TMPFS SOURCE_STORE`` copies the store onto the tmpfs, fills
the rest of the tmpfs, runs each scenario (export, repair, delete, write, edit, a MERL import into the
store and one into an empty folder), frees the space, checks what is left, and prints one JSON line
per scenario:
``{"name", "code", "message", "checks": {check: bool}}``.  The test (``test_faults.py``) runs it with
``unshare -rm`` and asserts on the JSON; the tmpfs vanishes with the namespace.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import sys
from pathlib import Path


def fill(root: Path) -> Path:
    """Fill the file system of ``root`` to the last byte; the filler file."""
    filler = root / "filler"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    try:
        for size in (1 << 16, 1 << 10, 1):  # big blocks, then smaller ones up to the last byte
            try:
                while True:
                    os.write(fd, b"\0" * size)
            except OSError:
                pass
    finally:
        os.close(fd)
    return filler


def cli(*argv):
    from facestats.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main([str(a) for a in argv])
        except SystemExit as exc:
            code = exc.code
    return code, out.getvalue() + err.getvalue()


def digests(path):
    from tests.reliability.helpers import subject_digests

    return subject_digests(path)


def scenario(name, root: Path, source: Path, run, checks, prepare=None):
    store = root / name / "s.zarr"
    shutil.copytree(source, store)
    if prepare is not None:
        prepare(root / name)
    before = digests(store)
    filler = fill(root)
    try:
        code, message = run(store, root / name)
    except Exception as exc:  # an exception that is not a FacestatsError is a failure of the scenario
        code, message = "raised", f"{type(exc).__name__}: {exc}"
    filler.unlink()
    result = {k: bool(v) for k, v in checks(store, root / name, before).items()}
    print(json.dumps({"name": name, "code": code, "message": message[-600:], "checks": result}), flush=True)
    shutil.rmtree(root / name)


def api(call):
    from facestats.errors import FacestatsError

    def run(store, work):
        try:
            call(store)
        except FacestatsError as exc:
            return 2, f"{type(exc).__name__}: {exc}"
        return 0, ""

    return run


def damaged(store):
    gen = next((store / "subjects" / "R2").glob("g*"))
    chunk = gen / "ts_m" / "c" / "0" / "0"
    chunk.write_bytes(chunk.read_bytes()[:7])


def export(store, work):
    return cli("export", "--store", store, "--out", work / "out")


def repair(store, work):
    return cli("validate", "--store", store, "--repair", "--yes")


def edit(store, work):
    return cli("edit", "brdf", "R1", "--target", "R2", "--store", store, "--images", work / "img")


def write(store):
    from facestats.io import open_store
    from tests.helpers import make_map_subject

    with open_store(store, mode="r+") as st:
        st.write_subject(make_map_subject("NEW", size=16))


def delete(store):
    from facestats.io import open_store

    with open_store(store, mode="r+") as st:
        st.delete_subject("R1")


def merl_file(root: Path) -> Path:
    """A valid ``ts_data.mat`` on the disk (written before it is filled)."""
    import scipy.io

    from tests.helpers import merl_dict

    path = root / "ts_data.mat"
    scipy.io.savemat(path, merl_dict())
    return path


def import_merl(store, work):
    return cli("import-merl", work.parent / "ts_data.mat", "--store", store)


def import_new(store, work):
    return cli("import-merl", work.parent / "ts_data.mat", "--store", work / "empty.zarr")


def still_repairable(store, work, before):
    code, _ = cli("validate", "--store", store, "--repair", "--yes")
    after = digests(store)
    kept = list(store.glob("subjects/R2/g*")) or list(store.glob("quarantine/*/subjects/R2/g*"))
    return {
        "repair works once space is back": code == 0,
        "intact subjects kept": all(after.get(k) == v for k, v in before.items() if k != "R2"),
        "damaged data not deleted": bool(kept),
    }


def unchanged(store, work, before):
    return {"data unchanged": digests(store) == before, "store valid": cli("validate", "--store", store)[0] == 0}


def no_export(store, work, before):
    return {**unchanged(store, work, before), "no half-written export": not (work / "out").exists()}


def no_images(store, work, before):
    return {**unchanged(store, work, before), "no images": not (work / "img").exists()}


def no_import(store, work, before):
    return {**unchanged(store, work, before), "no subject folder left": not list(store.glob("subjects/merl-*"))}


def still_empty(store, work, before):
    return {**unchanged(store, work, before), "the empty folder left empty": os.listdir(work / "empty.zarr") == []}


def main(root: Path, source: Path) -> None:
    scenario("export", root, source, export, no_export)
    damaged_source = root / "damaged" / "s.zarr"
    shutil.copytree(source, damaged_source)
    damaged(damaged_source)
    scenario("repair", root, damaged_source, repair, still_repairable)
    shutil.rmtree(root / "damaged")
    scenario("delete", root, source, api(delete), unchanged)
    scenario("write", root, source, api(write), unchanged)
    scenario("edit", root, source, edit, no_images)
    merl_file(root)
    scenario("import", root, source, import_merl, no_import)
    scenario("import-new", root, source, import_new, still_empty, prepare=lambda work: (work / "empty.zarr").mkdir())


if __name__ == "__main__":
    main(Path(sys.argv[1]), Path(sys.argv[2]))
    os._exit(0)
