"""Options several command groups share."""

from __future__ import annotations

__all__ = ["add_store_option"]


def add_store_option(parser, help="a store directory (X.zarr) or zip; default: the store embedded in facestats"):
    """``--store PATH`` (default None: the embedded store)."""
    parser.add_argument("--store", default=None, metavar="PATH", help=help)
