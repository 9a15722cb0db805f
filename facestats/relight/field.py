"""The reflectance field data model: an xarray Dataset of one image per light, its coordinates, and its zarr store.

A *reflectance field* (Debevec et al. 2000 §2.1, §3.2 eq. 2) from one camera is
the image of the subject under each light of a light stage, normalised per unit
incident light: R_xy(θ, φ) = L_θφ(x, y) / (L δA)_θφ, so that relighting is the
weighted sum of eq. 4.  In facestats it is an :class:`xarray.Dataset`:

* ``reflectance`` — dims (``light``, ``y``, ``x``, ``channel``) for an arbitrary
  light set, or (``light_phi``, ``light_theta``, ``y``, ``x``, ``channel``) for a
  light stage on a lat-long grid (Debevec's 32 × 64).  Values are pixel
  radiance per unit irradiance L·δA of a white light, sr⁻¹ (a Lambertian
  surface of albedo ρ has R = ρ/π max(N·l, 0)), linear RGB, float32 (or float16
  on disk).
* coordinates on the light dims: ``direction`` (light dims, ``component``) unit
  vectors from the surface **towards** each light in the world frame of
  :mod:`facestats.model.sphere`; ``solid_angle`` (light dims) the δA each light
  stands for, sr; ``intensity`` (light dims, ``channel``) the RGB irradiance of
  each light during the capture, by which the raw images were divided (1 for a
  synthetic stage).
* optional per-pixel variables: ``mask`` (y, x) pixels that see the subject;
  ``view`` (y, x, component) unit vectors towards the camera; ``normal``,
  ``position`` (mm) when the geometry is known.
* attributes: ``units`` of ``reflectance``, ``source`` and, for grids,
  ``layout = "latlong"`` (the light grid is :func:`facestats.model.sphere.light_stage_directions`).

On disk (:func:`write_field` / :func:`open_field`) the field is a zarr group
whose ``reflectance`` is chunked as whole light sets over image tiles
(all lights × ``tile`` × ``tile`` × 3), so one tile under every light reads alone
and fields larger than memory are relit tile by tile
(:func:`facestats.relight.relighting.relight`).
"""

from __future__ import annotations

import os
import pathlib
import shutil
import uuid

import numpy as np

from facestats.core.conventions import CHANNELS, COMPONENTS
from facestats.core.validate import (
    as_finite,
    as_float,
    check_choice,
    check_finite,
    check_integer,
    check_range,
    check_shape,
    check_unit_vectors,
)
from facestats.errors import StoreError, ValidationError
from facestats.model.sphere import latlong_directions, latlong_solid_angles, unit_directions, voronoi_solid_angles

__all__ = [
    "GRID_DIMS",
    "LIST_DIMS",
    "COMPONENTS",
    "make_field",
    "as_field",
    "light_dims",
    "is_grid",
    "flatten_lights",
    "light_table",
    "write_field",
    "open_field",
    "FieldStore",
    "image_tiles",
]

GRID_DIMS = ("light_phi", "light_theta")
LIST_DIMS = ("light",)
_UNITS = "sr-1"


