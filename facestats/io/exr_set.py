"""A subject's maps as an OpenEXR texture set with its face mesh: the renderer-facing form of a store subject.

:func:`write_exr_set` writes one EXR file per map of a map subject (Weyrich et
al. 2006 §4: parameter maps in UV space), a mesh with UVs and a
``manifest.json`` describing every file:

============================  ========  =========  ==============================================
file                          channels  type       content (units)
============================  ========  =========  ==============================================
``albedo.exr``                R G B     half       diffuse albedo α (eq. 9), 1
``modulation.exr``            R G B     half       M = α / α_avg (eq. 7), 1
``normal.exr``                R G B     half       diffuse normal, object space (x, y, z in [-1, 1])
``normal_tangent.exr``        R G B     half       the same normal in the mesh's tangent frame
``ts_rho_s.exr``, ``ts_m``    Y         float      Torrance-Sparrow ρs, Beckmann m (eq. 12-13), 1
``bp_rho_s``, ``bp_exponent`` Y         float      Blinn-Phong ρs, n (eq. 11), 1
``ts_error``, ``bp_error``    Y         float      fit error E(p) (eq. 14), sr⁻¹
``sigma_a``, ``sigma_s_prime``,
``sigma_tr``                  R G B     float      σa, σ's, σtr (§5.4, eq. 15), mm⁻¹, uniform maps
``region.exr``                Y         uint       face region 0-10 (Fig. 15)
``ts_flag``, ``bp_flag``      Y         uint       fit flags (bits: ``facestats.core.conventions.FLAG_BITS``)
``micro_normal.exr``          camNN.R…  half       per-camera micro-normals (§5.1), when stored
any other map                 Y / RGB   float      e.g. ``ts_rho_s_std`` standard errors, generically
============================  ========  =========  ==============================================

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
* lengths in mm (the mesh) and coefficients in mm⁻¹.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from facestats.errors import ValidationError
from facestats.io.images import write_exr
from facestats.io.mesh import FaceMesh, subject_mesh, write_mesh
from facestats.io.schema import VARIABLES, modulation, subject_kind

__all__ = ["EXR_SET_FORMAT", "COLOUR_SPACE", "UV_CONVENTION", "write_exr_set", "exr_set_textures"]

#: Version tag of the manifest.
EXR_SET_FORMAT = "facestats.exr_set/1"
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


def _texture(name, channels, *, units, quantity, space=DATA_SPACE, half=False, extra=None):
    return {
        "name": name,
        "channels": channels,
        "units": units,
        "quantity": quantity,
        "space": space,
        "half": half,
        "extra": extra or {},
    }


def _map_textures(ds):
    """One texture per (v, u[, channel|component]) map of the subject (normals handled separately)."""
    out = []
    for var in sorted(ds.data_vars):
        dims = tuple(ds[var].dims)
        if dims[:2] != ("v", "u") or var in ("normal", "modulation"):
            continue
        units = ds[var].attrs.get("units", VARIABLES.get(var, ((), "1", ""))[1])
        quantity = ds[var].attrs.get("long_name", VARIABLES.get(var, ((), "", var))[2])
        values = np.nan_to_num(np.asarray(ds[var].values))
        if len(dims) == 2:
            channels = {"Y": values}
        elif dims[2] in ("channel", "component") and values.shape[2] == 3:
            channels = dict(zip("RGB", np.moveaxis(values, 2, 0)))
        else:
            continue  # not an image-shaped map
        space = COLOUR_SPACE if var in _COLOUR else DATA_SPACE
        out.append(_texture(var, channels, units=units, quantity=quantity, space=space, half=var in _HALF))
    return out


def _normal_textures(ds, mesh: FaceMesh):
    """Object-space normal map and the same normals in the mesh's tangent frames."""
    if "normal" not in ds.data_vars:
        return []
    n = np.nan_to_num(np.asarray(ds["normal"].values, np.float64))
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(length > 0, n / np.where(length > 0, length, 1), 0.0)
    t, b, g = mesh.tangent_frames(n.shape[0])
    nt = np.stack([np.einsum("vuk,vuk->vu", n, f) for f in (t, b, g)], -1)
    nt[length[..., 0] == 0] = (0.0, 0.0, 1.0)
    quantity = VARIABLES["normal"][2]
    return [
        _texture("normal", dict(zip("RGB", np.moveaxis(n, 2, 0))), units="1", quantity=quantity, half=True,
                 extra={"normal_space": OBJECT_SPACE}),
        _texture("normal_tangent", dict(zip("RGB", np.moveaxis(nt, 2, 0))), units="1", quantity=quantity,
                 half=True, extra={"normal_space": TANGENT_SPACE}),
    ]  # fmt: skip


