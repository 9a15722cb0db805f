"""A subject's maps as an OpenEXR texture set with its face mesh: the renderer-facing form of a store subject.

:func:`write_exr_set` writes one EXR file per map of a map subject (Weyrich et
al. 2006 §4: parameter maps in UV space), a mesh with UVs and a
``manifest.json`` describing every file; :func:`read_exr_set` reads a set back.

================================  ========  =========  ==============================================
file                              channels  type       content (units)
================================  ========  =========  ==============================================
``albedo.exr``                    R G B     half       diffuse albedo α (eq. 9), 1
``modulation.exr``                R G B     half       M = α / α_avg (eq. 7), 1
``normal.exr``                    R G B     half       diffuse normal, object space (x, y, z in [-1, 1])
``normal_tangent.exr``            R G B     half       the same normal in the mesh's tangent frame
``ts_rho_s.exr``, ``ts_m``        Y         float      Torrance-Sparrow ρs, Beckmann m (eq. 12-13), 1
``bp_rho_s``, ``bp_exponent``     Y         float      Blinn-Phong ρs, n (eq. 11), 1
``ts_error``, ``bp_error``        Y         float      fit error E(p) (eq. 14), sr⁻¹
``sigma_a``, ``sigma_s_prime``,
``sigma_tr``                      R G B     float      σa, σ's, σtr (§5.4, eq. 15), mm⁻¹, uniform maps
``region.exr``                    Y         uint       face region 0-10 (Fig. 15)
``ts_flag``, ``bp_flag``          Y         uint       fit flags (bits: ``facestats.core.conventions.FLAG_BITS``)
``micro_normal_cam00.exr`` …      R G B     half       micro-normals seen by camera NN (§5.1), object space,
                                                       one file per camera, when stored
any other map                     Y / RGB   float      e.g. ``ts_rho_s_std`` standard errors, generically
================================  ========  =========  ==============================================

Every file is a single-part scanline EXR, ZIP-compressed (zlib over 16-line
blocks; :func:`facestats.io.images.write_exr`), that any OpenEXR reader opens.
The files are
independent, so they are written concurrently by a pool of threads (OpenEXR's
writer and numpy release the GIL); the micro-normals, most of the bytes of a
fitted subject (16 cameras × 3 half channels), are one file per camera for
that reason (format ``facestats.exr_set/1`` had them as one 48-channel
``micro_normal.exr``).

Conventions written into every EXR header (string attributes ``facestats.*``)
and the manifest:

* colour: linear, scene-referred, ITU-R BT.709 / sRGB primaries and D65 white
  (the OpenEXR default chromaticities, so no ``chromaticities`` attribute is
  needed); non-colour data say ``data (not a colour)``;
* UV: u to the right, v down, row 0 of every image is v = 0 (top of the
  forehead); the mesh files store v up, as OBJ/PLY do;
* object-space normals are in facestats' world frame (+x the subject's left,
  +y up, +z out of the face towards the frontal camera), unit vectors stored
  as signed components (not remapped to [0, 1]);
* tangent-space normals: x along ∂p/∂u, y up the texture (−∂p/∂v, the glTF
  2.0 / OpenGL "+Y up" convention), z along the mesh normal
  (:meth:`facestats.io.mesh.FaceMesh.tangent_frames`);
* lengths in mm (the mesh) and coefficients in mm⁻¹;
* ``facestats.variable`` names the subject variable a file holds and, for the
  micro-normals, ``facestats.camera`` the camera index.

Texels off the measured face.  A renderer samples the maps wherever the mesh's
UVs land and filters (mipmaps) across the face's edge, and the mesh covers more
than the measured face (61.6 % of the ICT face's area, the default store's
``ict-48``, lies on texels of region 0: scalp, ears, neck, sides).  So the maps
a renderer reads for colour and reflectance (:data:`FILLED_MAPS`: albedo,
modulation, ρs, m, Blinn-Phong ρs and n) hold, at every texel that is not
measured (region 0, or a non-finite value), the value of the nearest measured
texel (:class:`FaceFill`; measured texels are written unchanged); the
object-space normal map holds the mesh's own normal there and the tangent-space
one (0, 0, 1), i.e. no detail.  ``region.exr`` stays 0 and the flags 0 there,
so the region map says which texels are measured.  Every other map writes its
non-finite texels (NaN: not measured) as 0, and 0 off the face as stored.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from facestats.core.outputs import json_ready
from facestats.core.validate import check_integer
from facestats.errors import FormatError, ValidationError
from facestats.io.images import read_exr, write_exr
from facestats.io.mesh import FaceMesh, subject_mesh, write_mesh
from facestats.io.schema import VARIABLES, modulation, subject_kind, validate_subject

__all__ = [
    "EXR_SET_FORMAT",
    "COLOUR_SPACE",
    "FILLED_MAPS",
    "UV_CONVENTION",
    "DATA_SPACE",
    "exr_header",
    "FaceFill",
    "check_map_subject",
    "check_export_subject",
    "write_exr_set",
    "read_exr_set",
    "exr_set_textures",
    "tangent_space_normals",
]

#: Version tag of the manifest (2: micro-normals one file per camera).
EXR_SET_FORMAT = "facestats.exr_set/2"
COLOUR_SPACE = "linear scene-referred ITU-R BT.709/sRGB primaries, D65 white"
DATA_SPACE = "data (not a colour)"
UV_CONVENTION = "u right, v down; image row 0 is v = 0 (top of the forehead); maps indexed [v, u]"
OBJECT_SPACE = "object space: facestats world frame (+x subject's left, +y up, +z out of the face), signed components"
TANGENT_SPACE = "tangent space: x = dp/du, y = -dp/dv (up the texture, glTF/OpenGL +Y up), z = mesh normal"

#: Maps stored as half floats (values of order 1 that need ~3 significant digits).
_HALF = ("albedo", "modulation", "normal", "normal_tangent", "micro_normal")
#: Colour quantities (linear RGB reflectances); every other map is data.
_COLOUR = ("albedo", "modulation")
#: Per-subject coefficients written as uniform RGB maps.
_UNIFORM = ("sigma_a", "sigma_s_prime", "sigma_tr")
#: Bytes per texel and channel of each stored type (to write the largest files first).
_BYTES = {"half": 2, "float": 4, "uint": 4}
#: Maps a renderer reads for colour and reflectance: off the measured face, the nearest measured texel's value.
FILLED_MAPS = ("albedo", "modulation", "ts_rho_s", "ts_m", "bp_rho_s", "bp_exponent")


def check_map_subject(ds, what: str) -> None:
    """Refuse a subject that holds region samples (an imported published file), not maps.

    Parameters
    ----------
    ds : xarray.Dataset
        A subject of either kind (:func:`facestats.io.schema.subject_kind`).
    what : str
        What the caller makes of the maps, for the message (e.g. ``"an EXR texture set"``).

    Raises
    ------
    ValidationError
        ``subject 'ID' holds region samples, not maps: WHAT needs a map subject``.
    """
    if subject_kind(ds) != "maps":
        raise ValidationError(
            f"subject {ds.attrs.get('subject_id', '?')!r} holds region samples, not maps: {what} needs a map subject"
        )


def check_export_subject(ds, what: str) -> None:
    """Refuse a subject that an export cannot write faithfully: region samples, or values the store would refuse.

    A subject read from a store passed these checks when it was written; a Dataset given to a writer directly
    (the API) is checked here, so that a negative ρs or a NaN σa is not written as a texture.

    Parameters
    ----------
    ds : xarray.Dataset
        A subject.
    what : str
        What the caller makes of the maps, for the message (e.g. ``"an EXR texture set"``).

    Raises
    ------
    ValidationError
        A region-sample subject (:func:`check_map_subject`).
    SchemaError
        Anything :func:`facestats.io.schema.validate_subject` refuses, named by variable and value.
    """
    check_map_subject(ds, what)
    validate_subject(ds)


class FaceFill:
    """Every texel off a subject's measured face given the value of the nearest measured texel.

    A texel is measured where its region is 1-10 and its value finite (all
    channels).  The nearest measured texel is the one at the least Euclidean
    distance in texels (ties as :func:`scipy.ndimage.distance_transform_edt`
    breaks them); a measured texel is its own nearest, so measured texels keep
    their values bit for bit.  The nearest texel of every texel under the face
    mask is found once, when the fill is made; a map with non-finite texels on
    the face has its own search.

    Parameters
    ----------
    region : array_like of int, shape (H, W)
        The subject's region map (0 = not face).
    """

    def __init__(self, region):
        self.face = np.asarray(region) > 0
        self._face_nearest = _nearest_texels(self.face) if self.face.any() else None

    def __call__(self, values) -> np.ndarray:
        """``values`` (H, W) or (H, W, C) filled off the measured face.

        Returns
        -------
        ndarray
            Same shape and dtype as ``values``; if no texel is measured (nothing to fill from), ``values``
            with its non-finite texels as 0.
        """
        a = np.asarray(values)
        if a.shape[:2] != self.face.shape:
            raise ValidationError(f"values must have shape {self.face.shape} (+ channels), got {a.shape}")
        measured = self.face & np.isfinite(a).reshape(self.face.shape + (-1,)).all(axis=-1)
        if not measured.any():
            return _finite(a)
        nearest = self._face_nearest if np.array_equal(measured, self.face) else _nearest_texels(measured)
        return a.reshape(measured.size, -1)[nearest].reshape(a.shape)


def _nearest_texels(measured) -> np.ndarray:
    """For every texel, the flat index of the nearest texel where ``measured`` is True (its own if measured)."""
    from scipy.ndimage import distance_transform_edt

    iv, iu = distance_transform_edt(~measured, return_distances=False, return_indices=True)
    return (iv * measured.shape[1] + iu).ravel()


def _finite(values) -> np.ndarray:
    """``values`` as an array, non-finite floats (NaN: not measured) replaced by 0; copied only if it has any."""
    a = np.asarray(values)
    if a.dtype.kind == "f":
        bad = ~np.isfinite(a)
        if bad.any():
            a = np.where(bad, a.dtype.type(0), a)
    return a


def _planes(image) -> dict:
    """An (H, W) image as ``{"Y": image}``, an (H, W, 3) one as ``{"R": ..., "G": ..., "B": ...}`` (views)."""
    if image.ndim == 2:
        return {"Y": image}
    return {k: image[..., i] for i, k in enumerate("RGB")}


def _texture(name, channels, load, *, kind, units, quantity, space=DATA_SPACE, variable=None, extra=None):
    """One file of the set; ``load()`` builds its channels (called by the writing thread, so lazily)."""
    return {
        "name": name,
        "file": name + ".exr",
        "variable": variable or name,
        "channels": tuple(channels),
        "type": kind,
        "units": units,
        "quantity": quantity,
        "space": space,
        "extra": extra or {},
        "load": load,
    }


def _map_textures(ds, fill: FaceFill):
    """One texture per (v, u[, channel|component]) map of the subject (normals handled separately);
    :data:`FILLED_MAPS` filled off the measured face by ``fill``."""
    out = []
    for var in sorted(ds.data_vars):
        da = ds[var]
        dims = tuple(da.dims)
        if dims[:2] != ("v", "u") or var in ("normal", "modulation"):
            continue
        if len(dims) == 2:
            channels = ("Y",)
        elif len(dims) == 3 and dims[2] in ("channel", "component") and da.shape[2] == 3:
            channels = ("R", "G", "B")
        else:
            continue  # not an image-shaped map
        kind = "uint" if da.dtype.kind in "iub" else ("half" if var in _HALF else "float")
        prepare = fill if var in FILLED_MAPS else _finite
        out.append(
            _texture(
                var,
                channels,
                lambda da=da, prepare=prepare: _planes(prepare(da.values)),
                kind=kind,
                units=da.attrs.get("units", VARIABLES.get(var, ((), "1", ""))[1]),
                quantity=da.attrs.get("long_name", VARIABLES.get(var, ((), "", var))[2]),
                space=COLOUR_SPACE if var in _COLOUR else DATA_SPACE,
            )
        )
    return out


def _unit_normals(ds) -> np.ndarray:
    """The subject's diffuse normals normalised, (0, 0, 0) where absent or non-finite; shape (v, u, 3)."""
    n = _finite(np.asarray(ds["normal"].values, np.float32))
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def _measured_normals(ds):
    """The unit normals and where none is measured (off the face, or absent or non-finite: zero)."""
    n = _unit_normals(ds)
    return n, ~n.any(axis=-1) | (np.asarray(ds["region"].values) == 0)