def make_field(
    values,
    directions,
    solid_angles=None,
    intensity=None,
    *,
    mask=None,
    view=None,
    normal=None,
    position=None,
    attrs=None,
):
    """A reflectance field Dataset from an array of images and its light set (module docstring).

    Parameters
    ----------
    values : array_like, shape (L, H, W, 3) or (n_phi, n_theta, H, W, 3)
        One image per light, already divided by the light's irradiance (sr⁻¹),
        finite and ≥ 0.  Kept as float32 (float16 input stays float16).
    directions : array_like, shape (L, 3) or (n_phi, n_theta, 3)
        Unit vectors towards the lights.  A 3-D array makes a grid field, which
        must be the lat-long light stage of :func:`light_stage_directions`.
    solid_angles : array_like, optional
        δA per light (sr).  Default: exact lat-long cells for a grid, spherical
        Voronoi cells (:func:`facestats.model.sphere.voronoi_solid_angles`) for a list.
        Used by sums over the lights (ρs of the separation, the compression's weights);
        relighting by a probe integrates the probe over the lights' own cells
        (:func:`facestats.relight.relighting.lighting_for`), whatever is given here.
    intensity : array_like, shape (light dims) or (light dims, 3), optional
        RGB irradiance of each light in the capture (default 1).
    mask : array_like of bool, shape (H, W), optional
    view, normal, position : array_like, shape (H, W, 3), optional
        ``view`` and ``normal``: unit vectors (norm 1 ± 1e-3), or 0 where there is no surface.
    attrs : dict, optional
        Extra attributes (JSON-serialisable).

    Returns
    -------
    xarray.Dataset
    """
    import xarray as xr

    r = np.asarray(values)
    grid = np.ndim(directions) == 3
    ldims = GRID_DIMS if grid else LIST_DIMS
    nl = len(ldims)
    if r.ndim != nl + 3 or r.shape[-1] != 3:
        want = "(n_phi, n_theta, H, W, 3)" if grid else "(L, H, W, 3)"
        raise ValidationError(
            f"values must have shape {want} for directions of shape {np.shape(directions)}, got {r.shape}"
        )
    if r.size == 0:
        raise ValidationError(f"values must hold at least one light and one pixel, got shape {r.shape}")
    r = as_finite(r, "values", dtype=np.float16 if r.dtype == np.float16 else np.float32)
    check_range(r, "values", 0, None, unit="sr-1")
    lshape = r.shape[:nl]
    d = unit_directions(directions)
    check_shape(d, "directions", lshape + (3,))
    if grid and not np.allclose(d, latlong_directions(*lshape), atol=1e-6):
        raise ValidationError(
            f"directions of a grid field must be the lat-long light stage of shape {lshape} "
            "(facestats.model.sphere.light_stage_directions); pass a flat (L, 3) list for other light sets"
        )
    if solid_angles is None:
        sa = latlong_solid_angles(*lshape) if grid else voronoi_solid_angles(d)
    else:
        sa = check_shape(as_finite(solid_angles, "solid_angles", dtype=np.float64), "solid_angles", lshape)
        check_range(sa, "solid_angles", 0, 4 * np.pi, low_inclusive=False, unit="sr")
    inten = np.ones(lshape + (3,)) if intensity is None else as_finite(intensity, "intensity", dtype=np.float64)
    if inten.shape == lshape:
        inten = np.repeat(inten[..., None], 3, axis=-1)
    check_shape(inten, "intensity", lshape + (3,))
    check_range(inten, "intensity", 0, None, low_inclusive=False)
    h, w = r.shape[nl : nl + 2]
    coords = {
        "channel": list(CHANNELS),
        "component": list(COMPONENTS),
        "direction": (ldims + ("component",), d),
        "solid_angle": (ldims, sa),
        "intensity": (ldims + ("channel",), inten),
    }
    ds = xr.Dataset({"reflectance": (ldims + ("y", "x", "channel"), r)}, coords=coords)
    ds["reflectance"].attrs.update(units=_UNITS, long_name="pixel radiance per unit irradiance L·δA of each light")
    if grid:
        ds.attrs["layout"] = "latlong"
    for name, arr in (("view", view), ("normal", normal), ("position", position)):
        if arr is not None:
            ds[name] = (("y", "x", "component"), _pixel_vectors(arr, name, (h, w)))
    if mask is not None:
        m = np.asarray(mask, bool)
        check_shape(m, "mask", (h, w))
        ds["mask"] = (("y", "x"), m)
    ds.attrs.update(attrs or {})
    return ds


def _pixel_vectors(arr, name, size) -> np.ndarray:
    """A (H, W, 3) float32 map of ``make_field``; ``view`` and ``normal`` hold unit vectors or 0 (no surface)."""
    a = check_shape(as_finite(arr, name, dtype=np.float32), name, size + (3,))
    if name != "position":
        check_unit_vectors(a, name, allow_zero=True)
    return a


