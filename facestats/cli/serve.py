"""``facestats serve``: the statistics web application on a local port (:mod:`facestats.web`)."""

from __future__ import annotations

from facestats.cli.options import add_store_option, ascii_int, named_options, store_path_option

__all__ = ["add_serve"]


def _cmd_serve(args) -> int:
    from facestats.web import serve

    def ready(url):
        print(f"facestats: serving {args.store or 'the default store'} read-only at {url} (Ctrl-C to stop)", flush=True)

    try:
        with named_options(host="--host", port="--port", path="--store"):
            serve(store_path_option(args.store), host=args.host, port=args.port, ready=ready)
    except OSError as exc:
        from facestats.errors import ValidationError

        raise ValidationError(f"cannot listen on {args.host}:{args.port}: {exc.strerror or exc}") from None
    return 0


def add_serve(sub):
    """Register ``facestats serve``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handler (``func``) serves until Ctrl-C (:func:`facestats.cli.main` then exits 130); an address it cannot
        listen on raises a :class:`~facestats.errors.ValidationError` (exit 2).
    """
    p = sub.add_parser(
        "serve",
        help="the population statistics as a local web application (filters, tables, plots, subject pages)",
        description=(
            "Serve a store read-only in the browser: the statistics of facestats query for any skin type, gender, "
            "age, condition and region as tables and plots (albedo histograms, per-region BRDF bars, PCA ellipses "
            "of Fig. 15, sigma_a-sigma_s' scatter of Fig. 14), subject pages with maps and a relit preview, and "
            "JSON/CSV/EXR downloads. Needs Flask: pip install 'facestats[web]'."
        ),
    )
    add_store_option(p)
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=ascii_int, default=8000, help="port (default 8000; 0 picks a free one)")
    p.set_defaults(func=_cmd_serve)
