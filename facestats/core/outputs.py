"""Output files: checked before any work, written all or none.

Commands write results (plots, statistics, exports, images) only after they
have done their work, so a bad output path must be caught *first*, and a
failure while writing (a full disk) must leave nothing half-written:

* :func:`check_output_dir` / :func:`check_output_file` look at a path without
  changing anything: an existing directory must be writable, an existing
  file must be a regular file (for a file output) or absent (for a folder),
  and a path that does not exist yet must be creatable (its nearest existing
  ancestor a writable directory), with an accepted suffix if the caller has a
  list — so ``/dev/null/x``, a folder where a file is due, a file where a
  folder is due, or ``plot.xyz`` fail with a :class:`~facestats.errors.ValidationError`
  naming the argument and the path before any work is done;
* :class:`OutputSet` writes several files each under a temporary name beside
  its target and renames them into place only when all were written; on any
  failure it removes the temporaries and the folders it created, so the
  previous files (if any) stay as they were; an :class:`OSError` (a full
  disk) becomes a :class:`~facestats.errors.FacestatsError` naming the folder.
"""

from __future__ import annotations

import errno
import math
import os
import pathlib
import secrets
import shutil
import tempfile
from urllib.parse import urlparse

from facestats.errors import FacestatsError, ValidationError

__all__ = [
    "check_output_dir",
    "check_output_file",
    "check_names_free",
    "check_apart",
    "missing_folders",
    "url_scheme",
    "json_ready",
    "OutputSet",
]


def json_ready(value):
    """``value`` for ``json.dumps(..., allow_nan=False)``: every NaN or ±inf float becomes None (JSON has no such
    numbers; ``json.dumps`` would write the non-standard tokens ``NaN`` and ``Infinity``).

    Recursively through dicts (keys as str), lists, tuples and arrays (tuples and arrays become lists); numpy
    scalars become Python bool, int or float; a value of any other type becomes its ``str``.

    Parameters
    ----------
    value : object
        A number, string, None, numpy array or scalar, or a dict/list/tuple of these (nested).

    Returns
    -------
    object
        A new structure of dicts, lists, str, int, float, bool and None (the input is not changed).
    """
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if hasattr(value, "tolist") and hasattr(value, "ndim"):  # a numpy array or scalar
        value = value.tolist()
        if isinstance(value, list):
            return json_ready(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


def _as_path(path, name: str) -> pathlib.Path:
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)) or not os.fspath(path).strip() or "\x00" in os.fspath(path):
        raise ValidationError(f"{name} must be a file system path, got {path!r}")
    return pathlib.Path(os.fspath(path)).expanduser()


def _writable_dir(directory: pathlib.Path, name: str, p: pathlib.Path, what: str) -> None:
    """``directory`` must let this process create entries: checked by creating and removing an empty folder.

    ``os.access`` answers "writable" to root almost everywhere: in ``/proc`` (where nothing can be created) and
    on some read-only mounts, so a command running as root checked ``--images /proc/x``, did its work, then failed
    to write (after committing an edited subject).  Only writing tells; the probe leaves nothing behind.
    """
    if not os.access(directory, os.W_OK | os.X_OK):
        raise ValidationError(f"{name} must be a path that can be {what}, got {str(p)!r} ({directory} is not writable)")
    try:
        probe = tempfile.mkdtemp(prefix=".facestats-probe-", dir=directory)
    except OSError as exc:
        raise ValidationError(
            f"{name} must be a path that can be {what}, got {str(p)!r} ({directory}: {exc.strerror or exc})"
        ) from None
    os.rmdir(probe)


def _creatable(p: pathlib.Path, name: str) -> None:
    """The nearest existing ancestor of ``p`` must be a directory this process can create entries in, and the
    names to create in it no longer than its file system allows (nothing is left created).

    The probe creates one short name: a 300-byte folder name passed it, the command did its work and then failed
    to make the folder (``File name too long``), leaving the folders above it that it had made.
    """
    parent = p.absolute().parent
    while not os.path.lexists(parent) and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ValidationError(
            f"{name} must be a path that can be created, got {str(p)!r} ({parent} is not a directory)"
        )
    _writable_dir(parent, name, p, "created")
    try:
        longest = os.pathconf(parent, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):  # not known here (another system): 255 bytes, POSIX's usual
        longest = 255
    for part in p.absolute().relative_to(parent).parts:
        if len(os.fsencode(part)) > longest:
            raise ValidationError(
                f"{name} must be a path that can be created, got {str(p)!r} (a name of {len(os.fsencode(part))} "
                f"bytes, {part[:20]}…; the file system of {parent} allows at most {longest})"
            )


