"""Where a population fit runs and where it writes: a Dask distributed cluster or this machine, a shared store.

* :func:`scheduler_address` — the ``tcp://…`` (or ``tls://``, ``ucx://``,
  ``inproc://``) address of a running Dask scheduler, given explicitly
  (``facestats build --scheduler``) or by the environment variable
  ``DASK_SCHEDULER_ADDRESS`` (Dask's own name for it), or None: run locally
  (also when given ``"local"``, which ignores the variable);
* :func:`connect` — a :class:`distributed.Client` for such an address;
* :func:`store_directory` — the directory of a store the workers write to;
* :func:`run_tasks` — one task per subject on a cluster, a task lost with a
  shared worker submitted again alone.

Commit guarantees.  A store commits a subject by replacing ``index.json``
atomically under a POSIX ``flock`` (:mod:`facestats.io.store`), so workers
on several machines may write to one store only on a shared POSIX file
system with working ``flock`` (a local disk, NFSv4, Lustre, CephFS,
GPFS); each worker then writes its subject's data in parallel and commits
under the lock, as concurrent local writers do.  Object stores (``s3://``,
``gs://``, ``az://``, … — anything fsspec reaches) have no locks and no
atomic rename of a directory: facestats **refuses** to write a store there
(:class:`facestats.errors.StoreError` naming the URL) rather than risk two
workers' index updates overwriting each other.  Captures, which are only
read, may be at any URL that zarr and fsspec open (``s3://…/S001.zarr``,
``file://…``); a built local store can be uploaded to an object store
afterwards and read from there by whoever downloads it.
"""

from __future__ import annotations

import os
from urllib.parse import urlparse

from facestats.core.outputs import url_scheme
from facestats.errors import StoreError, ValidationError
from facestats.pipeline.progress import subject_bar

__all__ = [
    "SCHEDULER_VARIABLE",
    "LOCAL",
    "scheduler_address",
    "connect",
    "store_directory",
    "local_path",
    "is_url",
    "run_tasks",
    "Outcome",
]

#: Environment variable naming the scheduler (read by Dask too).
SCHEDULER_VARIABLE = "DASK_SCHEDULER_ADDRESS"
#: The ``scheduler`` value that runs on this machine whatever ``$DASK_SCHEDULER_ADDRESS`` says.
LOCAL = "local"
_SCHEMES = ("tcp", "tls", "ucx", "inproc", "ws", "wss")


def scheduler_address(scheduler=None):
    """The distributed scheduler to use: ``scheduler`` if it is an address, else ``$DASK_SCHEDULER_ADDRESS``, else None.

    ``scheduler="local"`` (:data:`LOCAL`) gives None whatever the variable says.

    Parameters
    ----------
    scheduler : str, optional
        A scheduler address (``tcp://host:8786``; protocols tcp, tls, ucx, inproc, ws, wss), ``"local"``, or
        None to read :data:`SCHEDULER_VARIABLE` (unset or empty: None).

    Returns
    -------
    str or None
        The address, stripped of blanks, or None to run on this machine.

    Raises
    ------
    ValidationError
        If ``scheduler`` (or the variable) is not an address of a known protocol.
    """
    if isinstance(scheduler, str) and scheduler.strip() == LOCAL:
        return None
    for value, name in ((scheduler, "scheduler"), (os.environ.get(SCHEDULER_VARIABLE) or None, SCHEDULER_VARIABLE)):
        if value is None:
            continue
        value = str(value).strip()
        try:
            scheme = urlparse(value).scheme
        except ValueError:  # e.g. an unclosed IPv6 bracket
            scheme = None
        if scheme not in _SCHEMES or "://" not in value:
            raise ValidationError(
                f"{name} must be a Dask scheduler address such as tcp://host:8786 "
                f"(protocols {', '.join(_SCHEMES)}) or {LOCAL!r}, got {value!r}"
            )
        return value
    return None


