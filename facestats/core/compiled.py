"""Whether numba's compiled kernels can run, and which implementation a ``backend`` argument selects.

numba is a declared dependency, but a missing package or an llvmlite that fails to load must not stop
facestats: every compiled kernel has a pure-numpy twin it is tested against.  numba is imported on the
first question (importing it costs about a second), never at facestats' import.
"""

from __future__ import annotations

import functools

from facestats.core.validate import check_choice
from facestats.errors import ValidationError

__all__ = ["BACKENDS", "numba_available", "resolve_backend"]

#: Values of a ``backend`` argument.
BACKENDS = ("auto", "numba", "numpy")


@functools.lru_cache(maxsize=1)
def numba_available() -> bool:
    """True when numba imports (ImportError, or an llvmlite that fails to load, gives False)."""
    try:
        import numba  # noqa: F401
    except Exception:
        return False
    return True


def resolve_backend(backend: str) -> str:
    """``"numba"`` or ``"numpy"`` from a ``backend`` argument in :data:`BACKENDS` (``"auto"``: numba if it imports).

    Raises
    ------
    ValidationError
        For other values, or ``"numba"`` where numba cannot be imported.
    """
    check_choice(backend, "backend", BACKENDS)
    if backend == "numba" and not numba_available():
        raise ValidationError("backend 'numba' needs the numba package, which cannot be imported")
    if backend == "auto":
        return "numba" if numba_available() else "numpy"
    return backend
