"""Which implementation runs the hot loops of the fit: compiled numba kernels or pure numpy.

Both engines compute the same stages (Weyrich et al. 2006 §5.1-5.3) with the
same algorithms; they differ only in how the per-sample loops run:

* ``"numba"`` — the fused kernels of :mod:`facestats.model.fitting.kernels`
  (one pass over each lumitexel's samples while they sit in the CPU cache;
  the Levenberg-Marquardt solve of eq. 14 runs texel by texel and stops each
  texel as soon as it converges);
* ``"numpy"`` — the vectorised numpy implementation, kept as the reference
  and as the fallback when numba is not installed.

The choice, in order: the ``engine`` argument of a fit function (or
:class:`facestats.pipeline.FitSettings`), else the environment variable
``FACESTATS_ENGINE``, else ``"numba"`` when numba imports, else ``"numpy"``.
The two engines are each deterministic and independent of the CPU (see
:mod:`facestats.model.fitting.kernels`) but not bit-identical: the kernels sum
in float64 where numpy sums pairwise in float32, and Levenberg-Marquardt
amplifies that on ill-determined texels.  On subject S001 of the default
population at 48² the albedo differs by at most 2.4e-7 relative and the
unflagged Torrance-Sparrow ρs and m by at most 5.5e-5 and 4.9e-5
(``docs/scale.md``, *Fit engines*: section 1 of ``notebooks/population_scale.ipynb``).
"""

from __future__ import annotations

import os

from facestats.core.compiled import numba_available
from facestats.errors import ValidationError

__all__ = ["ENGINES", "ENGINE_VARIABLE", "default_engine", "resolve_engine", "numba_available"]

#: The engines, in order of preference.
ENGINES = ("numba", "numpy")
#: Environment variable that sets the default engine.
ENGINE_VARIABLE = "FACESTATS_ENGINE"


def default_engine() -> str:
    """The engine used when none is given: ``$FACESTATS_ENGINE``, else numba if it imports, else numpy."""
    env = os.environ.get(ENGINE_VARIABLE, "").strip().lower()
    if env:
        if env not in ENGINES:
            raise ValidationError(f"{ENGINE_VARIABLE} must be one of {list(ENGINES)}, got {env!r}")
        return _usable(env, ENGINE_VARIABLE)
    return "numba" if numba_available() else "numpy"


def resolve_engine(engine=None) -> str:
    """``engine`` checked (``"numba"`` or ``"numpy"``), or :func:`default_engine` for None.

    Parameters
    ----------
    engine : {"numba", "numpy"} or None
        The engine asked for; None: ``$FACESTATS_ENGINE``, else numba if it imports, else numpy.

    Returns
    -------
    str
        ``"numba"`` or ``"numpy"``.

    Raises
    ------
    ValidationError
        An unknown engine (argument or ``$FACESTATS_ENGINE``), or ``"numba"`` when numba cannot be imported.
    """
    if engine is None:
        return default_engine()
    if engine not in ENGINES:
        raise ValidationError(f"engine must be one of {list(ENGINES)}, got {engine!r}")
    return _usable(engine, "engine")


def _usable(engine, name):
    if engine == "numba" and not numba_available():
        raise ValidationError(f"{name} is 'numba' but numba cannot be imported; install numba or use 'numpy'")
    return engine
