"""The texture sample: a few subjects with 512² maps, so the paper's texture transfer runs from a fresh install.

Weyrich et al. 2006 §8 transfer texture with a steerable pyramid of 7 levels and
4 orientations (23,808 histogram values).  The embedded default store holds
48 × 48 maps, on which at most 3 levels fit (:func:`facestats.edit.pyramid.max_levels`).
The texture sample holds the ground truth of six subjects of
the synthetic population (:func:`facestats.acquire.synthetic.population.synthesize_population`,
seed :data:`~facestats.core.conventions.DEFAULT_SEED`) drawn at
:data:`TEXTURE_SAMPLE_SIZE`² on the procedural face: albedo with pores,
freckles and moles, one subject per Fitzpatrick skin type
(:data:`TEXTURE_SAMPLE_SUBJECTS`).  The procedural head rather than the default's
ICT face: its UV layout fills 68 % of the map (ICT's 37 %, in islands), which gives
the 7-level pyramid of the texture transfer large connected regions.  Its maps are the generator's truth, not fits
(``provenance["source"]`` says so; flags are all zero): a texture source, not
a measurement.

It is made on demand rather than shipped: six subjects at 512² pack to about
27 MB of zip (the noise of pores does not compress), against a 10 MB budget for
package data, while drawing them takes about 8 s.  :func:`texture_sample` builds
it once into the user's cache (:func:`cache_dir`) as a read-only zip store
named by the fingerprint of the facestats sources
(:func:`facestats.core.version.source_fingerprint`), so a copy made by other
code is rebuilt, never reused.  It is deterministic: the same code draws the
same subjects bit for bit (:func:`build_texture_sample`; only the store's
timestamps and generation names differ).  On the command line ``--store texture-sample``
opens it (:func:`facestats.cli.options.open_store_option`).
"""

from __future__ import annotations

import json
import os
import pathlib
import shutil
import sys
import tempfile

import numpy as np

from facestats.core.conventions import DEFAULT_SEED
from facestats.core.validate import check_integer
from facestats.core.version import __version__, source_fingerprint
from facestats.errors import StoreError

__all__ = [
    "TEXTURE_SAMPLE_SIZE",
    "TEXTURE_SAMPLE_SUBJECTS",
    "cache_dir",
    "texture_sample_datasets",
    "build_texture_sample",
    "texture_sample",
]

#: Side of the sample's maps: 7 pyramid levels need ≥ 4 · 2⁶ = 256; 512 leaves the coarsest band 8 texels.
TEXTURE_SAMPLE_SIZE = 512

#: One subject per skin type I-VI (seed 2006): S030 (I, F, freckles, 3 moles), S021 (II, M, freckles,
#: 1 mole), S034 (III, F, freckles, 2 moles), S001 (IV, M, 2 moles), S006 (V, F, 1 mole), S015 (VI, F).
TEXTURE_SAMPLE_SUBJECTS = ("S030", "S021", "S034", "S001", "S006", "S015")