def as_field(field):
    """Validate a reflectance field (Dataset, or a DataArray of its ``reflectance``) and return it as a Dataset.

    Only the structure is checked: the dims of ``reflectance`` and the presence of the ``direction`` and
    ``solid_angle`` coordinates (not the values; a DataArray must carry those coordinates itself).

    Parameters
    ----------
    field : xarray.Dataset or xarray.DataArray
        The field, or its ``reflectance`` with the light coordinates.

    Returns
    -------
    xarray.Dataset
        ``field`` itself, or the DataArray as a Dataset with variable ``reflectance``.

    Raises
    ------
    ValidationError
        If ``field`` is neither, ``reflectance`` has other dims, or a coordinate is missing.
    """
    import xarray as xr

    if isinstance(field, xr.DataArray):
        field = field.to_dataset(name="reflectance")
    if not isinstance(field, xr.Dataset) or "reflectance" not in field.data_vars:
        raise ValidationError(
            f"field must be a reflectance-field Dataset with a 'reflectance' variable, got {type(field).__name__}"
        )
    dims = tuple(field["reflectance"].dims)
    if dims not in (LIST_DIMS + ("y", "x", "channel"), GRID_DIMS + ("y", "x", "channel")):
        raise ValidationError(
            f"field 'reflectance' must have dims {LIST_DIMS + ('y', 'x', 'channel')} or "
            f"{GRID_DIMS + ('y', 'x', 'channel')}, got {dims}"
        )
    for name in ("direction", "solid_angle"):
        if name not in field.coords:
            raise ValidationError(f"field must carry the light coordinate {name!r}")
    return field


def light_dims(field) -> tuple:
    """The light dims of a field: ``("light",)`` or ``("light_phi", "light_theta")``.

    Parameters
    ----------
    field : xarray.Dataset or xarray.DataArray
        A reflectance field, or its ``reflectance`` variable (:func:`as_field`).

    Returns
    -------
    tuple of str
        :data:`LIST_DIMS` or :data:`GRID_DIMS`.

    Raises
    ------
    ValidationError
        If ``field`` is not a reflectance field (:func:`as_field`).
    """
    return GRID_DIMS if "light_phi" in as_field(field)["reflectance"].dims else LIST_DIMS


def is_grid(field) -> bool:
    """True for a lat-long light-stage field (dims ``light_phi``, ``light_theta``).

    Parameters
    ----------
    field : xarray.Dataset or xarray.DataArray
        A reflectance field, or its ``reflectance`` variable (:func:`as_field`).

    Returns
    -------
    bool

    Raises
    ------
    ValidationError
        If ``field`` is not a reflectance field (:func:`as_field`).
    """
    return light_dims(field) == GRID_DIMS


def light_table(field):
    """The light set of a field as flat arrays: ``(directions (L, 3), solid_angles (L,), intensity (L, 3))``.

    Parameters
    ----------
    field : xarray.Dataset or xarray.DataArray
        A reflectance field, or its ``reflectance`` variable (:func:`as_field`).

    Returns
    -------
    directions : numpy.ndarray, shape (L, 3)
        The ``direction`` coordinate (unit vectors towards the lights), float64; a grid's in row-major (φ, θ) order.
    solid_angles : numpy.ndarray, shape (L,)
        δA per light, sr.
    intensity : numpy.ndarray, shape (L, 3)
        RGB irradiance of each light in the capture (ones when the field has no ``intensity``).

    Raises
    ------
    ValidationError
        If ``field`` is not a reflectance field (:func:`as_field`).
    """
    f = as_field(field)
    nl = len(light_dims(f))
    d = np.asarray(f["direction"].values, np.float64)
    sa = np.asarray(f["solid_angle"].values, np.float64)
    it = np.asarray(f["intensity"].values, np.float64) if "intensity" in f.coords else np.ones(d.shape)
    n = int(np.prod(d.shape[:nl]))
    return d.reshape(n, 3), sa.reshape(n), it.reshape(n, 3)


