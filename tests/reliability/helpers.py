"""Shared pieces of the reliability suite: a small store, the sentinel tree, in-process CLI runs, intact-data checks.

* :func:`make_store` writes a small store (two map subjects, one sample subject) once per test module;
  :func:`copy_store` gives each case its own copy.
* A **sentinel tree** (:func:`make_sentinel`) is planted beside every store: files, folders and a
  folder named like a generation.  Cases that plant links point them into it; :func:`snapshot` of it
  before and after a case must be equal (nothing outside the store touched).
* :func:`run` runs ``facestats.cli.main`` in this process (fast; :func:`tests.helpers.run_main`) and returns
  (exit code, stdout + stderr); an exception escaping ``main`` fails the test — that is a traceback.  The CLI's
  last-resort handler returns 3 for unexpected exceptions, which every case also rejects.
* :func:`subject_digests` reads every subject fully (checksums verified) and returns a digest of its
  data, so "no intact data lost" is a comparison of two dicts.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import stat
from pathlib import Path

import numpy as np

from facestats.errors import StoreError
from facestats.io import open_store
from tests.helpers import make_map_subject, make_sample_subject, run_main

MAP_IDS = ("R1", "R2")
SAMPLE_IDS = ("RM",)


def subjects():
    """The subjects of the small store."""
    out = [make_map_subject(sid, size=16, seed=k, skin_type=3 + k) for k, sid in enumerate(MAP_IDS)]
    out.append(make_sample_subject("RM", n_per_region=4))
    return out


def make_store(path: Path) -> Path:
    with open_store(path, mode="a") as st:
        st.write_subjects(subjects())
    return path


def copy_store(src: Path, dst_dir: Path) -> Path:
    """A copy of the store ``src`` as ``dst_dir/s.zarr`` with a sentinel tree beside it."""
    dst = dst_dir / "s.zarr"
    shutil.copytree(src, dst, symlinks=True)
    make_sentinel(dst_dir / "sentinel")
    return dst


def make_sentinel(path: Path) -> Path:
    """A tree the store must never touch: files, folders, a folder named like a generation."""
    (path / "g0000000000000001-1-aaaaaa" / "c").mkdir(parents=True, exist_ok=True)
    (path / "g0000000000000001-1-aaaaaa" / "zarr.json").write_text("{}")
    (path / "g0000000000000001-1-aaaaaa" / "c" / "0").write_bytes(b"\x01" * 64)
    (path / "notes.txt").write_text("not facestats'")
    (path / "index.json").write_text('{"format": 1, "subjects": {}}')
    (path / "deep" / "er").mkdir(parents=True, exist_ok=True)
    (path / "deep" / "er" / "file.bin").write_bytes(os.urandom(32))
    return path


def snapshot(path: Path) -> dict:
    """``{relative path: (kind, size, sha1)}`` of a tree (links not followed)."""
    out = {}
    for base, dirs, files in os.walk(path):
        for name in dirs + files:
            p = os.path.join(base, name)
            st = os.lstat(p)
            rel = os.path.relpath(p, path)
            if stat.S_ISREG(st.st_mode):
                with open(p, "rb") as fh:
                    out[rel] = ("file", st.st_size, hashlib.sha1(fh.read()).hexdigest())
            elif stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(p), None)
            else:
                out[rel] = ("dir" if stat.S_ISDIR(st.st_mode) else "other", 0, None)
    return out


def run(*argv, cwd=None, timeout: float = 120.0) -> tuple[int, str]:
    """``facestats ARGV`` in this process (:func:`tests.helpers.run_main`): (exit code, stdout + stderr)."""
    r = run_main(*argv, cwd=cwd, timeout=timeout)
    return r.returncode, r.stdout + r.stderr


def digest_dataset(ds) -> str:
    """A digest of every variable's values and the metadata of a subject."""
    h = hashlib.sha1()
    for name in sorted(ds.variables):
        v = np.asarray(ds[name].values)
        h.update(name.encode())
        h.update(v.astype(str).tobytes() if v.dtype.kind in "OUS" else np.ascontiguousarray(v).tobytes())
    for key in ("subject_id", "age", "gender", "skin_type", "condition"):
        h.update(repr(ds.attrs.get(key)).encode())
    return h.hexdigest()


def subject_digests(path) -> dict:
    """``{subject id: digest}`` of the subjects a store serves intact now (unreadable ones left out)."""
    out = {}
    try:
        st = open_store(path)
    except StoreError:
        return out
    with st:
        try:
            ids = st.ids()
        except StoreError:
            return out
        for sid in ids:
            try:
                out[sid] = digest_dataset(st.subject(sid))
            except StoreError:
                continue
    return out


def quarantined_generations(path) -> set:
    """Names of the generation folders in the store's quarantine."""
    return {p.name for p in Path(path).glob("quarantine/*/subjects/*/g*") if p.is_dir()}


def generation_dir(store: Path, sid: str) -> Path:
    """The current generation folder of ``sid``."""
    with open_store(store) as st:
        gen = st.index_entries()[sid]["generation"]
    return store / "subjects" / sid / gen


def flip_albedo_bit(gen_dir: Path) -> bytes:
    """Flip one bit in the first albedo chunk of a generation folder; the damaged chunk's bytes."""
    chunk = gen_dir / "albedo" / "c" / "0" / "0" / "0"
    data = bytearray(chunk.read_bytes())
    data[len(data) // 2] ^= 0x10
    chunk.write_bytes(bytes(data))
    return bytes(data)