def check_output_dir(path, name: str = "out") -> pathlib.Path:
    """``path`` as an output folder: an existing writable directory, or a path that can be created.

    Nothing is left created: writability is probed with an empty folder that is removed again.

    Parameters
    ----------
    path : str, bytes or os.PathLike
        The folder (``~`` expanded).
    name : str
        The argument's name in messages (default ``"out"``).

    Returns
    -------
    pathlib.Path
        ``path``, checked, with ``~`` expanded.

    Raises
    ------
    ValidationError
        Naming ``name`` and the path (a file, a device, an unwritable or uncreatable path).
    """
    p = _as_path(path, name)
    if os.path.lexists(p):
        if not p.is_dir():
            raise ValidationError(f"{name} must be a directory, got {str(p)!r}, which exists and is not one")
        if not os.access(p, os.W_OK | os.X_OK):
            raise ValidationError(f"{name} must be a writable directory, got {str(p)!r}")
        _writable_dir(p, name, p, "written in")
        return p
    _creatable(p, name)
    return p


def check_output_file(path, name: str = "out", suffixes=None, *, overwrite: bool = True) -> pathlib.Path:
    """``path`` as an output file: absent (creatable) or an existing regular file, with one of ``suffixes``.

    Parameters
    ----------
    path : str or os.PathLike
    name : str
        The argument's name in messages.
    suffixes : iterable of str, optional
        Accepted suffixes, lower case with the dot (e.g. ``(".png", ".svg")``).
    overwrite : bool
        Whether an existing file may be replaced (False: refused, pointing at ``--overwrite``).

    Returns
    -------
    pathlib.Path
        ``path``, checked.

    Raises
    ------
    ValidationError
        Naming ``name`` and the path.
    """
    p = _as_path(path, name)
    if suffixes is not None:
        accepted = sorted(set(suffixes))
        if p.suffix.lower() not in accepted:
            bare = p.name.lower() in accepted  # '.exr': a hidden file's name without a suffix, no name before it
            raise ValidationError(
                f"{name} must end in one of {accepted}"
                + (f" after a file name (e.g. out{p.name.lower()})" if bare else "")
                + f", got {str(p)!r}"
            )
    if os.path.lexists(p):
        if not p.is_file():
            raise ValidationError(f"{name} must be a file, got {str(p)!r}, which exists and is not a regular file")
        if not os.access(p, os.W_OK) or not os.access(p.parent, os.W_OK | os.X_OK):
            raise ValidationError(f"{name} must be writable, got {str(p)!r}")
        _writable_dir(p.absolute().parent, name, p, "replaced")  # replaced by a file written beside it, renamed
        if not overwrite:
            raise ValidationError(f"output {str(p)!r} exists (pass --overwrite to replace it)")
        return p
    _creatable(p, name)
    return p


def check_names_free(folder, names, name: str, what: str, other: str = "") -> None:
    """Refuse, before any work, a command's output ``folder`` (option ``name``) that already holds any of the
    file ``names`` the command may write (without ``--overwrite``).

    ``what`` says whose files they are in the message (e.g. "this edit's images"); ``other`` adds another way
    out (e.g. "or --id").

    Parameters
    ----------
    folder : str or os.PathLike
        The output folder (it need not exist).
    names : iterable of str
        File names relative to ``folder``.
    name : str
        The option's name, e.g. ``"--out"``.
    what : str
        Whose files they are, for the message.
    other : str
        Text appended to the message's advice, e.g. ``" or --id"`` (default none).

    Returns
    -------
    None

    Raises
    ------
    ValidationError
        Naming the option, the folder, the first file found and how many more, and pointing at ``--overwrite``.
    """
    there = [n for n in names if os.path.lexists(os.path.join(folder, n))]
    if there:
        raise ValidationError(
            f"{name} folder {os.fspath(folder)!r} already holds {there[0]}"
            + (f" and {len(there) - 1} more of {what}" if len(there) > 1 else "")
            + f": pass --overwrite to replace them, or choose another {name} folder{other}"
        )


def missing_folders(path) -> list[pathlib.Path]:
    """The folders of ``path`` (itself included) that do not exist yet, innermost first (what a ``mkdir -p`` makes).

    Parameters
    ----------
    path : str or os.PathLike
        A folder path.

    Returns
    -------
    list of pathlib.Path
        Absolute paths (links not resolved); empty if ``path`` exists.
    """
    missing = []
    d = pathlib.Path(os.path.abspath(path))
    while not os.path.lexists(d) and d != d.parent:
        missing.append(d)
        d = d.parent
    return missing