def flatten_lights(field):
    """A grid field with its two light dims stacked into one ``light`` dim (row-major: φ then θ); lists unchanged.

    Parameters
    ----------
    field : xarray.Dataset or xarray.DataArray
        A reflectance field, or its ``reflectance`` variable (:func:`as_field`).

    Returns
    -------
    xarray.Dataset
        For a grid: ``reflectance`` with dims (``light``, ``y``, ``x``, ``channel``), no ``light`` index, the
        ``layout`` attribute dropped and ``grid_shape`` = [n_phi, n_theta] added.  A list field is returned as is.

    Raises
    ------
    ValidationError
        If ``field`` is not a reflectance field (:func:`as_field`).
    """
    f = as_field(field)
    if not is_grid(f):
        return f
    n_phi, n_theta = f.sizes["light_phi"], f.sizes["light_theta"]
    out = f.stack(light=GRID_DIMS).drop_vars(["light", "light_phi", "light_theta"], errors="ignore")
    out = out.transpose("light", ...)
    out["reflectance"] = out["reflectance"].transpose("light", "y", "x", "channel")
    out.attrs = {k: v for k, v in f.attrs.items() if k != "layout"}
    out.attrs["grid_shape"] = [int(n_phi), int(n_theta)]
    return out


# -- zarr ------------------------------------------------------------------------------------
def _strings_as_objects(ds):
    """String coordinates as object arrays (zarr stores those as variable-length strings, a stable v3 type)."""
    for name in list(ds.coords):
        if ds[name].dtype.kind in "US":
            ds = ds.assign_coords({name: ds[name].copy(data=np.asarray(ds[name].values).astype(object))})
    return ds


def _strings_as_str(ds):
    """Variable-length strings read back from zarr as numpy ``str`` coordinates."""
    for name in list(ds.coords):
        if ds[name].dtype.kind in "OT":
            ds = ds.assign_coords({name: ds[name].copy(data=np.asarray(ds[name].values).astype(object).astype(str))})
    return ds


def write_field(path, field, *, dtype="float32", tile: int = 64, overwrite: bool = False):
    """Write a reflectance field to a zarr store, chunked as all lights × ``tile`` × ``tile`` × 3.

    The store is written to a temporary sibling directory and moved into place
    when complete, so a failed write leaves nothing behind and an existing
    store is only replaced with ``overwrite=True`` (and only once the new one is
    complete).

    Parameters
    ----------
    path : str or path-like
        Directory of the zarr store (conventionally ``*.zarr``).
    field : xarray.Dataset
    dtype : {"float32", "float16"}
        Storage type of ``reflectance`` (float16 halves the size; its 11-bit
        mantissa keeps 3 significant digits, ample for 8-16-bit source images).
    tile : int
        Image tile side of the chunks (≥ 1).
    overwrite : bool

    Returns
    -------
    pathlib.Path
    """
    f = as_field(field)
    check_choice(dtype, "dtype", ("float32", "float16"))
    t = check_integer(tile, "tile", 1)
    p = pathlib.Path(os.fspath(path))
    if p.exists() and not overwrite:
        raise StoreError(f"field store {str(p)!r} already exists (pass overwrite=True, or --overwrite, to replace it)")
    if not bool(np.isfinite(f["reflectance"]).all()):
        raise ValidationError(f"field reflectance must be finite to write {str(p)!r}, got NaN or inf")
    if dtype == "float16":
        big = float(f["reflectance"].max())
        if big > float(np.finfo(np.float16).max):
            raise ValidationError(f"field values up to {big:g} overflow float16 (max 65504); write it as float32")
    ldims = light_dims(f)
    chunks = tuple(f.sizes[d] for d in ldims) + (min(t, f.sizes["y"]), min(t, f.sizes["x"]), 3)
    out = _strings_as_objects(f.copy())
    out["reflectance"] = out["reflectance"].astype(dtype).chunk(dict(zip(ldims + ("y", "x", "channel"), chunks)))
    encoding = {"reflectance": {"chunks": chunks, "fill_value": 0.0}}
    for name in out.data_vars:
        if name != "reflectance":
            encoding[name] = {"chunks": tuple(out[name].shape)}
    tmp = p.with_name(f".{p.name}.tmp-{uuid.uuid4().hex[:8]}")
    try:
        out.to_zarr(tmp, mode="w", encoding=encoding, consolidated=False, zarr_format=3)
        if p.exists():
            old = p.with_name(f".{p.name}.old-{uuid.uuid4().hex[:8]}")
            p.rename(old)
            tmp.rename(p)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(p)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return p


