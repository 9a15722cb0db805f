"""facestats.web: the population statistics in a browser — the interactive applet of Weyrich et al. 2006 §7.

:func:`create_app` (:mod:`facestats.web.app`) builds a Flask application over a
read-only store: filters by skin type, gender, age, condition and region; the
``facestats query`` statistics as tables and SVG plots (albedo histograms,
per-region BRDF bars, the PCA ellipses of Fig. 15, the σa–σ's scatter of Fig.
14); subject pages with maps and a relit preview; JSON, CSV and EXR downloads.
:func:`serve` runs it on a local port (``facestats serve``).  Flask is an
optional dependency: ``pip install 'facestats[web]'``.
"""

from __future__ import annotations

from facestats.errors import ValidationError

__all__ = ["create_app", "serve", "make_server"]


def create_app(store=None, *, preload=True, allowed_hosts=None):
    """The Flask app over ``store``; see :func:`facestats.web.app.create_app` (imported on first call).

    Parameters
    ----------
    store : str, os.PathLike, Store or None
        Store path or a read-only :class:`~facestats.io.store.Store` (None: the embedded default).
    preload : bool
        Start reading the region samples for Fig. 15 in the background now.
    allowed_hosts : iterable of str, optional
        Host names a request's ``Host`` header may carry (others get 400; default: any).

    Returns
    -------
    flask.Flask

    Raises
    ------
    DependencyError
        If Flask is not installed.
    StoreError
        If a given :class:`~facestats.io.store.Store` is not read-only, or the path cannot be opened
        (:func:`facestats.io.store.open_store`).
    """
    # local import: keeps 23 modules out of this module's import
    from facestats.web.app import create_app as _create_app

    return _create_app(store, preload=preload, allowed_hosts=allowed_hosts)


#: Host names of this machine's loopback interface.
LOOPBACK = ("127.0.0.1", "localhost", "::1")


def _check_host(host):
    """``host`` as a non-empty address (an empty one would bind every interface)."""
    if not isinstance(host, str) or not host.strip() or host != host.strip():
        raise ValidationError(
            f"host must be an address such as 127.0.0.1 (an empty one binds every network interface), got {host!r}"
        )
    return host


def make_server(app, host: str = "127.0.0.1", port: int = 8000):
    """A threaded WSGI server (werkzeug) for ``app`` bound to ``host:port`` (port 0: any free port).

    Parameters
    ----------
    app : callable
        The WSGI application, e.g. :func:`create_app`'s.
    host : str
        Address to listen on (a non-empty name or address of this machine).
    port : int
        Port to listen on, 0-65535 (0: any free port).

    Returns
    -------
    werkzeug.serving.BaseWSGIServer
        ``server.server_port`` is the bound port; call ``serve_forever()`` / ``shutdown()``.

    Raises
    ------
    ValidationError
        A port out of range, an empty host, a host that does not resolve, or an address in use or not available.
    """
    from werkzeug.serving import make_server as _make_server

    # local import: keeps numpy out of this module's import
    from facestats.core.validate import check_integer

    check_integer(port, "port", 0, 65535)
    _check_host(host)
    import socket

    try:  # werkzeug would print its own message and exit: resolve first to name the host
        socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise ValidationError(f"host {host!r} is not an address of this machine: {exc.strerror}") from None
    try:
        return _make_server(host, port, app, threaded=True)
    except SystemExit:  # werkzeug exits when the address is taken; say so as every facestats error does
        raise ValidationError(f"cannot listen on {host}:{port}: the address is in use or not available") from None


def serve(store=None, *, host: str = "127.0.0.1", port: int = 8000, ready=None):
    """Serve the web app until interrupted (binds to 127.0.0.1 unless ``host`` is given).

    Parameters
    ----------
    store : str, os.PathLike or None
        Store to serve read-only (None: the embedded default).
    host, port
        Where to listen.
    ready : callable, optional
        Called with the URL once the server listens.
    """
    _check_host(host)
    local = host in LOOPBACK or host.startswith("127.")
    # On loopback, only requests addressed to this machine's names (no DNS rebinding through another name).
    allowed = set(LOOPBACK) | {host} if local else None
    server = make_server(create_app(store, allowed_hosts=allowed), host, port)
    if not local:
        import warnings

        warnings.warn(
            f"serving on {host}, not on loopback: anyone who can reach this machine on port {server.server_port} "
            "can read the store",
            stacklevel=2,
        )
    url = f"http://{f'[{host}]' if ':' in host else host}:{server.server_port}/"  # an IPv6 address in brackets
    if ready is not None:
        ready(url)
    try:
        server.serve_forever()
    finally:
        server.server_close()
