"""JSON-ready documents of analysis results: the conventions every ``to_dict()`` follows.

Each result object of :mod:`facestats.analysis` has a ``to_dict()`` method
returning a JSON-serialisable dict (the numbers ``facestats analyze`` writes
into ``<action>.json``; its docstring lists the keys).  Common conventions:

* units: σ in mm⁻¹, variances of σ in mm⁻², ℓd in mm, ρs, m and n
  dimensionless;
* missing or non-finite values are ``None`` (JSON ``null``);
* channels are keyed ``R``, ``G``, ``B``; regions are numbered as Weyrich
  Fig. 15; skin types are Roman numerals where they are keys or labels.

:func:`json_ready` makes the conversion (numpy scalars and arrays to Python,
NaN and infinities to ``None``, keys to strings).
"""

from __future__ import annotations

import math

import numpy as np

from facestats.core.conventions import CHANNELS

__all__ = ["json_ready", "by_channel", "records"]


def _json_scalar(obj):
    """A JSON-ready copy of a scalar (bool, int, float, str or None; anything else as its str)."""
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if obj is None or isinstance(obj, str):
        return obj
    return str(obj)


def json_ready(obj):
    """A JSON-serialisable copy: numpy scalars and arrays to Python, non-finite floats to None.

    Dicts (keys as str), lists, tuples and arrays are converted recursively;
    tuples and arrays become lists.
    """
    if isinstance(obj, dict):
        return {str(k): json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_ready(obj.tolist())
    return _json_scalar(obj)


def by_channel(values) -> dict:
    """``{"R": v0, "G": v1, "B": v2}`` of three values."""

    return {ch: v for ch, v in zip(CHANNELS, values)}


def records(frame) -> list:
    """Rows of a DataFrame (index reset) as a list of dicts."""
    return frame.reset_index().to_dict(orient="records")