def url_scheme(path) -> str:
    """The lower-case scheme of a ``scheme://…`` location, else ``""`` (RFC 3986 §3.1: schemes are compared
    without regard to case).

    Parameters
    ----------
    path : str, bytes or os.PathLike
        A path or URL; anything else has no scheme.

    Returns
    -------
    str
        ``"file"``, ``"s3"``, …; ``""`` for a local path, including ``C:\\…`` (a one-letter scheme is a drive letter).
    """
    if isinstance(path, bytes):
        path = os.fsdecode(path)
    if not isinstance(path, (str, os.PathLike)) or "://" not in os.fspath(path):
        return ""
    scheme = urlparse(os.fspath(path)).scheme.lower()
    return scheme if len(scheme) > 1 else ""


def _local_location(path):
    """``path`` as :func:`check_apart` compares it: a ``file://`` URL's path (as :func:`facestats.open_store` reads
    it), anything else unchanged."""
    return urlparse(os.fspath(path)).path if url_scheme(path) == "file" else path


def check_apart(
    path, protected, name: str = "out", what: str = "the store", *, replaced: bool = False, same: bool = False
) -> None:
    """Refuse an output ``path`` that is ``protected`` or lies inside it (links resolved).

    Writing there would mix files into ``protected`` (a store).  With
    ``replaced`` (an output folder replaced as a whole) a ``path`` that contains
    ``protected`` is refused too: replacing it would destroy ``protected``.
    With ``same``, ``path`` may be ``protected`` itself (an output store that is
    the source store), only not inside it.  A ``file://`` URL, given for either,
    stands for its path (as :func:`facestats.open_store` reads it); another URL
    (``s3://…``) is not on this file system, so it can neither lie inside a
    local path nor hold one: nothing is checked.

    Parameters
    ----------
    path : str or os.PathLike
        The output path (a ``file://`` URL: its path; another URL: nothing is checked).
    protected : str, os.PathLike or None
        The path to keep apart from; None or empty: nothing is checked; URLs as for ``path``.
    name : str
        The output's option name in messages (default ``"out"``).
    what : str
        What ``protected`` is, for messages (default ``"the store"``).
    replaced : bool
        ``path`` is replaced as a whole: also refuse a ``path`` that contains ``protected``.
    same : bool
        Allow ``path`` to be ``protected`` itself.

    Returns
    -------
    None

    Raises
    ------
    ValidationError
        Naming ``name``, the path and ``what``.
    """
    if not protected or url_scheme(protected) not in ("", "file") or url_scheme(path) not in ("", "file"):
        return  # a remote location (s3://…) neither lies inside a local path nor holds one
    guard = os.path.realpath(_as_path(_local_location(protected), what))
    real = os.path.realpath(_as_path(_local_location(path), name))
    common = os.path.commonpath([guard, real])
    if (common == guard and not (same and real == guard)) or (replaced and common == real):
        rule = "lie outside {w} and not contain it" if replaced else "lie outside {w}"
        raise ValidationError(
            f"{name} must {rule.format(w=what)}: {name} {os.fspath(path)!r}, {what} {os.fspath(protected)!r}"
        )