def _object_normals(ds, frames) -> np.ndarray:
    """The unit normals, the mesh's own normal (``frames()[2]``) where none is measured."""
    n, absent = _measured_normals(ds)
    if absent.any():
        n[absent] = frames()[2][absent]
    return n


def tangent_space_normals(ds, frames) -> np.ndarray:
    """A map subject's diffuse normals in its mesh's tangent frames: n_t = (n·T, n·B, n·N), float32 (v, u, 3).

    The normals are normalised first (:func:`_unit_normals`); a texel with none measured (off the face, or an
    absent, zero or non-finite normal) gets the mesh's own, (0, 0, 1).  One computation for the EXR set's
    ``normal_tangent`` file and the glTF export's normal texture.

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject (``normal``, ``region``).
    frames : tuple of ndarray
        ``(T, B, N)``, each (v, u, 3), as :meth:`facestats.io.mesh.FaceMesh.tangent_frames` gives them.

    Returns
    -------
    ndarray
        Tangent-space normals, float32, shape (v, u, 3); unit where measured (to about 1e-7: the frames are
        orthonormal to that).
    """
    n, absent = _measured_normals(ds)
    nt = np.stack([np.einsum("vuk,vuk->vu", n, f) for f in frames], -1)
    nt[absent] = (0.0, 0.0, 1.0)
    return nt


