"""numba's on-disk kernel caches, kept consistent with the kernels' sources.

The kernels are compiled with ``cache=True``: numba keeps the machine code in each module's ``__pycache__``
(``*.nbi`` index, ``*.nbc`` data) and checks it against the time stamp of *that module's* file only.  A kernel
that calls a kernel of another module keeps the callee's old code after the callee changed (an upgrade of
facestats, or an edit) and silently computes with it.  :func:`refresh_kernel_caches`, run when facestats is
imported, keeps a digest of every kernel module's source beside the caches and deletes all of them when any
kernel module changed.  Standard library only: it runs at facestats' import.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

__all__ = ["KERNEL_MODULES", "STAMP", "refresh_kernel_caches", "source_digest"]

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
#: The digest's file, in the package's own ``__pycache__``.
STAMP = "numba-kernels.sha256"


def source_digest(root) -> str:
    """SHA-256 (hex) of the relative names and contents of :data:`KERNEL_MODULES` under ``root`` (a missing
    module counts as a marker)."""
    digest = hashlib.sha256()
    for rel in KERNEL_MODULES:
        digest.update(rel.encode())
        try:
            digest.update((Path(root) / rel).read_bytes())
        except OSError:
            digest.update(b"\0missing")
    return digest.hexdigest()


@functools.lru_cache(maxsize=None)
def refresh_kernel_caches(package: str | None = None) -> bool:
    """Delete numba's cached kernels under ``package`` (default: facestats' directory) if any kernel module changed.

    The digest (:func:`source_digest`) is compared with the one stored in ``<package>/__pycache__/`` :data:`STAMP`;
    when they differ, every ``*.nbi`` and ``*.nbc`` file of the kernel modules is deleted and the new digest
    written (atomically), so numba compiles afresh on first use.  Returns whether caches were cleared.  An
    unwritable installation is left as it is (numba cannot write caches there either).  Runs once per process
    and package.
    """
    root = Path(package) if package is not None else Path(__file__).resolve().parent.parent
    text = source_digest(root)
    stamp = root / "__pycache__" / STAMP
    try:
        if stamp.read_text().strip() == text:
            return False
    except OSError:
        pass
    try:
        for rel in KERNEL_MODULES:
            module = root / rel
            cache = module.parent / "__pycache__"
            if cache.is_dir():
                for f in cache.iterdir():
                    if f.name.startswith(module.stem + ".") and f.suffix in (".nbi", ".nbc"):
                        f.unlink(missing_ok=True)
        stamp.parent.mkdir(exist_ok=True)
        tmp = stamp.with_name(f"{STAMP}.{os.getpid()}.tmp")
        tmp.write_text(text + "\n")
        os.replace(tmp, stamp)
    except OSError:
        return False
    return True
