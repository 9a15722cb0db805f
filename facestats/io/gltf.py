"""A subject as a glTF 2.0 asset: the face mesh with a metallic-roughness PBR material made from the fitted maps.

:func:`write_gltf` writes ``face.gltf`` (JSON), ``face.bin`` (geometry) and three
PNG textures, through pygltflib:

* ``base_color.png`` — the diffuse albedo α (Weyrich et al. 2006 eq. 9),
  sRGB-encoded 8-bit as glTF requires for ``baseColorTexture`` (IEC 61966-2-1);
* ``normal.png`` — the fitted normal map in the mesh's tangent space
  (:meth:`facestats.io.mesh.FaceMesh.tangent_frames`: x along ∂p/∂u, y up the
  texture, z the mesh normal — glTF's "+Y up" convention), stored linearly as
  (n + 1)/2; the mesh carries the matching ``TANGENT`` attribute (with w);
* ``metallic_roughness.png`` — linear 8-bit, G = roughness, B = metallic = 0
  (skin is a dielectric), R unused (0).

The mesh covers more than the measured face (most of the ICT head: scalp, ears,
neck), and the sampler filters across the face's edge (trilinear mipmaps), so
the base colour and the roughness hold, off the measured face, the value of the
nearest measured texel (:class:`facestats.io.exr_set.FaceFill`; measured texels
unchanged) and the normal map (0, 0, 1), the mesh's own normal (also where a face
texel has no fitted normal: NaN, which the schema allows); the EXR set's
``region.exr`` says which texels are measured.

Roughness conversion.  glTF's specular lobe is GGX (Trowbridge-Reitz) with
α = roughness²; the fitted lobe is Beckmann with width m (eq. 13).  α_GGX =
c·m with c = :data:`GGX_PER_BECKMANN` = 0.92, the least-squares match of the
projected distributions D(θ) cos θ over the hemisphere (the optimum is
0.913-0.923 for m in 0.2-0.4, the range of skin; ``tests/io/test_export_formats.py``
recomputes it), so roughness = sqrt(0.92 m).  What glTF cannot carry: ρs
(glTF's dielectric specular has a fixed strength; the skin's index 1.38 is
given by ``KHR_materials_ior``), the Blinn-Phong fit, and subsurface scattering.

Units and frame: glTF is in metres, +y up, +z the front of the asset —
facestats' world frame, so vertices are scaled by 0.001 and not rotated.  UV:
glTF's texture origin is the top-left corner with v down, facestats'
convention, so UVs are written as stored.
"""

from __future__ import annotations

import os

import numpy as np

from facestats.errors import DependencyError, ValidationError
from facestats.io.exr_set import FaceFill, check_map_subject
from facestats.io.ids import SUBJECT_ID_PATTERN
from facestats.io.images import write_image
from facestats.io.mesh import FaceMesh, subject_mesh

__all__ = ["GGX_PER_BECKMANN", "beckmann_to_gltf_roughness", "write_gltf", "read_gltf_summary"]

#: α_GGX / m: least-squares match of the projected Beckmann and GGX distributions (module docstring).
GGX_PER_BECKMANN = 0.92
#: IOR of skin for ``KHR_materials_ior`` (Weyrich et al. 2006 §3, η ≈ 1.38).
_IOR = 1.38


def _pygltflib():
    try:
        import pygltflib
    except ImportError as exc:
        raise DependencyError(
            f"pygltflib is not installed (needed for glTF export): pip install pygltflib ({exc})"
        ) from None
    return pygltflib


def beckmann_to_gltf_roughness(m):
    """glTF ``roughness`` from a Beckmann width m: sqrt(α_GGX) with α_GGX = 0.92 m (module docstring).

    Parameters
    ----------
    m : array_like
        Torrance-Sparrow roughness (Weyrich eq. 13), > 0 (0 is returned as 0).

    Returns
    -------
    ndarray
        Roughness in [0, 1].
    """
    m = np.asarray(m, np.float64)
    return np.clip(np.sqrt(np.clip(GGX_PER_BECKMANN * m, 0, None)), 0, 1)