def _shared_frames(mesh: FaceMesh, size: int):
    """A callable giving ``mesh.tangent_frames(size)``, computed once for both normal textures (their threads
    would otherwise each compute it, at once)."""
    import threading

    lock, memo = threading.Lock(), []

    def frames():
        with lock:
            if not memo:
                memo.append(mesh.tangent_frames(size))
            return memo[0]

    return frames


def _normal_textures(ds, mesh: FaceMesh):
    """Object-space normal map and the same normals in the mesh's tangent frames."""
    if "normal" not in ds.data_vars:
        return []
    quantity = VARIABLES["normal"][2]
    frames = _shared_frames(mesh, int(ds.sizes["v"]))
    return [
        _texture(
            "normal",
            "RGB",
            lambda: _planes(_object_normals(ds, frames)),
            kind="half",
            units="1",
            quantity=quantity,
            extra={"normal_space": OBJECT_SPACE},
        ),
        _texture(
            "normal_tangent",
            "RGB",
            lambda: _planes(tangent_space_normals(ds, frames())),
            kind="half",
            units="1",
            quantity=quantity,
            extra={"normal_space": TANGENT_SPACE},
        ),
    ]


def _micro_normal_textures(ds):
    """Per-camera micro-normals, one RGB file per camera (``micro_normal_camNN``), if the subject has them."""
    if "micro_normal" not in ds.data_vars:
        return []
    mn = ds["micro_normal"]
    return [
        _texture(
            f"micro_normal_cam{c:02d}",
            "RGB",
            lambda c=c: _planes(_finite(mn[c].values)),
            kind="half",
            units="1",
            quantity=VARIABLES["micro_normal"][2],
            variable="micro_normal",
            extra={"camera": c, "normal_space": OBJECT_SPACE},
        )
        for c in range(mn.shape[0])
    ]


