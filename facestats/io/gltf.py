"""A subject as a glTF 2.0 asset: the face mesh with a metallic-roughness PBR material made from the fitted maps.

:func:`write_gltf` writes ``face.gltf`` (JSON), ``face.bin`` (geometry) and five
PNG textures, through pygltflib:

* ``base_color.png`` — the diffuse albedo α (Weyrich et al. 2006 eq. 9),
  sRGB-encoded 8-bit as glTF requires for ``baseColorTexture`` (IEC 61966-2-1);
* ``normal.png`` — the fitted normal map in the mesh's tangent space
  (:meth:`facestats.io.mesh.FaceMesh.tangent_frames`: x along ∂p/∂u, y up the
  texture, z the mesh normal — glTF's "+Y up" convention), stored linearly as
  (n + 1)/2; the mesh carries the matching ``TANGENT`` attribute (with w);
* ``metallic_roughness.png`` — linear 8-bit, G = roughness, B = metallic = 0
  (skin is a dielectric), R unused (0);
* ``specular.png`` — ``KHR_materials_specular``'s ``specularTexture``: linear
  8-bit RGBA, A = min(4ρs, 1) (the specular weight; the extension reads only
  A, RGB are written white);
* ``specular_color.png`` — its ``specularColorTexture``: sRGB-encoded 8-bit
  grey, max(4ρs, 1)/K with ``specularColorFactor`` = (K, K, K) (below).

The mesh covers more than the measured face (most of the ICT head: scalp, ears,
neck), and the sampler filters across the face's edge (trilinear mipmaps), so
the base colour, the roughness and the two specular maps hold, off the measured
face, the value of the nearest measured texel
(:class:`facestats.io.exr_set.FaceFill`; measured texels unchanged) and the
normal map (0, 0, 1), the mesh's own normal (also where a face
texel has no fitted normal: NaN, which the schema allows); the EXR set's
``region.exr`` says which texels are measured.

Roughness conversion.  glTF's specular lobe is GGX (Trowbridge-Reitz) with
α = roughness²; the fitted lobe is Beckmann with width m (eq. 13).  α_GGX =
c·m with c = :data:`GGX_PER_BECKMANN` = 0.92, the least-squares match of the
projected distributions D(θ) cos θ over the hemisphere (the optimum is
0.913-0.923 for m in 0.2-0.4, the range of skin; ``tests/io/test_export_formats.py``
recomputes it), so roughness = sqrt(0.92 m).  glTF's roughness ends at 1, i.e. m =
1/0.92 = 1.087 (:data:`M_ROUGHNESS_LIMIT`); the schema allows m up to 10, and
rougher measured texels are written as roughness 1: their count is in the file's
``extras.facestats.roughness_clamp`` (``texels_clamped`` of ``texels_measured``)
and raises a :class:`~facestats.errors.FacestatsWarning`.

Specular strength (``KHR_materials_specular``).  Weyrich's eq. 12-13, as
:func:`facestats.model.brdf.torrance_sparrow` evaluates it, is

    f = (ρs/π) D_W G F_r(ωo·H) / ((N·ωi)(N·ωo)),   D_W = exp(−tan²δ/m²)/(m² cos⁴δ),

with D_W the Beckmann distribution printed *without* 1/π, G the V-groove
shadowing and F_r the exact unpolarised Fresnel reflectance of η = 1.38.  The
normalised Beckmann distribution (∫ D cos δ dω = 1) is D_B = D_W/π, so

    f = ρs D_B G F_r / ((N·ωi)(N·ωo)) = 4ρs · [D_B G F_r / (4 (N·ωi)(N·ωo))],

4ρs times the Cook-Torrance microfacet BRDF (``tests/io/test_export_formats.py``
checks this against :func:`~facestats.model.brdf.torrance_sparrow` to 1e-10).
glTF's dielectric specular is F · D · V with V = G/(4 |N·L||N·V|): the same
bracket, with GGX in place of Beckmann (the roughness above) and F in place of
F_r, so the Fresnel factor glTF must carry is F = 4ρs F_r(ωo·H).  With
``KHR_materials_ior`` and ``KHR_materials_specular`` (its §Implementation; three.js
evaluates the same) glTF's factor is

    F(c) = s · [F0' + (1 − F0')(1 − c)⁵],   F0' = min(F0_η k, 1),   F0_η = ((η − 1)/(η + 1))²,

c = V·H, s = specularFactor × specularTexture.a ∈ [0, 1] (specularFactor ≤ 1
by the schema), k = specularColorFactor × specularColorTexture.rgb ≥ 0 (no
upper bound); F0_η = 0.02549 for η = 1.38, which is F_r at normal incidence
exactly.  At normal incidence glTF's F0 = s k F0_η, and eq. 12's 4ρs F0_η; at
grazing incidence glTF's F90 = s, and eq. 12's 4ρs.  The exporter writes

    s = min(4ρs, 1),   k = min(max(4ρs, 1), 1/F0_η),   so   s k = 4ρs   for ρs ≤ 1/(4 F0_η) = 9.81:

* ρs ≤ 1/4 (:data:`RHO_S_EXACT`): s = 4ρs, k = 1, so glTF's F is 4ρs times
  Schlick's approximation of F_r, as eq. 12's is 4ρs F_r, at every angle.
  Schlick reads the exact F_r of η = 1.38 low by 0.8 % at V·H = cos 20°,
  4.4 % at 30°, 13 % at 40°, 23 % at 53°, and high by up to 11 % beyond 70°.
  This is the "4ρs where ρs ≤ 0.25" of the weight s alone, which cannot
  exceed 1.
* 1/4 < ρs ≤ 9.81 (:data:`RHO_S_F0_LIMIT`): the weight saturates at s = 1 and
  k = 4ρs carries the rest, so F0 = 4ρs F0_η is still exact, but F90 = 1
  where eq. 12 gives 4ρs > 1 (more than a surface of Fresnel mirror facets
  reflects, which glTF cannot express); at every angle glTF's F lies between
  the weight alone's F0_η + (1 − F0_η)(1 − c)⁵ and 4ρs times it.  29.5 % of
  the default store's measured texels are here (ρs median 0.217, 99th
  percentile 0.35, maximum 1.14): the weight alone would have cut their F0 by
  up to 4.5×.
* ρs > 9.81: glTF's own clamp min(F0_η k, 1) = 1 is reached; k is clamped to
  1/F0_η, so F0 = 1 (a mirror) instead of 4ρs F0_η.  9.81 is the top of the
  schema's domain of ρs (:data:`facestats.io.schema.TS_RHO_S_MAX`: eq. 12's
  directional albedo 4ρs F_r(0) reaches 1 there), and :func:`write_gltf`
  refuses a subject beyond the schema, so this case is counted (always 0 in
  its files) but never reached through it.

``specularColorTexture`` holds k/K with K ≥ the largest k of the map, rounded
up so that 1/K is an 8-bit sRGB code: texels with ρs ≤ 1/4 decode to k = 1
exactly.  The counts of measured texels (region > 0, finite ρs) in the last
two cases go into the file's ``extras.facestats.specular``
(``texels_f90_capped``, ``texels_clamped``, of ``texels_measured``; also in
:func:`read_gltf_summary`).  ``KHR_materials_specular`` is in
``extensionsUsed``, not ``extensionsRequired``: a viewer without it shows the
default specular (with ``KHR_materials_ior``: F0 = F0_η, F90 = 1, i.e. ρs =
1/4 everywhere).  glTF also weights the base colour by 1 − max F
(``fresnel_mix``), where eq. 12's diffuse term is not: 1 − 0.102 ρs at normal
incidence.

What glTF cannot carry: the Blinn-Phong fit, and subsurface scattering.

Units and frame: glTF is in metres, +y up, +z the front of the asset —
facestats' world frame, so vertices are scaled by 0.001 and not rotated.  UV:
glTF's texture origin is the top-left corner with v down, facestats'
convention, so UVs are written as stored.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

from facestats.errors import DependencyError, FacestatsWarning, ValidationError
from facestats.io.exr_set import FaceFill, check_export_subject, tangent_space_normals
from facestats.io.ids import SUBJECT_ID_PATTERN
from facestats.io.images import linear_to_srgb, srgb_to_linear, write_image
from facestats.io.mesh import FaceMesh, subject_mesh

__all__ = [
    "GGX_PER_BECKMANN",
    "M_ROUGHNESS_LIMIT",
    "RHO_S_EXACT",
    "RHO_S_F0_LIMIT",
    "beckmann_to_gltf_roughness",
    "rho_s_to_gltf_specular",
    "write_gltf",
    "read_gltf_summary",
]

#: α_GGX / m: least-squares match of the projected Beckmann and GGX distributions (module docstring).
GGX_PER_BECKMANN = 0.92
#: Largest Beckmann m that glTF's roughness (at most 1) carries: 1 / :data:`GGX_PER_BECKMANN` = 1.087.
M_ROUGHNESS_LIMIT = 1.0 / GGX_PER_BECKMANN
#: IOR of skin for ``KHR_materials_ior`` (Weyrich et al. 2006 §3, η ≈ 1.38).
_IOR = 1.38
#: glTF's dielectric F0 of that IOR, ((η − 1)/(η + 1))² = 0.02549: Weyrich's F_r at normal incidence.
_F0 = ((_IOR - 1) / (_IOR + 1)) ** 2
#: Largest ρs whose whole Fresnel curve glTF scales like eq. 12: specular weight 4ρs ≤ 1 (module docstring).
RHO_S_EXACT = 0.25
#: Largest ρs whose normal-incidence F0 = 4ρs F0_η glTF can carry (F0 ≤ 1): 1/(4 F0_η) = 9.81, the top of the
#: schema's domain (:data:`facestats.io.schema.TS_RHO_S_MAX`, where eq. 12 reflects all light at normal incidence).
RHO_S_F0_LIMIT = 1 / (4 * _F0)
_SPECULAR_EXTENSION = "KHR_materials_specular"


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


def rho_s_to_gltf_specular(rho_s):
    """``KHR_materials_specular``'s weight s and colour scale k for a Torrance-Sparrow ρs (module docstring).

    s = min(4ρs, 1) (``specularFactor`` × ``specularTexture.a``) and k = min(max(4ρs, 1), 1/F0_η)
    (``specularColorFactor`` × ``specularColorTexture.rgb``), so glTF's dielectric F0 = F0_η s k equals
    Weyrich's 4ρs F0_η for ρs ≤ :data:`RHO_S_F0_LIMIT` (F0_η = ((1.38 − 1)/(1.38 + 1))²), and its F90 = s
    equals eq. 12's 4ρs for ρs ≤ :data:`RHO_S_EXACT`.

    Parameters
    ----------
    rho_s : array_like
        ρs ≥ 0 in the convention of :func:`facestats.model.brdf.torrance_sparrow` (negative values count as 0).

    Returns
    -------
    s, k : ndarray
        float64, shape of ``rho_s``; s in [0, 1], k in [1, 1/F0_η].
    """
    four = 4 * np.clip(np.asarray(rho_s, np.float64), 0, None)
    return np.minimum(four, 1.0), np.clip(four, 1.0, 1 / _F0)


def _textures(ds, mesh, out):
    """Write the five PNGs (all but the normal map filled off the measured face); file names, K, clamp report."""
    fill = FaceFill(ds["region"].values)
    face = fill.face
    alb = fill(np.asarray(ds["albedo"].values, np.float64))
    write_image(os.path.join(out, "base_color.png"), alb, srgb=True)
    nt = tangent_space_normals(ds, mesh.tangent_frames(int(ds.sizes["v"])))  # (0, 0, 1) where none is measured
    write_image(os.path.join(out, "normal.png"), (nt + 1) / 2)
    del nt
    m = np.asarray(ds["ts_m"].values, np.float64)
    rough = beckmann_to_gltf_roughness(fill(m))
    mr = np.stack([np.zeros_like(rough), rough, np.zeros_like(rough)], -1)
    write_image(os.path.join(out, "metallic_roughness.png"), mr)
    colour_factor, report = _specular_textures(ds, fill, out)
    names = ("base_color.png", "normal.png", "metallic_roughness.png", "specular.png", "specular_color.png")
    return names, colour_factor, report, _roughness_report(ds, m[face & np.isfinite(m)])


def _roughness_report(ds, measured_m) -> dict:
    """How many measured texels are rougher than glTF's roughness 1 carries (module docstring); warns if any."""
    report = {
        "texels_measured": int(measured_m.size),
        "texels_clamped": int(np.count_nonzero(measured_m > M_ROUGHNESS_LIMIT)),
        "m_limit": M_ROUGHNESS_LIMIT,
    }
    if report["texels_clamped"]:
        warnings.warn(
            f"glTF export of subject {ds.attrs.get('subject_id', '?')!r}: {report['texels_clamped']} of "
            f"{report['texels_measured']} measured texels have m > {M_ROUGHNESS_LIMIT:.3f}, rougher than glTF's "
            "roughness 1 (GGX alpha = 1); they are exported as roughness 1",
            FacestatsWarning,
            stacklevel=4,  # the caller of write_gltf
        )
    return report