def _textures(ds, mesh, out):
    """Write the three PNGs (base colour and roughness filled off the measured face); returns their file names."""
    fill = FaceFill(ds["region"].values)
    face = fill.face
    alb = fill(np.asarray(ds["albedo"].values, np.float64))
    write_image(os.path.join(out, "base_color.png"), alb, srgb=True)
    n = np.asarray(ds["normal"].values, np.float64)
    absent = ~face | ~np.all(np.isfinite(n), axis=-1) | (np.linalg.norm(np.nan_to_num(n), axis=-1) == 0)
    n = np.nan_to_num(n)
    t, b, g = mesh.tangent_frames(n.shape[0])
    nt = np.stack([np.einsum("vuk,vuk->vu", n, f) for f in (t, b, g)], -1)
    nt /= np.maximum(np.linalg.norm(nt, axis=-1, keepdims=True), 1e-12)
    nt[absent] = (0.0, 0.0, 1.0)  # no fitted normal (off the face, or missing): the mesh's own, as the EXR set
    write_image(os.path.join(out, "normal.png"), (nt + 1) / 2)
    rough = beckmann_to_gltf_roughness(fill(np.asarray(ds["ts_m"].values, np.float64)))
    mr = np.stack([np.zeros_like(rough), rough, np.zeros_like(rough)], -1)
    write_image(os.path.join(out, "metallic_roughness.png"), mr)
    return "base_color.png", "normal.png", "metallic_roughness.png"


def _buffer(g, mesh):
    """Vertex and index data as one binary blob with its buffer views and accessors (indices 0-4)."""
    pos = (mesh.vertices * 1e-3).astype(np.float32)  # mm -> m
    nrm = mesh.normals.astype(np.float32)
    tan, w = mesh.vertex_tangents()
    tng = np.concatenate([tan, w[:, None]], 1).astype(np.float32)
    uv = mesh.uv.astype(np.float32)
    idx = mesh.faces.astype(np.uint32).ravel()
    parts = [(pos, g.VEC3, g.FLOAT, g.ARRAY_BUFFER), (nrm, g.VEC3, g.FLOAT, g.ARRAY_BUFFER),
             (tng, g.VEC4, g.FLOAT, g.ARRAY_BUFFER), (uv, g.VEC2, g.FLOAT, g.ARRAY_BUFFER),
             (idx, g.SCALAR, g.UNSIGNED_INT, g.ELEMENT_ARRAY_BUFFER)]  # fmt: skip
    blob, views, accessors = b"", [], []
    for i, (arr, kind, ctype, target) in enumerate(parts):
        data = arr.tobytes()
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data), target=target))
        acc = g.Accessor(bufferView=i, componentType=ctype, count=len(arr), type=kind)
        if i == 0:
            acc.min, acc.max = pos.min(0).tolist(), pos.max(0).tolist()
        accessors.append(acc)
        blob += data + b"\0" * (-len(data) % 4)
    return blob, views, accessors