def _uniform_textures(ds):
    """σa, σ's, σtr of the subject (one value per channel) as uniform RGB maps at map size."""
    shape = (int(ds.sizes["v"]), int(ds.sizes["u"]))
    out = []
    for var in _UNIFORM:
        if var not in ds.data_vars:
            continue
        vals = np.asarray(ds[var].values, np.float64)
        out.append(
            _texture(
                var,
                "RGB",
                lambda vals=vals: {k: np.full(shape, v, np.float32) for k, v in zip("RGB", vals)},
                kind="float",
                units="mm-1",
                quantity=VARIABLES[var][2],
                extra={"value": " ".join(repr(float(x)) for x in vals)},
            )
        )
    return out


def _modulation_texture(ds, fill: FaceFill):
    """M = α / α_avg (eq. 7): the stored ``modulation`` map or :func:`facestats.io.schema.modulation`, filled
    off the measured face by ``fill``."""

    def load():
        m = ds["modulation"] if "modulation" in ds.data_vars else modulation(ds)
        return _planes(fill(m.values))

    return _texture(
        "modulation", "RGB", load, kind="half", units="1", quantity=VARIABLES["modulation"][2], space=COLOUR_SPACE
    )


def exr_set_textures(ds, mesh: FaceMesh, fill: FaceFill | None = None):
    """The files :func:`write_exr_set` writes, described without building their pixels.

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject.
    mesh : FaceMesh
        Its face mesh (for the tangent-space normal map).
    fill : FaceFill, optional
        The fill of ``ds``'s region map, if the caller made one (default: made here).

    Returns
    -------
    list of dict
        Per file: ``name`` (file stem), ``file``, ``variable`` (the subject
        variable it holds), ``channels`` (names), ``type`` (``half``, ``float``
        or ``uint``), ``units``, ``quantity``, ``space`` (colour space or
        ``data``), ``extra`` (further header attributes) and ``load``, a
        function returning the channels as ``{name: (v, u) array}``
        (:data:`FILLED_MAPS` filled off the measured face, the object-space
        normals the mesh's there, other non-finite texels 0; module docstring).

    Raises
    ------
    ValidationError
        A region-sample subject (it has no maps), or two textures of one file name (an extra map named like
        a file of the set, e.g. ``normal_tangent``).
    """
    check_map_subject(ds, "an EXR texture set")
    fill = FaceFill(ds["region"].values) if fill is None else fill
    textures = (
        _map_textures(ds, fill)
        + [_modulation_texture(ds, fill)]
        + _normal_textures(ds, mesh)
        + _uniform_textures(ds)
        + _micro_normal_textures(ds)
    )
    writers = {}
    for tex in textures:  # an extra map named like a file of the set (e.g. normal_tangent) would overwrite it
        other = writers.setdefault(tex["file"], tex)
        if other is not tex:
            raise ValidationError(
                f"subject {ds.attrs.get('subject_id', '?')!r}: variable {tex['variable']!r} would be written to "
                f"{tex['file']}, which holds {other['variable']!r} in an EXR texture set; rename the variable"
            )
    return textures