class OutputSet:
    """Files written all or none (module docstring).

    Use as a context manager; :meth:`path` gives the temporary path to write
    each target to; leaving the block without an exception renames them all
    into place::

        with OutputSet(out_dir) as out:
            fig.savefig(out.path("plot.png"))
            out.path("data.json").write_text(...)
        out.written  # the final paths

    Targets may also be paths in other folders (``out.path("/elsewhere/x.png")``):
    their missing folders are created, and removed again on failure.  The
    temporaries have unique names (never a name an earlier run could have left,
    never followed through a symlink).  Renaming into place is a transaction:
    an existing target is first kept under a second name (a hard link: it never
    disappears), and if any rename fails, or the process is interrupted, every
    target is put back as it was.

    Without ``overwrite`` a target is placed only where no file is (a hard link, which fails on an existing
    name, then the temporary removed): a file that appeared under a target's name since the command checked the
    folder (another process writing there) is kept, and the set fails as a whole.

    Parameters
    ----------
    directory : str or os.PathLike
        The folder of the files (created if missing, removed again on failure if it was created).
    overwrite : bool
        Whether a target may replace an existing file (default True; False: the set fails, nothing replaced).
    """

    def __init__(self, directory, *, overwrite: bool = True):
        self.directory = pathlib.Path(directory)
        self.overwrite = bool(overwrite)
        self.written: list[pathlib.Path] = []
        self._temps: list[tuple[pathlib.Path, pathlib.Path]] = []
        self._created: list[pathlib.Path] = []

    def __enter__(self):
        self._make_dirs(self.directory)
        return self

    def _make_dirs(self, directory: pathlib.Path) -> None:
        missing = missing_folders(directory)
        try:
            directory.mkdir(parents=True, exist_ok=True)
        except BaseException as exc:  # the folders made before the failure go again (a name too long for the last)
            for d in missing:  # innermost first
                try:
                    os.rmdir(d)
                except OSError:
                    pass
            if not isinstance(exc, OSError):
                raise
            raise ValidationError(f"cannot create the output folder {directory}: {exc.strerror}") from None
        self._created = missing + self._created  # innermost first, newest first

    def path(self, name) -> pathlib.Path:
        """The temporary path to write the file ``name`` (of :attr:`directory`, or a path elsewhere) to.

        Parameters
        ----------
        name : str or os.PathLike
            The target, relative to :attr:`directory` or absolute; its missing folders are created.

        Returns
        -------
        pathlib.Path
            An empty file, reserved under a unique hidden name beside the target; renamed into place on success.

        Raises
        ------
        ValidationError
            If the target is named twice, is a folder (a rename cannot replace one by a file), or its folder cannot
            be created.
        """
        final = pathlib.Path(os.path.abspath(self.directory / name))
        if any(final == f for _, f in self._temps):
            raise ValidationError(f"output {str(final)!r} is named twice")
        if os.path.isdir(final) and not os.path.islink(final):  # refused now, not when the renames fail
            raise ValidationError(f"output {str(final)!r} is a folder: move it away or choose another output folder")
        self._make_dirs(final.parent)
        tmp = final.with_name(f".{final.name}.tmp-{os.getpid()}-{secrets.token_hex(6)}{final.suffix}")
        # Reserve the name: O_EXCL never opens an existing file or follows a symlink left there.
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        self._temps.append((tmp, final))
        return tmp

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self._commit()
                return False
            except OSError as err:
                exc = err
            except BaseException:  # interrupted while committing: the targets are back, the temporaries go
                self._cleanup()
                raise
        self._cleanup()
        if isinstance(exc, OSError):  # e.g. a full disk: say where, and that nothing was left behind
            where = exc.filename if getattr(exc, "filename", None) else self.directory
            raise FacestatsError(
                f"cannot write the output files in {self.directory} ({where}): {exc.strerror or exc}; "
                "nothing was written"
            ) from None
        return False

    def _commit(self) -> None:
        """Rename every temporary into place; on a failure (or an interruption), put every target back.

        An existing target is first kept under a hard link (a second name for the same file), so it never
        disappears: readers see the old file, then the new one.  Where hard links are not possible (another
        file system's rules), it is copied instead.
        """
        kept: list[tuple[pathlib.Path, pathlib.Path]] = []  # (backup, final)
        placed: list[pathlib.Path] = []
        try:
            for _, final in self._temps:
                if not self.overwrite and os.path.lexists(final):  # appeared since the check: nothing is replaced
                    raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(final))
                if os.path.lexists(final) and not os.path.isdir(final):
                    backup = final.with_name(f".{final.name}.old-{os.getpid()}-{secrets.token_hex(6)}")
                    try:
                        os.link(final, backup, follow_symlinks=False)
                    except OSError:
                        shutil.copy2(final, backup, follow_symlinks=False)
                    kept.append((backup, final))
            for tmp, final in self._temps:
                if self.overwrite:
                    os.replace(tmp, final)
                else:
                    _place_new(tmp, final)
                placed.append(final)
        except BaseException:
            _put_back(placed, kept)
            raise
        for backup, _ in kept:
            _remove(backup)
        self.written = placed

    def _cleanup(self) -> None:
        for tmp, _ in self._temps:
            _remove(tmp)
        for d in self._created:  # innermost first; a folder someone else filled meanwhile stays
            try:
                os.rmdir(d)
            except OSError:
                pass


def _place_new(tmp, final) -> None:
    """Rename ``tmp`` to ``final`` unless a file of that name exists (:class:`FileExistsError`, nothing changed).

    A hard link fails on an existing name (POSIX ``link``), so a file that appears meanwhile is never replaced;
    where hard links are not possible, the name is checked just before :func:`os.replace`.
    """
    try:
        os.link(tmp, final)
    except FileExistsError:  # named by the target (link() names the temporary first)
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(final)) from None
    except OSError:  # no hard links on this file system
        if os.path.lexists(final):
            raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(final)) from None
        os.replace(tmp, final)
        return
    _remove(tmp)


def _put_back(placed, kept) -> None:
    """Undo the renames of :meth:`OutputSet._commit`: remove the new files ``placed`` that had no old file, put each
    old file back from its backup (``kept``: (backup, target) pairs), and remove the backups of targets that were
    not reached, which still are the old files (their backup is a second name for them, and a rename of one name
    of a file onto another does nothing: POSIX ``rename``)."""
    restored = {final for _, final in kept}
    for final in placed:
        if final not in restored:
            _remove(final)
    for backup, final in kept:
        if final in placed:
            os.replace(backup, final)
        else:
            _remove(backup)


def _remove(path) -> None:
    try:
        os.remove(path)
    except OSError:
        pass
