"""numba's on-disk kernel caches, kept consistent with the kernels' sources.

The kernels are compiled with ``cache=True``: numba keeps the machine code (``*.nbi`` index, ``*.nbc`` data) and
checks it against the time stamp of *that module's* file only.  A kernel that calls a kernel of another module
keeps the callee's old code after the callee changed (an upgrade of facestats, or an edit) and silently computes
with it.  :func:`refresh_kernel_caches`, run when facestats is imported, keeps a digest of every kernel module's
source beside the caches and deletes all of them when any kernel module changed.

numba (0.60-0.68) keeps a module's caches in one of three places (:func:`cache_places`): the folder named by
``NUMBA_CACHE_DIR`` when it is set; else the module's own ``__pycache__``; else, where that cannot be written (a
read-only installation), a user-wide folder (on Linux ``$XDG_CACHE_HOME/numba``, default ``~/.cache/numba``).  Outside
the package a module's caches lie in the subfolder ``<folder name>_<SHA-1 of the folder's absolute path>``, as
numba's ``get_suitable_cache_subpath`` names it (a test checks the two agree).  Standard library only: it runs at
facestats' import.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

__all__ = ["KERNEL_MODULES", "STAMP", "cache_places", "refresh_kernel_caches", "source_digest"]

#: The modules that define numba kernels (paths relative to the package; a test keeps the list complete).
KERNEL_MODULES = (
    "acquire/devices/scene_numba.py",
    "acquire/dome_numba.py",
    "acquire/hdr_numba.py",
    "acquire/merge_numba.py",
    "core/raster_numba.py",
    "io/deflate_numba.py",
    "model/fitting/kernels/factors.py",
    "model/fitting/kernels/fastexp.py",
    "model/fitting/kernels/lm.py",
    "model/fitting/kernels/runs.py",
    "model/fitting/kernels/samples.py",
    "model/microstructure/compiled.py",
    "relight/compression_numba.py",
)
#: The digest's file, in the package's own ``__pycache__`` (``facestats-<tag>.`` before it outside the package).
STAMP = "numba-kernels.sha256"


def source_digest(root) -> str:
    """SHA-256 (hex) of the relative names and contents of :data:`KERNEL_MODULES` under ``root`` (a missing
    module counts as a marker).

    Parameters
    ----------
    root : str or os.PathLike
        The package's directory (the folder holding ``core/``, ``model/``, ...).

    Returns
    -------
    str
        64 hex digits.
    """
    digest = hashlib.sha256()
    for rel in KERNEL_MODULES:
        digest.update(rel.encode())
        try:
            digest.update((Path(root) / rel).read_bytes())
        except OSError:
            digest.update(b"\0missing")
    return digest.hexdigest()


def cache_places(root) -> list:
    """``(stamp, folders)`` for each place numba may keep the caches of the kernel modules under ``root``
    (module docstring): the digest's file there and, per :data:`KERNEL_MODULES` entry, the folder of its caches.

    Parameters
    ----------
    root : str or os.PathLike
        The package's directory; made absolute without resolving links, as numba does.

    Returns
    -------
    list of tuple
        ``(pathlib.Path, list of pathlib.Path)`` pairs: first the package's own ``__pycache__`` places, then the
        ``NUMBA_CACHE_DIR`` folder (only when that variable is set), then the user-wide folder.  Nothing is
        created or checked for existence.
    """
    root = Path(os.path.abspath(root))  # as numba takes a module's file: absolute, links not resolved
    modules = [root / rel for rel in KERNEL_MODULES]
    places = [(root / "__pycache__" / STAMP, [m.parent / "__pycache__" for m in modules])]
    tag = hashlib.sha1(str(root).encode()).hexdigest()[:16]
    xdg = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    for base in (os.environ.get("NUMBA_CACHE_DIR"), os.path.join(xdg, "numba")):
        if base:
            base = Path(base)
            subs = [base / f"{m.parent.name}_{hashlib.sha1(str(m.parent).encode()).hexdigest()}" for m in modules]
            places.append((base / f"facestats-{tag}.{STAMP}", subs))
    return places


@functools.lru_cache(maxsize=None)
def refresh_kernel_caches(package: str | None = None) -> bool:
    """Delete numba's cached kernels of ``package`` (default: facestats' directory) if any kernel module changed.

    For each place numba may keep them (:func:`cache_places`), the digest (:func:`source_digest`) is compared with
    the one stored there; when they differ, every ``*.nbi`` and ``*.nbc`` file of the kernel modules in that place
    is deleted and the new digest written (atomically), so numba compiles afresh on first use.  A place outside the
    package where numba has kept no facestats caches is skipped, and one that cannot be written is left as it is
    (numba cannot write caches there either).  Returns whether caches were cleared anywhere.  Runs once per process and
    package.
    """
    root = package if package is not None else os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    text = source_digest(root)
    cleared = False
    for i, (stamp, folders) in enumerate(cache_places(root)):
        cleared |= _refresh_place(stamp, folders, text, in_tree=i == 0)
    return cleared


def _refresh_place(stamp: Path, folders: list, text: str, in_tree: bool) -> bool:
    """One place of :func:`refresh_kernel_caches`; ``folders`` in :data:`KERNEL_MODULES` order.  The package's own
    ``__pycache__`` is made if missing; a place outside it without a folder of facestats' caches is left alone."""
    try:  # Path.is_dir raises where a folder cannot be entered (a HOME of another user): such a place is left
        if not in_tree and not any(folder.is_dir() for folder in folders):
            return False
    except OSError:
        return False
    try:
        if stamp.read_text().strip() == text:
            return False
    except OSError:
        pass
    try:
        for rel, cache in zip(KERNEL_MODULES, folders):
            stem = Path(rel).stem
            if cache.is_dir():
                for f in cache.iterdir():
                    if f.name.startswith(stem + ".") and f.suffix in (".nbi", ".nbc"):
                        f.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        tmp = stamp.with_name(f"{stamp.name}.{os.getpid()}.tmp")
        tmp.write_text(text + "\n")
        os.replace(tmp, stamp)
    except OSError:
        return False
    return True