def exr_header(ds, *, file_format, variable, quantity, units, colour_space, **extra) -> dict:
    """The ``facestats.*`` string attributes of an EXR file facestats writes from a subject (module docstring).

    Every file of the EXR set (``file_format`` :data:`EXR_SET_FORMAT`) and every image of ``facestats render`` carries
    them: which format and subject, the variable the file holds, its quantity in words, its units and colour
    space (:data:`COLOUR_SPACE` for linear RGB, ``data (not a colour)`` for other data), then ``extra``, in the
    order given, each as ``facestats.<key>`` (values converted with ``str``).

    Parameters
    ----------
    ds : xarray.Dataset
        The subject (its ``subject_id`` attribute; empty if it has none).
    file_format : str
        The kind of file, e.g. ``"facestats.exr_set/2"``.
    variable, quantity, units, colour_space : str
        What the file holds.
    **extra
        Further attributes (e.g. ``uv``, ``geometry``, ``camera``).

    Returns
    -------
    dict of str to str
        For the ``attributes`` of :func:`facestats.io.images.write_exr`.
    """
    attrs = {
        "facestats.format": str(file_format),
        "facestats.subject_id": str(ds.attrs.get("subject_id", "")),
        "facestats.variable": str(variable),
        "facestats.quantity": str(quantity),
        "facestats.units": str(units),
        "facestats.colour_space": str(colour_space),
    }
    attrs.update({f"facestats.{k}": str(v) for k, v in extra.items()})
    return attrs


def _header(ds, tex, geometry) -> dict:
    return exr_header(
        ds, file_format=EXR_SET_FORMAT, variable=tex["variable"], quantity=tex["quantity"], units=tex["units"],
        colour_space=tex["space"], uv=UV_CONVENTION, geometry=geometry["name"], **tex["extra"],
    )  # fmt: skip


