"""facestats.io: the Zarr parameter store, its population index, queries and file formats.

* :func:`open_store` / :class:`Store` (:mod:`facestats.io.store`): one Zarr v3
  group per subject (an xarray Dataset following :mod:`facestats.io.schema`),
  a population index of per-subject summaries (:mod:`facestats.io.summary`,
  :mod:`facestats.io.index`), atomic per-subject writes with file locking
  (:mod:`facestats.io.locking`), integrity checks on read, and read-only zip
  stores (:func:`pack_store`, the embedded default).  The store's parts, one
  job each: :mod:`~facestats.io.layout` (file names, generation names, durable
  writes), :mod:`~facestats.io.root` (creating a store, its root group),
  :mod:`~facestats.io.backends` (directory and zip access),
  :mod:`~facestats.io.integrity` (manifest and checked reads),
  :mod:`~facestats.io.generations` (writing one generation),
  :mod:`~facestats.io.batch` (checking and committing a write),
  :mod:`~facestats.io.maintenance` (gc, validation, repair),
  :mod:`~facestats.io.packing` (:func:`pack_store`), :mod:`~facestats.io.ids`
  (the subject-id rule).
* :class:`QueryResult` (:mod:`facestats.io.query`): the §7 "applet" statistics
  of the subjects matching skin type, gender, age and condition.
* :mod:`facestats.io.export`: the public statistics release (CSV/JSON).
* :mod:`facestats.io.merl`: the MERL/ETH Skin Reflectance Database ``ts_data.mat``.
* :mod:`facestats.io.mesh`: real face scans (OBJ/PLY with UVs) as geometries.
* :func:`read_light_probe` (:mod:`facestats.io.probes`): light probes (Radiance,
  OpenEXR, PFM) in lat-long or angular layout (one-light-at-a-time folders are read
  as reflectance fields by :mod:`facestats.relight.olat`).

Importing this package loads numpy only; xarray, zarr and pandas are imported
when a subject or a DataFrame is needed.
"""

from facestats.io.packing import pack_store
from facestats.io.probes import read_light_probe
from facestats.io.query import QueryResult
from facestats.io.store import Store, open_store

__all__ = ["open_store", "Store", "QueryResult", "pack_store", "read_light_probe"]
