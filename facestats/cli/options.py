"""Options several command groups share, and how a ``--store`` value opens a store."""

from __future__ import annotations

__all__ = ["add_store_option", "store_path_option", "open_store_option", "TEXTURE_SAMPLE"]

#: The ``--store`` value that names the texture sample (:mod:`facestats.pipeline.texture_sample`);
#: a directory of that name is written ``./texture-sample``.
TEXTURE_SAMPLE = "texture-sample"


def add_store_option(
    parser,
    help="a store directory (X.zarr) or zip, or texture-sample (six subjects with 512² maps, built once into "
    "the cache); default: the store embedded in facestats",
):
    """``--store PATH`` (default None: the embedded store)."""
    parser.add_argument("--store", default=None, metavar="PATH", help=help)


def store_path_option(value):
    """The store a ``--store`` value names: None (the embedded default), the texture sample's zip
    (built into the cache on first use) for ``texture-sample``, else ``value`` itself."""
    if value == TEXTURE_SAMPLE:
        from facestats.pipeline.texture_sample import texture_sample

        return str(texture_sample())
    return value


def open_store_option(value, mode: str = "r"):
    """:func:`facestats.open_store` of what a ``--store`` value names (:func:`store_path_option`)."""
    from facestats.io.store import open_store

    return open_store(store_path_option(value), mode=mode)