def _default_workers() -> int:
    """The CPUs this process may run on (its affinity mask where the OS has one)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


def write_exr_set(
    ds, out_dir, *, mesh=None, mesh_format: str = "obj", mesh_grid: int | None = None, workers=None, fill=None
):
    """Write a map subject as an EXR texture set, its face mesh and ``manifest.json`` into ``out_dir``.

    Every file is independent, so the texture files and the mesh are written by
    ``workers`` threads, largest first (a file's pixels are built by the thread
    that writes it, so at most ``workers`` files' pixels are in memory); the
    manifest is written last.

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject (:mod:`facestats.io.schema`).
    out_dir : str or os.PathLike
        Existing directory to write into.
    mesh : str, os.PathLike or FaceMesh, optional
        The scan the maps belong to; default: the procedural head recorded in
        the subject's provenance (:func:`facestats.io.mesh.subject_mesh`).
    mesh_format : {"obj", "ply"}
    mesh_grid : int, optional
        Procedural mesh resolution (default 128).
    workers : int, optional
        Threads writing files (default: the CPUs available to the process).
    fill : FaceFill, optional
        The fill of ``ds``'s region map, if the caller needs one too (its nearest-texel search, 0.56 s at
        2048², is then made once); default: made here.

    Returns
    -------
    dict
        The manifest (also written as ``manifest.json``): subject metadata,
        ``geometry`` (what mesh was used), ``mesh`` (file name), ``textures``
        (per file stem: file, variable, channels, type, units, quantity, colour
        space, camera for the micro-normals) and ``coefficients`` (σa, σ's,
        σtr, α_avg per channel).

    Raises
    ------
    ValidationError
        Before anything is written: a region-sample subject, a bad ``mesh_format`` or ``workers``, two
        textures of one file name (:func:`exr_set_textures`). While writing: a half-float map beyond ±65504
        (named by variable and file; nothing is removed, the caller owns ``out_dir``).
    SchemaError
        A subject the store would refuse (:func:`check_export_subject`).
    """
    check_export_subject(ds, "an EXR texture set")
    if mesh_format not in ("obj", "ply"):
        raise ValidationError(f"mesh_format must be 'obj' or 'ply', got {mesh_format!r}")
    workers = _default_workers() if workers is None else check_integer(workers, "workers", 1, 256)
    fm = mesh if isinstance(mesh, FaceMesh) else subject_mesh(ds, mesh, mesh_grid=mesh_grid)
    textures = exr_set_textures(ds, fm, fill)
    out_dir = os.fspath(out_dir)
    mesh_file = f"mesh.{mesh_format}"

    def write(tex):
        planes = tex["load"]()
        if tex["type"] == "half":
            _check_half(ds, tex, planes)
        write_exr(
            os.path.join(out_dir, tex["file"]), planes, half=tex["type"] == "half",
            attributes=_header(ds, tex, fm.geometry),
        )  # fmt: skip

    def write_mesh_file():
        write_mesh(os.path.join(out_dir, mesh_file), fm.vertices, fm.faces, fm.uv, fm.normals)

    largest_first = sorted(textures, key=lambda t: -len(t["channels"]) * _BYTES[t["type"]])
    with ThreadPoolExecutor(max_workers=workers) as pool:
        jobs = [pool.submit(write, t) for t in largest_first] + [pool.submit(write_mesh_file)]
        for job in jobs:
            job.result()  # re-raises the first failure
    manifest = _manifest(ds, textures, fm, mesh_file)
    manifest = json_ready(manifest)  # a subject attribute of NaN is written as null, not as the token NaN
    with open(os.path.join(out_dir, "manifest.json"), "w", encoding="utf-8") as fh:
        json.dump(manifest, fh, indent=2, allow_nan=False)
    return manifest


def _check_half(ds, tex, planes) -> None:
    """Refuse a half-float texture with values beyond float16 (|x| > 65504), naming its variable and file.

    The modulation M = α / α_avg (eq. 7) gets there when ``albedo_avg`` is tiny (the schema allows any value
    in (0, 1]), so its message gives ``albedo_avg`` too.
    """
    limit = float(np.finfo(np.float16).max)
    for channel, plane in planes.items():
        top = float(np.max(np.abs(plane), initial=0.0))
        if top > limit:
            cause = ""
            if tex["variable"] == "modulation" and "modulation" not in ds.data_vars:
                cause = f" (M = albedo / albedo_avg, albedo_avg = {np.asarray(ds['albedo_avg'].values).tolist()})"
            raise ValidationError(
                f"subject {ds.attrs.get('subject_id', '?')!r}: {tex['variable']} must lie within the half-float "
                f"range (|x| <= {limit:g}) for {tex['file']}, got {top:.6g} in channel {channel!r}{cause}"
            )


def _manifest(ds, textures, fm: FaceMesh, mesh_file) -> dict:
    meta = {k: (v.item() if hasattr(v, "item") else v) for k, v in ds.attrs.items() if k != "provenance"}
    coeffs = {
        var: [float(x) for x in np.asarray(ds[var].values)] for var in (*_UNIFORM, "albedo_avg") if var in ds.data_vars
    }
    return {
        "format": EXR_SET_FORMAT,
        "subject": meta,
        "geometry": fm.geometry,
        "mesh": {"file": mesh_file, "units": "mm", "uv": "v up in the file (OBJ/PLY convention)"},
        "uv": UV_CONVENTION,
        "colour_space": COLOUR_SPACE,
        "coefficients": coeffs,
        "coefficient_units": {"sigma_a": "mm-1", "sigma_s_prime": "mm-1", "sigma_tr": "mm-1", "albedo_avg": "1"},
        "textures": {
            t["name"]: {
                "file": t["file"],
                "variable": t["variable"],
                "channels": list(t["channels"]),
                "type": t["type"],
                "units": t["units"],
                "quantity": t["quantity"],
                "colour_space": t["space"],
                **t["extra"],
            }
            for t in textures
        },
    }


def read_exr_set(path):
    """Read an EXR texture set written by :func:`write_exr_set` back into arrays.

    Parameters
    ----------
    path : str or os.PathLike
        The set's directory (holding ``manifest.json``).

    Returns
    -------
    maps : dict of str to ndarray
        Per file stem, the image indexed ``[v, u]`` (one channel) or
        ``[v, u, channel]`` (R, G, B) as stored (float16, float32 or uint32),
        except the per-camera micro-normals, gathered into ``micro_normal``
        indexed ``[camera, v, u, component]``.
    manifest : dict
        ``manifest.json``.

    Raises
    ------
    FormatError
        No readable manifest, a manifest of another format, or micro-normal
        cameras that are not 0, 1, ..., C − 1.
    ImageFormatError
        An unreadable EXR file.
    """
    root = os.fspath(path)
    name = os.path.join(root, "manifest.json")
    try:
        with open(name, encoding="utf-8") as fh:
            manifest = json.load(fh)
    except (OSError, ValueError) as exc:
        raise FormatError(f"cannot read the EXR set manifest {name!r}: {exc}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != EXR_SET_FORMAT:
        got = manifest.get("format") if isinstance(manifest, dict) else type(manifest).__name__
        raise FormatError(f"field 'format' of {name!r} must be {EXR_SET_FORMAT!r}, got {got!r}")
    if not isinstance(manifest.get("textures"), dict):
        raise FormatError(f"field 'textures' of {name!r} must be an object, got {manifest.get('textures')!r}")
    maps, cameras = {}, {}
    for stem, entry in manifest["textures"].items():
        missing = [k for k in ("file", "variable", "channels") if k not in entry]
        if missing:
            raise FormatError(f"texture {stem!r} of {name!r} has no field {missing[0]!r}")
        channels, _ = read_exr(os.path.join(root, entry["file"]))
        names = entry["channels"]
        if set(names) - set(channels):
            raise FormatError(f"{entry['file']!r} of {name!r} lacks channels {sorted(set(names) - set(channels))}")
        image = channels[names[0]] if len(names) == 1 else np.stack([channels[k] for k in names], -1)
        if entry["variable"] == "micro_normal":
            cameras[int(entry["camera"])] = image
        else:
            maps[stem] = image
    if cameras:
        if sorted(cameras) != list(range(len(cameras))):
            raise FormatError(
                f"the micro-normal cameras of {name!r} must be 0..{len(cameras) - 1}, got {sorted(cameras)}"
            )
        maps["micro_normal"] = np.stack([cameras[c] for c in range(len(cameras))])
    return maps, manifest
