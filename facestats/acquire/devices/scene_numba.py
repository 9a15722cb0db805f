"""The compiled dark-code look-up of the emulated dome's frames
(:meth:`facestats.acquire.devices.scene.DomeScene.render`, whose numpy twin is ``numpy.take``).
Imported only when a dome scene renders with numba: importing numba costs about a second."""

from __future__ import annotations

import numba

__all__ = ["table_lookup"]


@numba.njit(cache=True, nogil=True)
def table_lookup(table, index, out):
    """``out[i] = table[index[i]]`` for every i (1-D arrays; ``index`` unsigned, below ``table.size``).

    The same values as ``numpy.take(table, index)``, without numpy's conversion of the 16-bit indices
    to a temporary array of 64-bit ones (3 M indices, a 1024² frame: 2.0-2.3 ms instead of 5.2-6.8).
    Serial and releasing the GIL: the emulated cameras render their frames on several threads.
    """
    for i in range(index.size):
        out[i] = table[index[i]]