def connect(address, timeout: float = 30.0):
    """A :class:`distributed.Client` connected to the scheduler at ``address``.

    A ``tcp://`` address is first probed for a Dask handshake, so another service on that port fails fast.

    Parameters
    ----------
    address : str
        The scheduler's address, e.g. from :func:`scheduler_address`.
    timeout : float
        Seconds to wait for the scheduler (default 30).

    Returns
    -------
    distributed.Client
        Connected, not set as Dask's default scheduler.

    Raises
    ------
    ValidationError
        If the ``distributed`` package is missing or no scheduler answers.
    """
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - distributed is in the test extra
        raise ValidationError(
            f"the Dask scheduler at {address!r} needs the 'distributed' package: pip install 'facestats[distributed]'"
        ) from None
    _check_connectable(address)  # a Client built from a malformed address fails half-made
    if address.lower().startswith("tcp://"):
        _probe_tcp(address, timeout)
    try:
        # Not made Dask's default scheduler: a Client that fails to connect would stay the default, and the
        # process's later Dask computations would wait for it. facestats passes the client explicitly.
        return Client(address, timeout=timeout, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise ValidationError(f"the Dask scheduler at {address!r} did not answer within {timeout:g} s: {exc}") from None
    except (ValueError, TypeError, KeyError) as exc:  # e.g. an in-process address that no cluster listens on
        raise ValidationError(f"the Dask scheduler at {address!r}: not an address Dask can connect to: {exc}") from None
    except MemoryError:  # another service's reply read as the length of a message
        raise ValidationError(f"the Dask scheduler at {address!r} is not one (its reply is not Dask's)") from None


#: Longest first message of a Dask scheduler's handshake that :func:`_probe_tcp` accepts (bytes).
_MAX_HANDSHAKE = 1 << 24


def _probe_tcp(address, timeout: float) -> None:
    """ValidationError unless a Dask scheduler answers at the ``tcp://`` ``address`` within ``timeout`` s.

    A Dask listener speaks first: on a new connection it sends its handshake, a message whose first 8 bytes
    are its length (an unsigned 64-bit integer in the machine's byte order, ``distributed.comm.tcp``).  Another
    service (Dask's dashboard on 8787 instead of the scheduler's 8786, a web server) sends nothing, which made
    the client wait past its timeout for ever, or a reply whose first bytes read as a length of exabytes, which
    ended in MemoryError; a refused connection waited the whole timeout.  A test checks this against a real
    scheduler, so a change of Dask's framing shows.
    """
    import socket
    import struct
    import time

    from distributed.comm.addressing import get_address_host_port

    host, port = get_address_host_port(address)
    start = time.monotonic()
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            head = b""
            while len(head) < 8:
                sock.settimeout(max(0.1, timeout - (time.monotonic() - start)))
                part = sock.recv(8 - len(head))
                if not part:
                    break
                head += part
    except TimeoutError:
        raise ValidationError(
            f"the Dask scheduler at {address!r} did not answer within {timeout:g} s (is it a scheduler's address? the "
            "scheduler listens on 8786 by default, its dashboard on 8787)"
        ) from None
    except OSError as exc:
        raise ValidationError(f"the Dask scheduler at {address!r} cannot be reached: {exc.strerror or exc}") from None
    if len(head) < 8 or not 0 < struct.unpack("Q", head)[0] <= _MAX_HANDSHAKE:
        shown = head[:8].decode("ascii", "replace") if head else "nothing"
        raise ValidationError(
            f"the Dask scheduler at {address!r} is not one: it answered {shown!r}, not Dask's handshake (the "
            "scheduler listens on 8786 by default, its dashboard on 8787)"
        )


def _check_connectable(address):
    """ValidationError unless ``address`` has a protocol distributed knows and a host and a port, or is an in-process
    address something listens on (distributed's own parsers and registry). A Client made for an address that cannot
    work fails half-made, and its clean-up can block the process."""
    from distributed.comm.addressing import get_address_host_port, parse_address
    from distributed.comm.registry import get_backend

    try:
        scheme, location = parse_address(address)
        get_backend(scheme)
        if scheme != "inproc":
            _, port = get_address_host_port(address)
            if not 0 < int(port) < 65536:
                raise ValueError(f"port {port} is not in 1..65535")
        else:  # an in-process scheduler either listens in this process now or cannot be reached at all
            from distributed.comm.inproc import global_manager

            if global_manager.get_listener_for(location) is None:
                raise ValueError("no in-process scheduler of this process listens there")
    except (ValueError, TypeError, KeyError) as exc:
        raise ValidationError(f"the Dask scheduler at {address!r}: not an address Dask can connect to: {exc}") from None


def is_url(path) -> bool:
    """True for ``scheme://…`` locations other than plain local paths (and other than ``file://``; schemes are
    compared without regard to case, as RFC 3986 §3.1 has them).

    Parameters
    ----------
    path : str or os.PathLike
        The location (its ``str`` is parsed).

    Returns
    -------
    bool
        Whether it holds ``://`` after a scheme of two or more characters (a drive letter is not one) other than
        ``file``.
    """
    return url_scheme(str(path)) not in ("", "file")


def local_path(path, name="path") -> str:
    """The absolute local path of a path or ``file://`` URL: what every worker of a build resolves alike.

    A relative path would be resolved against each worker's own working directory (another folder, or another
    machine's), so workers would read another capture or write another store than the caller named.

    Parameters
    ----------
    path : str or os.PathLike
        A local path (absolute or relative to the working directory) or a ``file:///…`` URL (``file:/…`` and
        ``file://localhost/…`` too). Other URLs are not refused here: callers test :func:`is_url` first.
    name : str
        The argument's name in messages (default ``"path"``).

    Returns
    -------
    str
        The path joined to the working directory (not normalised: ``..`` and links are left as written).

    Raises
    ------
    ValidationError
        A ``file://`` URL naming a host (``file://host/path``: facestats reads local files only; fsspec and this
        function would disagree on where it points), or a path that begins like a URL with one slash
        (``s3:/bucket``), which would make a local folder ``s3:``; also an fsspec chained URL (``a::b``) or an
        empty path.
    """
    text = str(path)
    parsed = urlparse(text)
    if "::" in text:  # fsspec's chained URLs (simplecache::s3://…) are not local folders
        raise ValidationError(f"{name} must be a local path or a file:// URL, got the chained URL {text!r}")
    if parsed.scheme.lower() == "file":  # file:///abs/path, or file:/abs/path (RFC 8089)
        if parsed.netloc not in ("", "localhost"):
            raise ValidationError(
                f"{name} must be a local path or a file:///absolute/path URL, got {text!r} (it names the host "
                f"{parsed.netloc!r}; write file:/// with three slashes for an absolute path)"
            )
        text = parsed.path
    elif len(parsed.scheme) > 1 and text[len(parsed.scheme) + 1 : len(parsed.scheme) + 3] != "//" and ":/" in text:
        raise ValidationError(f"{name} must be a local path or a URL scheme://…, got {text!r} (one slash after the "
                              f"scheme {parsed.scheme!r}: did you mean {parsed.scheme}://?)")  # fmt: skip
    if not text:
        raise ValidationError(f"{name} must name a file or folder, got {str(path)!r}")
    # joined to the working folder, not normalised: "link/../x" is x beside the link's target, as the system
    # opens it, and os.path.abspath would make it x beside the link
    return os.path.join(os.getcwd(), text)


def store_directory(path, name="store") -> str:
    """The absolute local directory of a store location for writing (:func:`local_path`; ``file://`` URLs
    accepted; object stores refused).

    Parameters
    ----------
    path : str or os.PathLike
        The store's location.
    name : str
        The argument's name in messages (default ``"store"``).

    Returns
    -------
    str
        The absolute path, as :func:`local_path` gives it.

    Raises
    ------
    StoreError
        ``path`` is a URL (:func:`is_url`) of an object store.
    ValidationError
        As :func:`local_path`.
    """
    text = str(path)
    if is_url(text):
        raise StoreError(
            f"{name} {text!r} is on an object store: a store commits subjects by an atomic rename under a POSIX "
            "lock, which object stores do not have, so facestats does not write stores there (two workers' "
            "commits could overwrite each other). Build into a directory on a shared POSIX file system and "
            "upload it afterwards."
        )
    return local_path(text, name)


class Outcome:
    """A finished task's result or exception, held by the client: its future is released on the cluster, so a
    worker lost later does not make the scheduler compute it again.

    Parameters
    ----------
    future : distributed.Future
        A finished future: its ``status`` is kept and its result (or the exception it raises: a task lost with
        its worker, ``KilledWorker``, or cancelled) taken now, then it is released.
    """

    def __init__(self, future):
        self.status = future.status
        try:
            self._value, self._error = future.result(), None
        except BaseException as exc:  # the task was lost with its worker (KilledWorker), or cancelled
            self._value, self._error = None, exc
        future.release()

    def result(self, timeout=None):
        """The task's result; its exception raised again if it was lost (``timeout``, as a future's, is moot).

        Parameters
        ----------
        timeout : float, optional
            Ignored: the result is already held (accepted so that an outcome stands in for a future).

        Returns
        -------
        object
            What the task returned.
        """
        if self._error is not None:
            raise self._error
        return self._value


def run_tasks(client, task, tasks, progress=False, desc="build", poll_s: float = 5.0, grace_s: float = 60.0):
    """Run ``task(*t)`` for every tuple ``t`` of ``tasks`` on ``client``; return their outcomes, in order.

    ``task`` must never raise (it reports its own failures in its result), so a future in error is a task
    lost with its worker: Dask resubmits such a task until ``distributed.scheduler.allowed-failures`` deaths
    of workers that held it, then raises ``KilledWorker``.  The scheduler cannot tell which task killed a
    worker and counts the death against every task the worker held, so a subject sharing a worker with one
    that runs it out of memory is lost too.  Each lost task is therefore submitted again after the others,
    alone on the cluster, so that only its own deaths count.  The finished tasks' results are taken to the
    client first (:class:`Outcome`), so that a worker the lone task kills takes no finished result with it.
    A lone task is not submitted to a cluster left without workers for ``grace_s`` seconds, and one whose cluster
    stays without a worker that long while it waits is cancelled: both keep their first outcome.

    Parameters
    ----------
    client : distributed.Client
    task : callable
        Picklable by reference; never raises.
    tasks : list of tuple
        The arguments of each task.
    progress : bool
        A bar per round, over the subjects (the second one, ``"<desc> again, alone"``, only if a task was lost).
    desc : str
        The bars' label.
    poll_s : float
        Seconds between the checks that a lone task's cluster still has workers.
    grace_s : float
        Seconds a cluster without workers is given to get one (a nanny restarts a dead worker in a second or two).

    Returns
    -------
    list of Outcome
        One per tuple of ``tasks``: :meth:`Outcome.result` gives the task's result or raises its loss.
    """
    from distributed import as_completed, wait

    futures = [client.submit(task, *t, pure=False) for t in tasks]
    for _ in subject_bar(as_completed(futures, loop=client.loop), len(futures), progress, desc=desc):
        pass
    outcomes = [Outcome(f) for f in futures]
    lost = [i for i, o in enumerate(outcomes) if o.status == "error"] if len(outcomes) > 1 else []
    for i in subject_bar(lost, len(lost), progress, desc=f"{desc} again, alone"):
        if not _workers_within(client, grace_s):
            continue  # no worker left to run it: its first outcome stands
        future = client.submit(task, *tasks[i], pure=False)
        while True:
            try:
                wait(future, timeout=poll_s)
                break
            except TimeoutError:  # (distributed's is the built-in one)
                if not _workers_within(client, grace_s):
                    future.cancel()
                    future = None
                    break
        if future is not None:
            outcomes[i] = Outcome(future)
    return outcomes


def _workers_within(client, grace_s) -> bool:
    """Whether the cluster has a worker, or gets one within ``grace_s`` seconds (a nanny restarting a dead one)."""
    if client.scheduler_info().get("workers"):
        return True
    try:
        client.wait_for_workers(1, timeout=grace_s)
    except TimeoutError:
        return False
    return True