class FieldStore:
    """A field written to zarr tile by tile (for fields larger than memory); see :func:`write_field`.

    The store is created in a temporary sibling directory with every light
    coordinate and per-pixel variable; :meth:`write` fills ``reflectance`` one
    image tile (all lights) at a time; :meth:`close` moves the complete store
    into place and returns it opened lazily; :meth:`abort` removes it.  Tiles
    never written stay 0.

    Parameters
    ----------
    path : str or path-like
    directions : ndarray, shape (L, 3) or (n_phi, n_theta, 3)
    image_shape : (int, int)
    per_pixel : dict, optional
        ``mask``, ``view``, ``normal``, ``position`` images (:func:`make_field`).
    solid_angles, intensity, attrs : optional
        As :func:`make_field`.
    dtype : {"float32", "float16"}
    tile : int
    overwrite : bool
    """

    def __init__(self, path, directions, image_shape, *, per_pixel=None, solid_angles=None, intensity=None,
                 attrs=None, dtype="float32", tile=64, overwrite=False):  # fmt: skip
        import dask.array as da

        check_choice(dtype, "dtype", ("float32", "float16"))
        t = check_integer(tile, "tile", 1)
        self.path = pathlib.Path(os.fspath(path))
        if self.path.exists() and not overwrite:
            raise StoreError(
                f"field store {str(self.path)!r} already exists (pass overwrite=True, or --overwrite, to replace it)"
            )
        h, w = (check_integer(n, "image_shape", 1) for n in image_shape)
        d = np.asarray(directions, np.float64)
        lshape = d.shape[:-1]
        one = np.zeros(lshape + (1, 1, 3), np.float32)
        small = {k: np.asarray(v)[:1, :1] for k, v in (per_pixel or {}).items()}
        tmpl = make_field(one, d, solid_angles, intensity, attrs=attrs, **small)
        ldims = light_dims(tmpl)
        chunks = lshape + (min(t, h), min(t, w), 3)
        ds = tmpl.drop_vars(list(small)).isel(y=slice(0, 0), x=slice(0, 0))
        ds = ds.drop_vars("reflectance")
        ds["reflectance"] = (ldims + ("y", "x", "channel"), da.zeros(lshape + (h, w, 3), dtype=dtype, chunks=chunks))
        ds["reflectance"].attrs.update(tmpl["reflectance"].attrs)
        for k, v in (per_pixel or {}).items():
            ds[k] = (tmpl[k].dims, np.asarray(v))
        ds = _strings_as_objects(ds)
        self._dtype = np.dtype(dtype)
        self._tmp = self.path.with_name(f".{self.path.name}.tmp-{uuid.uuid4().hex[:8]}")
        # fill 0: the stage writes only the tiles that hold face pixels, and the rest read as the fill value (NaN by
        # default, so a relight of the whole image failed on them)
        encoding = {"reflectance": {"chunks": chunks, "fill_value": 0.0}}
        ds.to_zarr(self._tmp, mode="w", compute=False, encoding=encoding, consolidated=False, zarr_format=3)
        import zarr

        self._array = zarr.open_group(self._tmp, mode="r+")["reflectance"]
        self._nl = len(ldims)

    def write(self, ys: slice, xs: slice, block):
        """Store the values of all lights on the image tile ``[ys, xs]`` (block: light dims + (ty, tx, 3)).

        Parameters
        ----------
        ys, xs : slice
            The tile's rows and columns in the image.
        block : array_like, shape light dims + (ty, tx, 3)
            Reflectance of every light on the tile (light dims may also be given flat, (L, ty, tx, 3)); stored in
            the store's dtype.

        Raises
        ------
        ValidationError
            A value that is not finite, or overflows the dtype (float16).
        """
        name = f"field block [y {ys.start}:{ys.stop}, x {xs.start}:{xs.stop}]"
        b = check_finite(as_float(block, name, self._dtype), name)  # as_float: float16 overflow is an error
        b = b.reshape(tuple(self._array.shape[: self._nl]) + b.shape[-3:])
        self._array[(slice(None),) * self._nl + (ys, xs, slice(None))] = b.astype(self._dtype)

    def close(self):
        """Move the finished store into place (replacing an old one) and open it lazily."""
        if self.path.exists():
            old = self.path.with_name(f".{self.path.name}.old-{uuid.uuid4().hex[:8]}")
            self.path.rename(old)
            self._tmp.rename(self.path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            self._tmp.rename(self.path)
        return open_field(self.path)

    def abort(self):
        """Remove the unfinished store (nothing at ``path`` changes)."""
        shutil.rmtree(self._tmp, ignore_errors=True)


def open_field(path):
    """Open a field written by :func:`write_field`, lazily (dask arrays: tiles are read on demand).

    ``reflectance`` keeps its stored dtype until computed; relighting converts
    each tile to float32.

    Parameters
    ----------
    path : str or path-like
        Directory of the zarr store.

    Returns
    -------
    xarray.Dataset
        The field (checked by :func:`as_field`), string coordinates as ``str``.

    Raises
    ------
    StoreError
        If ``path`` is not a directory or cannot be opened as a zarr store.
    ValidationError
        If the store holds no reflectance field.
    """
    import xarray as xr

    p = pathlib.Path(os.fspath(path))
    if not p.is_dir():
        raise StoreError(f"field store {str(p)!r} does not exist")
    try:
        ds = xr.open_zarr(p, consolidated=False, zarr_format=3)
    except Exception as exc:  # zarr raises many types for a directory that is not a store
        raise StoreError(f"field store {str(p)!r} cannot be opened: {exc}") from exc
    return as_field(_strings_as_str(ds))


def image_tiles(field, tile: int | None = None):
    """``(y slice, x slice)`` pairs covering the image, one per stored chunk (or per ``tile`` × ``tile`` block).

    Parameters
    ----------
    field : xarray.Dataset or xarray.DataArray
        A reflectance field, or its ``reflectance`` variable (:func:`as_field`).
    tile : int, optional
        Tile side in pixels, ≥ 1 (edge tiles are smaller).  Default: the chunks of a dask-backed ``reflectance``,
        else one tile over the whole image.

    Returns
    -------
    list of tuple of slice
        Row-major over the tiles.

    Raises
    ------
    ValidationError
        If ``field`` is not a reflectance field, or ``tile`` < 1.
    """
    f = as_field(field)
    h, w = f.sizes["y"], f.sizes["x"]
    if tile is None:
        chunks = f["reflectance"].chunks
        if chunks is not None:
            dims = f["reflectance"].dims
            ys, xs = chunks[dims.index("y")], chunks[dims.index("x")]
            y_edges, x_edges = np.cumsum((0,) + tuple(ys)), np.cumsum((0,) + tuple(xs))
            return [
                (slice(int(y_edges[i]), int(y_edges[i + 1])), slice(int(x_edges[j]), int(x_edges[j + 1])))
                for i in range(len(ys))
                for j in range(len(xs))
            ]
        tile = max(h, w)
    t = check_integer(tile, "tile", 1)
    return [(slice(y, min(y + t, h)), slice(x, min(x + t, w))) for y in range(0, h, t) for x in range(0, w, t)]