def write_gltf(ds, out_dir, *, mesh=None, name="face"):
    """Write a map subject as a glTF 2.0 asset (``NAME.gltf``, ``NAME.bin``, three PNGs) into ``out_dir``.

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject with ``albedo``, ``normal``, ``ts_m`` and ``region``.
    out_dir : str or os.PathLike
        Existing directory.
    mesh : FaceMesh, str or os.PathLike, optional
        The face mesh (default: the recorded procedural head, :func:`facestats.io.mesh.subject_mesh`).
    name : str
        Base name of the ``.gltf`` and ``.bin`` files: a plain file stem (1-64 letters, digits, '.', '_' or
        '-', starting with a letter or digit; no folder).

    Returns
    -------
    str
        Path of the ``.gltf`` file.

    Raises
    ------
    ValidationError
        A region-sample subject, missing maps, or a ``name`` that is not a plain file stem (checked before
        anything is written).
    """

    if not isinstance(name, str) or not SUBJECT_ID_PATTERN.fullmatch(name):
        raise ValidationError(
            "name must be a plain file stem (1-64 letters, digits, '.', '_' or '-', starting with a letter or "
            f"digit; no folder), got {name!r}"
        )
    g = _pygltflib()
    check_map_subject(ds, "a glTF asset")
    missing = [v for v in ("albedo", "normal", "ts_m", "region") if v not in ds.data_vars]
    if missing:
        raise ValidationError(f"subject {ds.attrs.get('subject_id', '?')!r} lacks the maps {missing} glTF needs")
    fm = mesh if isinstance(mesh, FaceMesh) else subject_mesh(ds, mesh)
    out = os.fspath(out_dir)
    base, normal, mr = _textures(ds, fm, out)
    blob, views, accessors = _buffer(g, fm)
    with open(os.path.join(out, f"{name}.bin"), "wb") as fh:
        fh.write(blob)
    material = g.Material(
        name=f"skin {ds.attrs.get('subject_id', '')}",
        pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorTexture=g.TextureInfo(index=0), metallicRoughnessTexture=g.TextureInfo(index=2),
            metallicFactor=1.0, roughnessFactor=1.0,
        ),
        normalTexture=g.NormalMaterialTexture(index=1),
        doubleSided=False,
        extensions={"KHR_materials_ior": {"ior": _IOR}},
    )  # fmt: skip
    prim = g.Primitive(attributes=g.Attributes(POSITION=0, NORMAL=1, TANGENT=2, TEXCOORD_0=3), indices=4, material=0)
    gltf = g.GLTF2(
        asset=g.Asset(version="2.0", generator="facestats"),
        scene=0,
        scenes=[g.Scene(nodes=[0])],
        nodes=[g.Node(mesh=0, name=str(ds.attrs.get("subject_id", "face")))],
        meshes=[g.Mesh(primitives=[prim], name="face")],
        materials=[material],
        samplers=[g.Sampler(magFilter=9729, minFilter=9987, wrapS=33071, wrapT=33071)],
        images=[g.Image(uri=u) for u in (base, normal, mr)],
        textures=[g.Texture(source=i, sampler=0) for i in range(3)],
        buffers=[g.Buffer(byteLength=len(blob), uri=f"{name}.bin")],
        bufferViews=views,
        accessors=accessors,
        extensionsUsed=["KHR_materials_ior"],
        extras={"facestats": {"geometry": fm.geometry, "roughness": "sqrt(0.92 m), Beckmann m -> GGX alpha"}},
    )
    path = os.path.join(out, f"{name}.gltf")
    gltf.save_json(path)
    return path


def read_gltf_summary(path) -> dict:
    """Read a glTF file back with pygltflib and check what :func:`write_gltf` promises; a short summary.

    Checks: version 2.0, one triangle primitive whose accessors fit their
    buffer views and the binary file, POSITION/NORMAL/TANGENT/TEXCOORD_0
    present, a metallic-roughness material whose three textures exist.

    Returns
    -------
    dict
        ``n_vertices``, ``n_triangles``, ``bounds_m`` (min, max), ``images`` (paths).
    """
    g = _pygltflib()
    gl = g.GLTF2().load(os.fspath(path))
    base = os.path.dirname(os.fspath(path))
    if gl.asset.version != "2.0":
        raise ValidationError(f"{path}: glTF version must be 2.0, got {gl.asset.version!r}")
    size = os.path.getsize(os.path.join(base, gl.buffers[0].uri))
    if size < gl.buffers[0].byteLength:
        raise ValidationError(f"{path}: buffer holds {size} bytes, declared {gl.buffers[0].byteLength}")
    for acc in gl.accessors:
        view = gl.bufferViews[acc.bufferView]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[acc.type] * 4
        if acc.count * width > view.byteLength or view.byteOffset + view.byteLength > gl.buffers[0].byteLength:
            raise ValidationError(f"{path}: accessor of {acc.count} x {acc.type} does not fit its buffer view")
    prim = gl.meshes[0].primitives[0]
    attrs = prim.attributes
    if None in (attrs.POSITION, attrs.NORMAL, attrs.TANGENT, attrs.TEXCOORD_0):
        raise ValidationError(f"{path}: the primitive lacks POSITION, NORMAL, TANGENT or TEXCOORD_0")
    mat = gl.materials[prim.material]
    pbr = mat.pbrMetallicRoughness
    tex = [pbr.baseColorTexture.index, mat.normalTexture.index, pbr.metallicRoughnessTexture.index]
    images = [os.path.join(base, gl.images[gl.textures[t].source].uri) for t in tex]
    for p in images:
        if not os.path.isfile(p):
            raise ValidationError(f"{path}: texture {p} is missing")
    pos = gl.accessors[attrs.POSITION]
    return {
        "n_vertices": pos.count,
        "n_triangles": gl.accessors[prim.indices].count // 3,
        "bounds_m": (pos.min, pos.max),
        "images": images,
    }
