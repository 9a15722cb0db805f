"""MATLAB ``.mat`` files (v4-v7), read without risking the caller's process.

:func:`read_mat` reads a file with :func:`scipy.io.loadmat` in a child
process: some damaged files make ``loadmat`` crash the interpreter (SIGSEGV
in SciPy 1.17, found by a fuzzing red team: single changed bytes of a small
valid file), which would end the caller with no message.  The child costs
about 0.4 s per file (starting Python and importing SciPy).  Used by the MERL importer
(:mod:`facestats.io.merl`) and for DiLiGenT ground-truth normals
(:mod:`facestats.relight.olat`).
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys

from facestats.errors import FormatError
from facestats.io.layout import read_regular_file

__all__ = ["read_mat"]

#: Run by :func:`read_mat` in a child process: the file's bytes on stdin, a pickled
#: ``(status, variables or message, logical keys)`` on stdout.
_CHILD = """
import io, pickle, sys
import scipy.io
data = io.BytesIO(sys.stdin.buffer.read())
try:
    mat = scipy.io.loadmat(data, squeeze_me=False, chars_as_strings=True)
    try:
        data.seek(0)
        logical = frozenset(name for name, _, cls in scipy.io.whosmat(data) if cls == "logical")
    except Exception:
        logical = frozenset()
    out = ("ok", mat, logical)
except NotImplementedError as exc:
    out = ("v7.3", str(exc), None)
except Exception as exc:
    out = ("error", f"{type(exc).__name__}: {exc}", None)
sys.stdout.buffer.write(pickle.dumps(out))
"""


def read_mat(path):
    """``(variables, logical keys)`` of a MATLAB file.

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    variables : dict
        As :func:`scipy.io.loadmat` returns them (``squeeze_me=False``, ``chars_as_strings=True``).
    logical : frozenset of str
        The keys stored as MATLAB ``logical`` (``loadmat`` returns them as uint8 0/1), from
        :func:`scipy.io.whosmat`.

    Raises
    ------
    FormatError
        The file is missing, not a regular file (a FIFO is never opened), a v7.3 (HDF5) file
        (with the hint to save it with ``-v7``), not MATLAB data, or damaged so that ``loadmat``
        crashed (the message names the signal).
    """
    try:
        data = read_regular_file(path)
    except OSError as exc:
        what = "no such file" if not os.path.lexists(path) else f"not a readable regular file ({exc.strerror})"
        raise FormatError(f"{path}: {what}") from None
    child = subprocess.run([sys.executable, "-I", "-c", _CHILD], input=data, capture_output=True)
    if child.returncode != 0:
        how = f"signal {-child.returncode}" if child.returncode < 0 else f"exit status {child.returncode}"
        raise FormatError(f"{path}: not a readable MATLAB file (SciPy's loadmat ended with {how}: a damaged file)")
    status, value, logical = pickle.loads(child.stdout)  # written by _CHILD above, never by the file
    if status == "v7.3":
        raise FormatError(f"{path}: {value}; save it with `save -v7` to read it")
    if status != "ok":
        raise FormatError(f"{path}: not a readable MATLAB file ({value})")
    return value, logical
