"""Whether numba's compiled kernels can run, and which implementation a ``backend`` argument selects.

numba is a declared dependency, but a missing package or an llvmlite that fails to load must not stop
facestats: every compiled kernel has a pure-numpy twin it is tested against.  numba is imported on the
first question (importing it costs about a second), never at facestats' import.
"""

from __future__ import annotations

import contextlib
import functools

from facestats.core.validate import check_choice
from facestats.errors import ValidationError

__all__ = ["BACKENDS", "numba_available", "resolve_backend", "threads_at_most"]

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


@contextlib.contextmanager
def threads_at_most(n: int):
    """Run numba's parallel regions started in the ``with`` block on at most ``n`` threads (at least one).

    A ``prange`` of fewer iterations than threads leaves the extra threads idle, yet starting the OpenMP team
    and its threads' wait afterwards cost milliseconds of CPU a call, far more than a small kernel's work.  Each
    iteration is still one thread's work, so the results are the same bits.  Only for code that uses numba.

    Parameters
    ----------
    n : int
        Parallel iterations of the kernels called in the block.
    """
    import numba

    before = numba.get_num_threads()
    if n >= before:
        yield
        return
    numba.set_num_threads(max(int(n), 1))
    try:
        yield
    finally:
        numba.set_num_threads(before)