def cache_dir() -> pathlib.Path:
    """Where facestats keeps what it makes once: ``$FACESTATS_CACHE_DIR``, else ``$XDG_CACHE_HOME/facestats``,
    else ``~/.cache/facestats`` (not created here)."""
    if os.environ.get("FACESTATS_CACHE_DIR"):
        return pathlib.Path(os.environ["FACESTATS_CACHE_DIR"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache"
    return pathlib.Path(base).expanduser() / "facestats"


def texture_sample_datasets(*, size: int = TEXTURE_SAMPLE_SIZE, subjects=TEXTURE_SAMPLE_SUBJECTS, seed=DEFAULT_SEED):
    """The sample's subjects as store Datasets (map subjects of :mod:`facestats.io.schema`).

    Parameters
    ----------
    size : int
        Map side in texels (≥ 16).
    subjects : sequence of str
        Population subject ids (``"S001"`` … ``"S149"``).
    seed : int
        Population seed.

    Returns
    -------
    list of xarray.Dataset
        Each the subject's truth (:meth:`SubjectTruth.to_dataset`) with zero ``ts_flag`` and
        ``bp_flag`` maps, the head's own ``normal`` map (the procedural face's normals,
        0 off the face) and a provenance naming the generator, its seed, size, the
        head (``geometry`` = ``procedural-N``, which export rebuilds) and the
        subject's drawn features (freckles, moles, melanin).
    """
    from facestats.acquire.synthetic.population import synthesize_population
    from facestats.face.procedural import procedural_face
    from facestats.io.schema import set_variable_attrs

    check_integer(size, "size", 16)
    geometry = procedural_face(size)
    population = synthesize_population(seed, size, geometry=geometry, conditions=False, subjects=list(subjects))
    out = []
    for sid in subjects:
        truth = population[sid]
        ds = truth.to_dataset()
        for model in ("ts", "bp"):
            ds[f"{model}_flag"] = (("v", "u"), np.zeros((size, size), np.uint8))
        normal = np.zeros((size, size, 3), np.float32)  # the head's own normals (no micro-geometry); 0 off the face
        normal[geometry.grid_index[:, 0], geometry.grid_index[:, 1]] = geometry.normal
        ds["normal"] = (("v", "u", "component"), normal)
        ds.attrs = dict(truth.metadata())
        ds.attrs["provenance"] = json.dumps(
            {
                "source": "facestats population generator (ground truth, not fitted)",
                "generator": "facestats.acquire.synthetic.population.synthesize_population",
                "seed": int(seed),
                "map_size": int(size),
                "geometry": geometry.name,  # procedural-N: export rebuilds this head
                "features": dict(truth.features),
                "software": f"facestats {__version__}",
            },
            sort_keys=True,
        )
        out.append(set_variable_attrs(ds))
    return out


def build_texture_sample(path, *, size: int = TEXTURE_SAMPLE_SIZE, subjects=TEXTURE_SAMPLE_SUBJECTS) -> pathlib.Path:
    """Write the texture sample as a zip store at ``path`` (replaced atomically if it exists).

    Deterministic: the draws are seeded, so the same code writes the same subjects bit for bit
    (the store's creation time and generation names differ between builds).

    Parameters
    ----------
    path : str or os.PathLike
        The zip file to write (its folder is created if missing).
    size : int
        Map side in texels, ≥ 16 (default 512).
    subjects : sequence of str
        Population subject ids (default :data:`TEXTURE_SAMPLE_SUBJECTS`, one per skin type I-VI).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    from facestats.io.packing import pack_store
    from facestats.io.store import open_store

    path = pathlib.Path(path)
    datasets = texture_sample_datasets(size=size, subjects=subjects)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = pathlib.Path(tempfile.mkdtemp(prefix=".texture-sample-", dir=path.parent))
    try:
        with open_store(tmp / "sample.zarr", mode="a") as store:
            store.write_subjects(datasets)
        pack_store(tmp / "sample.zarr", tmp / "sample.zip")
        os.replace(tmp / "sample.zip", path)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return path


def texture_sample(*, rebuild: bool = False, quiet: bool = False) -> pathlib.Path:
    """The path of the texture sample (a read-only zip store), built into :func:`cache_dir` when absent.

    The file is ``texture-sample-<fingerprint[:16]>.zip``; samples of other facestats sources in the
    cache are removed when a new one is built.  Building takes about 8 s and writes about 27 MB.

    Parameters
    ----------
    rebuild : bool
        Build even if a current copy exists.
    quiet : bool
        Do not tell stderr that the sample is being built.

    Returns
    -------
    pathlib.Path
        The sample's path.

    Raises
    ------
    StoreError
        If the cache directory cannot be written (set ``FACESTATS_CACHE_DIR``).
    """
    folder = cache_dir()
    path = folder / f"texture-sample-{source_fingerprint()[:16]}.zip"
    if path.is_file() and not rebuild:
        return path
    if not quiet:
        print(f"facestats: building the texture sample (6 subjects at 512², ~10 s, once) in {path}", file=sys.stderr)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        build_texture_sample(path)
    except OSError as exc:
        raise StoreError(
            f"cannot write the texture sample to {folder} ({exc.strerror}): set FACESTATS_CACHE_DIR to a "
            "writable directory"
        ) from None
    for old in folder.glob("texture-sample-*.zip"):
        if old != path:
            old.unlink(missing_ok=True)
    return path
