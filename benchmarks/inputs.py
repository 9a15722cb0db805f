"""Inputs the benchmarks build once and reuse, rebuilt when absent or stale.

A benchmark input (e.g. the full-resolution capture, ~10 min to simulate) lives
in ``FACESTATS_BENCH_DIR`` (default: ``facestats-bench`` in the system's temporary
directory) next to a key file recording the facestats source it was made with
(a SHA-256 of every ``facestats/**/*.py``) and the parameters it was made from.
An input whose key differs from the current one is deleted and rebuilt, so a
benchmark can never measure data that an older version of the code produced.

Two processes asking for one input at once build it once: the check and the
build hold an exclusive lock (``<name>.lock``, POSIX ``flock``).  Do not run
benchmarks of *different* code versions against one ``FACESTATS_BENCH_DIR`` at
the same time: the newer one deletes and rebuilds an input the other may be
reading, and zarr reads the chunks that vanished as zeros.
"""

from __future__ import annotations

import fcntl
import json
import os
import pathlib
import shutil
import tempfile

from facestats.core.version import source_fingerprint

__all__ = ["bench_dir", "cached_input"]


def bench_dir() -> pathlib.Path:
    """Where benchmark inputs live: ``$FACESTATS_BENCH_DIR`` or ``<tmp>/facestats-bench`` (created)."""
    root = pathlib.Path(
        os.environ.get("FACESTATS_BENCH_DIR") or pathlib.Path(tempfile.gettempdir()) / "facestats-bench"
    )
    root.mkdir(parents=True, exist_ok=True)
    return root


def cached_input(name: str, params: dict, make, *, rebuild: bool = False):
    """The path of input ``name``, made by ``make(path)`` unless a current copy exists.

    Parameters
    ----------
    name : str
        File or directory name of the input inside :func:`bench_dir`.
    params : dict
        JSON-serialisable parameters the input is made from (part of its key).
    make : callable
        ``make(path)`` writes the input at ``path`` and may return a dict of figures.
    rebuild : bool
        Rebuild even if a current copy exists (a benchmark that measures the making).

    Returns
    -------
    path : str
    figures : dict
        What ``make`` returned, or ``{}`` when a current copy was reused.
    """
    root = bench_dir()
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        return _current_or_built(root, name, params, make, rebuild)


def _current_or_built(root, name, params, make, rebuild):
    path, key_file = root / name, root / f"{name}.key.json"
    key = {"code": source_fingerprint(), "params": params}
    if not rebuild and path.exists() and key_file.exists():
        try:
            if json.loads(key_file.read_text()) == key:
                return str(path), {}
        except ValueError:
            pass
    key_file.unlink(missing_ok=True)
    shutil.rmtree(path, ignore_errors=True)
    figures = make(str(path)) or {}
    key_file.write_text(json.dumps(key))
    return str(path), figures