def _micro_normal_texture(ds):
    """Per-camera micro-normals as one multi-channel EXR (``camNN.R/G/B``), if the subject has them."""
    if "micro_normal" not in ds.data_vars:
        return []
    mn = np.nan_to_num(np.asarray(ds["micro_normal"].values))
    channels = {f"cam{c:02d}.{k}": mn[c, ..., i] for c in range(mn.shape[0]) for i, k in enumerate("RGB")}
    return [
        _texture("micro_normal", channels, units="1", quantity=VARIABLES["micro_normal"][2], half=True,
                 extra={"normal_space": OBJECT_SPACE})
    ]  # fmt: skip


def _uniform_textures(ds):
    """σa, σ's, σtr of the subject (one value per channel) as uniform RGB maps at map size."""
    shape = (int(ds.sizes["v"]), int(ds.sizes["u"]))
    out = []
    for var in _UNIFORM:
        if var not in ds.data_vars:
            continue
        vals = np.asarray(ds[var].values, np.float64)
        channels = {k: np.full(shape, vals[i], np.float32) for i, k in enumerate("RGB")}
        out.append(
            _texture(var, channels, units="mm-1", quantity=VARIABLES[var][2],
                     extra={"value": " ".join(repr(float(x)) for x in vals)})
        )  # fmt: skip
    return out


def exr_set_textures(ds, mesh: FaceMesh):
    """The textures :func:`write_exr_set` writes, as dicts (``name``, ``channels``, ``units``, ...).

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject.
    mesh : FaceMesh
        Its face mesh (for the tangent-space normal map).

    Returns
    -------
    list of dict
    """
    if subject_kind(ds) != "maps":
        raise ValidationError(
            f"subject {ds.attrs.get('subject_id', '?')!r} holds region samples, not maps: it has no texture set"
        )
    textures = _map_textures(ds)
    m = modulation(ds) if "modulation" not in ds.data_vars else ds["modulation"]
    mod = np.nan_to_num(np.asarray(m.values))
    textures.append(
        _texture("modulation", dict(zip("RGB", np.moveaxis(mod, 2, 0))), units="1",
                 quantity=VARIABLES["modulation"][2], space=COLOUR_SPACE, half=True)
    )  # fmt: skip
    return textures + _normal_textures(ds, mesh) + _uniform_textures(ds) + _micro_normal_texture(ds)


def _header(ds, tex, geometry) -> dict:
    attrs = {
        "facestats.format": EXR_SET_FORMAT,
        "facestats.subject_id": str(ds.attrs.get("subject_id", "")),
        "facestats.variable": tex["name"],
        "facestats.quantity": tex["quantity"],
        "facestats.units": tex["units"],
        "facestats.colour_space": tex["space"],
        "facestats.uv": UV_CONVENTION,
        "facestats.geometry": geometry["name"],
    }
    attrs.update({f"facestats.{k}": str(v) for k, v in tex["extra"].items()})
    return attrs


def write_exr_set(ds, out_dir, *, mesh=None, mesh_format: str = "obj", mesh_grid: int | None = None, workers=4):
    """Write a map subject as an EXR texture set, its face mesh and ``manifest.json`` into ``out_dir``.

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
    workers : int
        Files written in parallel.

    Returns
    -------
    dict
        The manifest (also written as ``manifest.json``): subject metadata,
        ``geometry`` (what mesh was used), ``mesh`` (file name), ``textures``
        (per name: file, channels, type, units, quantity, colour space) and
        ``coefficients`` (σa, σ's, σtr, α_avg per channel).
    """
    if mesh_format not in ("obj", "ply"):
        raise ValidationError(f"mesh_format must be 'obj' or 'ply', got {mesh_format!r}")
    fm = mesh if isinstance(mesh, FaceMesh) else subject_mesh(ds, mesh, mesh_grid=mesh_grid)
    textures = exr_set_textures(ds, fm)
    out_dir = os.fspath(out_dir)

    def write(tex):
        path = os.path.join(out_dir, tex["name"] + ".exr")
        write_exr(path, tex["channels"], half=tex["half"], attributes=_header(ds, tex, fm.geometry))

    with ThreadPoolExecutor(max_workers=max(1, int(workers))) as pool:
        list(pool.map(write, textures))
    mesh_file = f"mesh.{mesh_format}"
    write_mesh(os.path.join(out_dir, mesh_file), fm.vertices, fm.faces, fm.uv, fm.normals)
    manifest = _manifest(ds, textures, fm, mesh_file)
    with open(os.path.join(out_dir, "manifest.json"), "w", encoding="utf-8") as fh:
        json.dump(manifest, fh, indent=2)
    return manifest


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
                "file": t["name"] + ".exr",
                "channels": list(t["channels"]),
                "type": "uint" if np.asarray(next(iter(t["channels"].values()))).dtype.kind in "iub"
                else ("half" if t["half"] else "float"),
                "units": t["units"],
                "quantity": t["quantity"],
                "colour_space": t["space"],
                **t["extra"],
            }
            for t in textures
        },
    }  # fmt: skip
