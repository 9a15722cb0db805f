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
    """True when numba imports and compiles: False on an ImportError, an llvmlite that fails to load, or
    ``NUMBA_DISABLE_JIT=1``.  With the JIT off the kernels would run as Python loops over every texel and sample
    (hours where the numpy twins take seconds), and a kernel that emits LLVM directly (the microstructure pass's
    ``_lanczos_pair``) cannot run at all, so ``backend="auto"`` takes the numpy twins."""
    try:
        import numba
    except Exception:
        return False
    return not numba.config.DISABLE_JIT


def resolve_backend(backend: str) -> str:
    """``"numba"`` or ``"numpy"`` from a ``backend`` argument in :data:`BACKENDS` (``"auto"``: numba if it imports).

    Parameters
    ----------
    backend : {"auto", "numba", "numpy"}
        The argument given; ``"auto"`` takes numba when :func:`numba_available` (it imports and its JIT is on).

    Returns
    -------
    str
        ``"numba"`` or ``"numpy"``.

    Raises
    ------
    ValidationError
        For other values, or ``"numba"`` where numba cannot be imported.
    """
    check_choice(backend, "backend", BACKENDS)
    if backend == "numba" and not numba_available():
        raise ValidationError(
            "backend 'numba' needs the numba package, which cannot be imported or has its JIT disabled "
            "(NUMBA_DISABLE_JIT=1)"
        )
    if backend == "auto":
        return "numba" if numba_available() else "numpy"
    return backend