def _specular_textures(ds, fill, out):
    """Write ``specular.png`` (A = s) and ``specular_color.png`` (k/K, sRGB); returns K and the clamp report."""
    rho = np.asarray(ds["ts_rho_s"].values, np.float64)
    measured = fill.face & np.isfinite(rho)
    s, k = rho_s_to_gltf_specular(fill(rho))
    # K: the largest k, rounded up so that 1/K is an 8-bit sRGB code (k = 1 then decodes to exactly 1/K)
    code = max(int(np.floor(float(linear_to_srgb(1 / float(k.max()))) * 255)), 1)
    colour_factor = 1 / float(srgb_to_linear(code / 255))
    rgba = np.concatenate([np.ones(s.shape + (3,)), s[..., None]], -1)  # RGB unused by the extension: white
    write_image(os.path.join(out, "specular.png"), rgba)
    write_image(os.path.join(out, "specular_color.png"), np.repeat((k / colour_factor)[..., None], 3, -1), srgb=True)
    values = rho[measured]
    report = {
        "mapping": "F0 = ((ior-1)/(ior+1))^2 * 4 rho_s: specularTexture.a = min(4 rho_s, 1), "
        "specularColorFactor * specularColorTexture = max(4 rho_s, 1), at most (ior+1)^2/(ior-1)^2",
        "texels_measured": int(values.size),
        "texels_f90_capped": int(np.count_nonzero(values > RHO_S_EXACT)),
        "texels_clamped": int(np.count_nonzero(values > RHO_S_F0_LIMIT)),
        "rho_s_exact": RHO_S_EXACT,
        "rho_s_f0_limit": RHO_S_F0_LIMIT,
    }
    return colour_factor, report


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
    """Write a map subject as a glTF 2.0 asset (``NAME.gltf``, ``NAME.bin``, five PNGs) into ``out_dir``.

    The material carries ρs through ``KHR_materials_specular`` (module docstring); how many measured texels
    lie beyond what it expresses is in the file's ``extras.facestats.specular``.

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject with ``albedo``, ``normal``, ``ts_m``, ``ts_rho_s`` and ``region``.
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
    SchemaError
        A subject the store would refuse (:func:`facestats.io.exr_set.check_export_subject`).

    Warns
    -----
    FacestatsWarning
        Measured texels with m > :data:`M_ROUGHNESS_LIMIT` (1.087), exported as roughness 1 (their count is in
        ``extras.facestats.roughness_clamp.texels_clamped``).
    """

    if not isinstance(name, str) or not SUBJECT_ID_PATTERN.fullmatch(name):
        raise ValidationError(
            "name must be a plain file stem (1-64 letters, digits, '.', '_' or '-', starting with a letter or "
            f"digit; no folder), got {name!r}"
        )
    g = _pygltflib()
    check_export_subject(ds, "a glTF asset")
    missing = [v for v in ("albedo", "normal", "ts_m", "ts_rho_s", "region") if v not in ds.data_vars]
    if missing:
        raise ValidationError(f"subject {ds.attrs.get('subject_id', '?')!r} lacks the maps {missing} glTF needs")
    fm = mesh if isinstance(mesh, FaceMesh) else subject_mesh(ds, mesh)
    out = os.fspath(out_dir)
    images, colour_factor, specular, roughness = _textures(ds, fm, out)
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
        extensions={
            "KHR_materials_ior": {"ior": _IOR},
            _SPECULAR_EXTENSION: {
                "specularFactor": 1.0, "specularTexture": {"index": 3},
                "specularColorFactor": [colour_factor] * 3, "specularColorTexture": {"index": 4},
            },
        },
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
        images=[g.Image(uri=u) for u in images],
        textures=[g.Texture(source=i, sampler=0) for i in range(len(images))],
        buffers=[g.Buffer(byteLength=len(blob), uri=f"{name}.bin")],
        bufferViews=views,
        accessors=accessors,
        extensionsUsed=["KHR_materials_ior", _SPECULAR_EXTENSION],  # not required: viewers without it still work
        extras={
            "facestats": {
                "geometry": fm.geometry,
                "roughness": "sqrt(0.92 m), Beckmann m -> GGX alpha",
                "roughness_clamp": roughness,
                "specular": specular,
            }
        },
    )
    path = os.path.join(out, f"{name}.gltf")
    gltf.save_json(path)
    return path


def read_gltf_summary(path) -> dict:
    """Read a glTF file back with pygltflib and check what :func:`write_gltf` promises; a short summary.

    Checks: version 2.0, one triangle primitive whose accessors fit their
    buffer views and the binary file, POSITION/NORMAL/TANGENT/TEXCOORD_0
    present, a metallic-roughness material whose three textures exist, and
    the textures of its ``KHR_materials_specular`` when it has one.

    Parameters
    ----------
    path : str or path-like
        The ``.gltf`` file (its buffer and textures beside it).

    Returns
    -------
    dict
        ``n_vertices``, ``n_triangles``, ``bounds_m`` (min, max), ``images`` (paths), ``specular`` and
        ``roughness_clamp`` (the ``extras.facestats`` reports of :func:`write_gltf`, None in files written
        before them).
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
    spec = (mat.extensions or {}).get(_SPECULAR_EXTENSION) or {}
    tex += [spec[key]["index"] for key in ("specularTexture", "specularColorTexture") if key in spec]
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
        "specular": ((gl.extras or {}).get("facestats") or {}).get("specular"),
        "roughness_clamp": ((gl.extras or {}).get("facestats") or {}).get("roughness_clamp"),
    }
