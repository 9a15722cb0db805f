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

from facestats.core.conventions import CHANNELS
from facestats.core.outputs import json_ready

__all__ = ["json_ready", "by_channel", "records"]


def by_channel(values) -> dict:
    """``{"R": v0, "G": v1, "B": v2}`` of three values.

    Parameters
    ----------
    values : iterable
        One value per channel, in R, G, B order (extra values past the third are dropped by the ``zip``).

    Returns
    -------
    dict
        Channel name to value; the values are not converted (see :func:`json_ready`).
    """

    return {ch: v for ch, v in zip(CHANNELS, values)}


def records(frame) -> list:
    """Rows of a DataFrame (index reset) as a list of dicts.

    Parameters
    ----------
    frame : pandas.DataFrame
        Table to convert; its index levels become columns of each record.

    Returns
    -------
    list of dict
        One dict per row, column name to value (numpy scalars kept; see :func:`json_ready`).
    """
    return frame.reset_index().to_dict(orient="records")
