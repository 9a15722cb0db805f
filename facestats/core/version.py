"""The facestats version (one place; ``pyproject.toml`` reads it from here) and the sources' fingerprint."""

import functools
import hashlib
import pathlib

__version__ = "0.1.0"


@functools.cache
def source_fingerprint() -> str:
    """SHA-256 (hex) of the facestats sources: relative path and content of every ``.py``, in sorted order.

    The key of anything facestats makes once and reuses (the texture sample in the user's
    cache, benchmark inputs): a copy made by other code has another fingerprint and is rebuilt.
    Computed once per process.
    """
    package = pathlib.Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        h.update(str(path.relative_to(package)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()
