"""A subject as a Mitsuba 3 scene (XML file and Python dict), and rendering it.

Mitsuba 3 (``pip install mitsuba``; the CPU variant ``scalar_rgb`` is used) is
an optional dependency: building the XML needs nothing, building the dict and
rendering raise :class:`facestats.errors.DependencyError` without it.

The scene (units: **mm** for lengths, so **mm⁻¹** for σ; world frame of
facestats, +y up, +z towards the camera) holds the subject's face mesh
(:func:`facestats.io.mesh.subject_mesh`), a perspective camera, a light probe
as ``envmap`` and one of two materials:

``material="surface"`` — the fitted maps.  Weyrich et al. 2006 eq. 12-13 with
D printed without 1/π, D_W = π D_B where D_B = exp(−tan²δ/m²)/(π m² cos⁴δ) is
the normalised Beckmann distribution Mitsuba uses with α = m, so

    f_TS = ρs/π · D_W G F/((N·ωi)(N·ωo)) = 4 ρs · D_B G F/(4 (N·ωi)(N·ωo)),

i.e. 4ρs times Mitsuba's ``roughconductor`` with ``distribution="beckmann"``,
``alpha`` = the m map (a texture: no per-region shapes are needed) and
Fresnel of a dielectric (``eta`` = 1.38, ``k`` = 0 makes the conductor Fresnel
the dielectric one).  Differences, stated: Mitsuba's G is Smith's (for
Beckmann, Walter et al. 2007's rational fit of G1, exactly 1 while
a = 1/(m tan θ) ≥ 1.6, i.e. θ ≤ 51° at m = 0.5), eq. 13's is the V-cavity
term (1 unless 2(N·H) min(N·ωi, N·ωo) < ωo·H); below those angles both are 1
and Mitsuba's BSDF equals eq. 12 to float32 precision (measured |ratio − 1|
≤ 3e-5; at θi = θo = 60°, m = 0.5 Smith gives 0.979 of it).  The diffuse term is
eq. 9-10's α/π F_t(ωi) F_t(ωo), F_t = 1 − F_r the smooth Fresnel transmittance at
η (what :mod:`facestats.relight` and the fit use).  Mitsuba's ``diffuse`` is α/π
without them: 5.3 % bright at normal incidence and view, 6.3 % at θi = θo = 40°,
15 % at 60°, and rendered faces 8-13 % brighter than :func:`facestats.relight.stage.relight_subject`
under the same probe (docs/export.md).  Mitsuba's
smooth ``plastic`` (``nonlinear`` false) evaluates its diffuse part as
ρ/(1 − F_dr) · η⁻² · (1 − F_r(θi))(1 − F_r(θo))/π with F_dr the internal
diffuse Fresnel reflectance (Egan & Hilgeman's fit, Mitsuba's
``fresnel_diffuse_reflectance(1/η)``), exactly eq. 9-10's form; so the
diffuse part is a ``plastic`` with ``specular_reflectance`` 0 (its mirror
lobe off: the rough specular is the conductor's) and ``diffuse_reflectance``
ρ = c α, c = η² (1 − F_dr(η)) = 0.9253 at η = 1.38 (:func:`plastic_reflectance_scale`,
through :func:`facestats.model.fresnel.diffuse_fresnel_reflectance`, the same
fit with constants rounded otherwise than Mitsuba's, whose 1 − F_dr is 1.6e-4
relative lower: its diffuse is that much brighter).  The smooth
F_t (not the rough interface's transmittance of ``roughplastic``, whose α is
one number per material, not a texture) is eq. 10's.
Mitsuba has no additive BSDF, so the sum is ``blendbsdf`` with weight w of
that ``plastic`` with ρ = c α/(1 − w) and the specular with ``specular_reflectance``
4ρs/w ((1 − w)·α F_t F_t/π + w·4ρs/w·f = α F_t F_t/π + 4ρs·f); these two scaled maps are
written as ``mitsuba_diffuse.exr`` and ``mitsuba_specular.exr``.  w = min(0.5, 1 − max α)
(:func:`blend_weight`; 0.5 for α ≤ 0.5): Mitsuba's spectral variants clamp a reflectance
texture to [0, 1], so a diffuse map above 1 (2α with a fixed w = 0.5, on 18.6 % of the
default store's face texels) rendered light skin too dark there (×0.77 in red for S141); the
specular map is ``raw`` and not clamped.  Like the EXR
set's ``ts_m.exr`` (the ``alpha`` texture), they hold, off the measured face
(which most of the ICT head's mesh lies outside: scalp, ears, neck), the value
of the nearest measured texel (:class:`facestats.io.exr_set.FaceFill`), not 0.

The mesh is an OBJ: Mitsuba reads a PLY's texture coordinates as stored (v up),
but flips an OBJ's (v down, the maps' convention), so the maps would lie upside
down on a PLY; ``mesh_format="ply"`` is refused.

``material="subsurface"`` — Mitsuba 3 has no dipole; its recommended
replacement is volumetric path tracing: a ``roughdielectric`` boundary
(``int_ior`` 1.38, Beckmann α = the m map) around a ``homogeneous`` medium
with σt = σa + σ's and single-scattering albedo σ's/σt per channel and an
isotropic phase function (the similarity relation that the dipole's reduced
coefficients assume).  Mitsuba takes RGB values in [0, 1], so ``sigma_t`` is
σt / max(σt) with ``scale`` = max(σt) in mm⁻¹ (the scene is in mm).  The medium
is homogeneous per subject (§5.4): the modulation texture M is not
represented, and the boundary's Fresnel reflection stands for the specular
lobe (it equals eq. 12 with ρs = 1/4).  The medium fills what the mesh encloses,
tracked by Mitsuba along each path, and the face mesh encloses nothing: the default
``ict-48`` face is open at the eyes, the mouth and a rim around the head's sides and
neck (362 boundary edges, :meth:`facestats.io.mesh.FaceMesh.boundary_edges`), so the
medium has no end behind the face and through those openings.  Against the mesh
closed by fans over its openings the face renders 1.4-2.1 % brighter beyond 2 cm of
them and 3-10 % within (docs/export.md); the mesh is kept open (closing it would
invent geometry: skin over the eyes and mouth) and the export warns
(:class:`facestats.errors.FacestatsWarning`) when a subsurface scene's mesh has
openings.  Paths are unlimited in length (``max_depth`` −1, ended by
Russian roulette): skin's red scatters hundreds of times before it leaves.
Under uniform light a flat slab of this material reflects what a Monte Carlo
solution of the same transport (semi-infinite medium, isotropic phase,
smooth Fresnel boundary) gives, within 1.2 % (tested to 3 %); the dipole's total
diffuse reflectance R_d (:func:`facestats.model.dipole.total_diffuse_reflectance`,
what a fitted albedo means) plus F(0) is 2-19 % above it for S003's
σ's/σt = 0.98, 0.88, 0.80 — the diffusion approximation's error, not the
scene's.

Light probe: a latitude-longitude HDR file (EXR or Radiance ``.hdr``; Mitsuba
reads it itself) in facestats' one lat-long convention
(:mod:`facestats.model.sphere`: centre column towards −z, Debevec's).  Mitsuba's
``envmap`` puts its centre column at +z (u = atan2(x, −z)/2π, ``envmap.cpp``),
so the emitter gets ``to_world`` = a 180° turn about +y: the same file then
means the same lighting in Mitsuba, in :mod:`facestats.relight` and in
:func:`facestats.pipeline.validation.render_probe`.  Without a probe a studio
probe is written (:func:`facestats.io.probes.write_studio_probe`).
"""

from __future__ import annotations

import json
import os
import shutil
import warnings
import xml.etree.ElementTree as ET

import numpy as np

from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_finite, check_choice, check_integer
from facestats.errors import DependencyError, FacestatsWarning, ValidationError
from facestats.io.images import write_exr
from facestats.io.probes import read_light_probe, write_studio_probe
from facestats.model.fresnel import diffuse_fresnel_reflectance

__all__ = [
    "MATERIALS",
    "SCENE_FILES",
    "check_medium",
    "blend_weight",
    "plastic_reflectance_scale",
    "MITSUBA_VARIANT",
    "require_mitsuba",
    "scene_spec",
    "spec_to_dict",
    "spec_to_xml",
    "write_mitsuba_scene",
    "render_scene",
]

MATERIALS = ("surface", "subsurface")
MITSUBA_VARIANT = "scalar_rgb"
#: The EXR files a Mitsuba scene writes beside the EXR set, by stem: a subject map of that name would collide.
SCENE_FILES = {
    "mitsuba_diffuse": "the diffuse reflectance of the blend",
    "mitsuba_specular": "the specular reflectance of the blend",
    "probe": "the light probe",
}
#: Tag of each plugin type in the XML format.
_TAGS = {
    "scene": "scene",
    "diffuse": "bsdf",
    "plastic": "bsdf",
    "roughconductor": "bsdf",
    "roughdielectric": "bsdf",
    "blendbsdf": "bsdf",
    "obj": "shape",
    "ply": "shape",
    "envmap": "emitter",
    "perspective": "sensor",
    "hdrfilm": "film",
    "independent": "sampler",
    "path": "integrator",
    "volpath": "integrator",
    "bitmap": "texture",
    "homogeneous": "medium",
    "isotropic": "phase",
    "gaussian": "rfilter",
}


def require_mitsuba():
    """The ``mitsuba`` module with the ``scalar_rgb`` variant set, or :class:`DependencyError`."""
    try:
        import mitsuba as mi
    except ImportError as exc:
        raise DependencyError(
            "Mitsuba 3 is not installed (needed to build the scene dict and to render): "
            f"pip install mitsuba, or pip install 'facestats[render]' ({exc})"
        ) from None
    if mi.variant() != MITSUBA_VARIANT:
        mi.set_variant(MITSUBA_VARIANT)
    return mi


def _bitmap(filename, raw=True):
    return {"type": "bitmap", "filename": filename, "raw": raw}


def _rgb(values):
    return {"type": "rgb", "value": [float(v) for v in values]}


def blend_weight(albedo) -> float:
    """The ``blendbsdf`` weight w of the surface material: min(0.5, 1 − max α), at least 1e-3 (module docstring).

    The diffuse map c α/(1 − w) (c = :func:`plastic_reflectance_scale` < 1) then stays within [0, 1], which
    Mitsuba's spectral variants clamp a reflectance to.

    Parameters
    ----------
    albedo : array_like
        The diffuse albedo α (any shape); NaN is ignored.

    Returns
    -------
    float
        w in [1e-3, 0.5]; 0.5 for an albedo ≤ 0.5 (or all NaN).
    """
    top = float(np.nanmax(np.asarray(albedo, np.float64), initial=0.0))
    return float(min(0.5, max(1.0 - top, 1e-3)))


def plastic_reflectance_scale(eta=ETA_SKIN) -> float:
    """c = η² (1 − F_dr(η)): Mitsuba ``plastic``'s ``diffuse_reflectance`` per unit albedo α (module docstring).

    Mitsuba 3's smooth ``plastic`` with ``nonlinear`` false evaluates its diffuse part as
    ρ/(1 − F_dr) · η⁻² · F_t(θi) F_t(θo)/π (F_t = 1 − F_r, smooth Fresnel transmittance at relative index η;
    F_dr the internal diffuse Fresnel reflectance); with ρ = c α it is Weyrich et al. 2006 eq. 9-10's diffuse
    BRDF α/π F_t(ωi) F_t(ωo).  F_dr is Egan & Hilgeman's polynomial
    (:func:`facestats.model.fresnel.diffuse_fresnel_reflectance`, Jensen et al. 2001; Suzuki et al. eq. 9),
    which Mitsuba evaluates with its constants rounded to four digits: 1 − F_dr differs by 1.6e-4 relative at
    η = 1.38.

    Parameters
    ----------
    eta : float
        Relative index of refraction of skin over air, in [1, 3].

    Returns
    -------
    float
        c, dimensionless (0.9253 at η = 1.38).
    """
    e = as_finite(eta, "eta", 1, 3)
    return float(e * e * (1 - diffuse_fresnel_reflectance(e)))


def _material(material, files, coefficients, eta, weight=0.5):
    """The shape's BSDF (and interior medium) for ``material`` (module docstring)."""
    if material == "surface":
        bsdf = {
            "type": "blendbsdf",
            "weight": float(weight),
            "diffuse": {  # α F_t F_t/π (module docstring): the map holds c α/(1 − w), the mirror lobe is off
                "type": "plastic",
                "diffuse_reflectance": _bitmap(files["mitsuba_diffuse"], raw=False),
                "specular_reflectance": 0.0,
                "int_ior": float(eta),
                "ext_ior": 1.0,
                "nonlinear": False,
            },
            "specular": {
                "type": "roughconductor",
                "distribution": "beckmann",
                "alpha": _bitmap(files["ts_m"]),
                "eta": float(eta),
                "k": 0.0,
                "specular_reflectance": _bitmap(files["mitsuba_specular"]),
            },
        }
        return bsdf, None
    sa, sp = check_medium(coefficients["sigma_a"], coefficients["sigma_s_prime"])
    bsdf = {
        "type": "roughdielectric",
        "distribution": "beckmann",
        "alpha": _bitmap(files["ts_m"]),
        "int_ior": float(eta),
        "ext_ior": 1.0,
    }
    st = sa + sp
    medium = {  # Mitsuba takes RGB in [0, 1]: σt = rgb · scale, with scale = max σt (mm⁻¹, the scene unit)
        "type": "homogeneous",
        "sigma_t": _rgb(st / st.max()),
        "albedo": _rgb(sp / st),
        "scale": float(st.max()),
        "phase": {"type": "isotropic"},
    }
    return bsdf, medium


def check_medium(sigma_a, sigma_s_prime):
    """σa and σ's (mm⁻¹, per channel) of a subsurface medium: finite, ≥ 0, with σt = σa + σ's > 0 in every channel.

    Mitsuba's ``homogeneous`` medium takes albedo σ's/σt and σt (module docstring); with σt = 0 in a channel
    the albedo is 0/0, a NaN that Mitsuba renders as NaN pixels without complaint.

    Parameters
    ----------
    sigma_a, sigma_s_prime : array_like, shape (C,)
        Absorption and reduced scattering coefficients per channel, mm⁻¹.

    Returns
    -------
    tuple of ndarray
        (σa, σ's) as float64.

    Raises
    ------
    ValidationError
        Naming the channel and its values.
    """
    sa = as_finite(sigma_a, "sigma_a")
    sp = as_finite(sigma_s_prime, "sigma_s_prime")
    if sa.shape != sp.shape or sa.ndim != 1:
        raise ValidationError(f"sigma_a and sigma_s_prime must be 1-D of one length, got {sa.shape} and {sp.shape}")
    for k in range(sa.size):  # loop over the three channels
        if not (sa[k] >= 0 and sp[k] >= 0 and sa[k] + sp[k] > 0):
            raise ValidationError(
                "a subsurface medium needs sigma_a >= 0, sigma_s_prime >= 0 and sigma_t = sigma_a + sigma_s_prime "
                f"> 0 in every channel, got sigma_a = {float(sa[k])!r}, sigma_s_prime = {float(sp[k])!r} mm-1 in "
                f"channel {k}"
            )
    return sa, sp


def scene_spec(
    files,
    coefficients,
    *,
    material="surface",
    origin=(0.0, 0.0, 700.0),
    target=(0.0, 0.0, 0.0),
    fov=22.0,
    width=256,
    height=256,
    spp=64,
    max_depth=-1,
    eta=ETA_SKIN,
    probe_scale=1.0,
    weight=0.5,
):
    """The scene as a plain dict in Mitsuba's dict layout, with transforms as ``{"type": "look_at", ...}``.

    Parameters
    ----------
    files : dict
        File names: ``mesh``, ``probe``, ``ts_m``, ``mitsuba_diffuse``, ``mitsuba_specular``.
    coefficients : dict
        ``sigma_a`` and ``sigma_s_prime`` per channel (mm⁻¹).
    material : {"surface", "subsurface"}
    origin, target : array_like, shape (3,)
        Camera centre and aim point, mm (default: frontal, 70 cm away).
    fov : float
        Horizontal field of view, degrees.
    width, height, spp : int
        Image size and samples per pixel.
    max_depth : int
        Longest path in bounces (``volpath`` for the subsurface material); −1
        (default): unlimited, paths ended by Mitsuba's Russian roulette after 5
        bounces, which is unbiased.  A limit biases the subsurface material
        dark where the medium scatters most: skin's red (σ's/σt ≈ 0.98) takes
        hundreds of scattering events, and a limit of 64 loses 3-4 % of its
        reflectance under uniform light (measured on a flat slab of subject S003).
    eta : float
        Relative index of refraction of skin, in [1, 3] (the surface material's ``plastic`` and conductor, the
        subsurface boundary).
    probe_scale : float
        Factor on the probe's radiance.
    weight : float
        The surface material's ``blendbsdf`` weight w, in (0, 1): the maps were written as c α/(1 − w)
        (c = :func:`plastic_reflectance_scale` of ``eta``) and 4ρs/w (:func:`blend_weight`).

    Returns
    -------
    dict
    """
    check_choice(material, "material", MATERIALS)
    as_finite(eta, "eta", 1, 3)
    as_finite(weight, "weight", 0, 1, low_inclusive=False, high_inclusive=False)
    as_finite(fov, "fov", 1, 170, unit="deg")
    for name, value in (("width", width), ("height", height), ("spp", spp)):
        check_integer(value, name, 1, 1 << 14)
    if check_integer(max_depth, "max_depth") != -1 and not 1 <= max_depth <= 100000:
        raise ValidationError(f"max_depth must be -1 (unlimited) or an integer in [1, 100000], got {max_depth!r}")
    o = as_finite(origin, "origin")
    t = as_finite(target, "target")
    if o.shape != (3,) or t.shape != (3,) or np.allclose(o, t):
        raise ValidationError(f"origin and target must be distinct 3-vectors (mm), got {list(o)} and {list(t)}")
    bsdf, medium = _material(material, files, coefficients, eta, weight)
    shape = {"type": os.path.splitext(files["mesh"])[1][1:], "filename": files["mesh"], "bsdf": bsdf}
    if medium is not None:
        shape["interior"] = medium
    return {
        "type": "scene",
        "integrator": {"type": "volpath" if medium is not None else "path", "max_depth": int(max_depth)},
        "sensor": {
            "type": "perspective",
            "fov": float(fov),
            "to_world": {
                "type": "look_at",
                "origin": list(map(float, o)),
                "target": list(map(float, t)),
                "up": [0.0, 1.0, 0.0],
            },
            "film": {"type": "hdrfilm", "width": int(width), "height": int(height), "rfilter": {"type": "gaussian"}},
            "sampler": {"type": "independent", "sample_count": int(spp)},
        },  # fmt: skip
        "face": shape,
        "probe": {
            "type": "envmap",
            "filename": files["probe"],
            "scale": float(probe_scale),
            "to_world": {"type": "rotate", "axis": [0.0, 1.0, 0.0], "angle": 180.0},  # module docstring
        },
    }


def spec_to_dict(spec, base_dir=None):
    """A :func:`scene_spec` as the dict ``mitsuba.load_dict`` takes (file names joined to ``base_dir``).

    Parameters
    ----------
    spec : dict
        A :func:`scene_spec` (not modified).
    base_dir : str or os.PathLike, optional
        Folder of the scene's files (default: file names left as they are).

    Returns
    -------
    dict
        Transforms as ``mitsuba.ScalarTransform4f``.

    Raises
    ------
    DependencyError
        Mitsuba 3 is not installed.
    """
    mi = require_mitsuba()

    def convert(key, value):
        if isinstance(value, dict):
            if value.get("type") == "look_at":
                return mi.ScalarTransform4f().look_at(origin=value["origin"], target=value["target"], up=value["up"])
            if value.get("type") == "rotate":
                return mi.ScalarTransform4f().rotate(axis=value["axis"], angle=value["angle"])
            return {k: convert(k, v) for k, v in value.items()}
        if key == "filename" and base_dir is not None:
            return os.path.join(os.fspath(base_dir), value)
        return value

    return convert("", spec)


def _xml_value(parent, name, value):
    """One property of a plugin as an XML element."""
    if isinstance(value, dict):
        kind = value["type"]
        if kind == "rgb":
            ET.SubElement(parent, "rgb", name=name, value=", ".join(repr(float(v)) for v in value["value"]))
        elif kind == "look_at":
            tr = ET.SubElement(parent, "transform", name=name)
            ET.SubElement(
                tr, "lookat", **{k: ", ".join(repr(float(x)) for x in value[k]) for k in ("origin", "target", "up")}
            )
        elif kind == "rotate":
            tr = ET.SubElement(parent, "transform", name=name)
            ax = dict(zip("xyz", (repr(float(a)) for a in value["axis"])))
            ET.SubElement(tr, "rotate", **ax, angle=repr(float(value["angle"])))
        else:
            _xml_plugin(parent, value, name=name)
    elif isinstance(value, bool):
        ET.SubElement(parent, "boolean", name=name, value=str(value).lower())
    elif isinstance(value, (int, np.integer)):
        ET.SubElement(parent, "integer", name=name, value=str(int(value)))
    elif isinstance(value, (float, np.floating)):
        ET.SubElement(parent, "float", name=name, value=repr(float(value)))
    else:
        ET.SubElement(parent, "string", name=name, value=str(value))


def _xml_plugin(parent, spec, name=None, ident=None):
    attrs = {"type": spec["type"]}
    if ident is not None:
        attrs["id"] = ident
    elif name is not None and _TAGS[spec["type"]] not in ("bsdf", "film", "sampler", "rfilter", "phase"):
        attrs["name"] = name
    el = ET.SubElement(parent, _TAGS[spec["type"]], **attrs)
    for key, value in spec.items():
        if key != "type":
            _xml_value(el, key, value)
    return el


def spec_to_xml(spec) -> str:
    """A :func:`scene_spec` as Mitsuba 3 scene XML (``version="3.0.0"``); needs no Mitsuba installed.

    Parameters
    ----------
    spec : dict
        A :func:`scene_spec`.

    Returns
    -------
    str
        The XML document, indented, ending in a newline.
    """
    root = ET.Element("scene", version="3.0.0")
    for key, value in spec.items():
        if key != "type":
            _xml_plugin(root, value, ident=key)
    ET.indent(root)
    return ET.tostring(root, encoding="unicode") + "\n"


def write_mitsuba_scene(ds, out_dir, *, probe=None, material="surface", mesh=None, mesh_format="obj", **view):
    """Write a subject's Mitsuba 3 scene: EXR set, Mitsuba textures, probe, ``scene.xml`` and ``scene.json``.

    Parameters
    ----------
    ds : xarray.Dataset
        A map subject.
    out_dir : str or os.PathLike
        Existing directory to write into.
    probe : str or os.PathLike, optional
        Lat-long HDR light probe (copied beside the scene); default: a studio probe.
    material : {"surface", "subsurface"}
        See the module docstring.
    mesh : str or os.PathLike, optional
        The scan the maps belong to (default: the recorded procedural head).
    mesh_format : {"obj"}
        The mesh file written; "ply" is refused (module docstring: Mitsuba would map the textures upside down).
    **view
        Camera and film settings of :func:`scene_spec`.

    Returns
    -------
    dict
        The :func:`scene_spec` (file names relative to ``out_dir``), also saved as
        ``scene.json``; ``scene.xml`` is the same scene as Mitsuba XML.

    Raises
    ------
    ValidationError
        Before anything is written: a region-sample subject, an unknown ``material``, a ``mesh_format`` other
        than obj, an unreadable probe, a subject map named like a file of the scene (:data:`SCENE_FILES`), or
        for ``material="subsurface"`` a channel with σa + σ's = 0 (:func:`check_medium`).
    SchemaError
        A subject the store would refuse (:func:`facestats.io.exr_set.check_export_subject`, through
        :func:`~facestats.io.exr_set.write_exr_set`, before anything is written).
    """

    # local import: keeps facestats.acquire (5 modules) out of this module's import
    from facestats.io.exr_set import FaceFill, check_map_subject, write_exr_set

    check_map_subject(ds, "a Mitsuba scene")  # the schema: write_exr_set's check, the first thing it does
    check_choice(material, "material", MATERIALS)
    taken = sorted(set(ds.data_vars) & set(SCENE_FILES))
    if taken:
        raise ValidationError(
            f"subject {ds.attrs.get('subject_id', '?')!r}: variable {taken[0]!r} would be exported as "
            f"{taken[0]}.exr, a file the Mitsuba scene writes itself ({SCENE_FILES[taken[0]]}); rename the variable"
        )
    if material == "subsurface":
        check_medium(ds["sigma_a"].values, ds["sigma_s_prime"].values)
    if mesh_format != "obj":
        raise ValidationError(
            "mesh_format must be 'obj' for a Mitsuba scene (Mitsuba reads a PLY's texture coordinates v up, "
            f"so the maps would lie upside down), got {mesh_format!r}"
        )
    plastic = plastic_reflectance_scale(view.get("eta", ETA_SKIN))  # η checked before anything is written
    out = os.fspath(out_dir)
    if probe is not None:
        read_light_probe(probe)  # checked before anything is written
    if material == "subsurface":  # the medium needs a closed surface around it (module docstring)
        from facestats.io.mesh import FaceMesh, subject_mesh

        mesh = mesh if isinstance(mesh, FaceMesh) else subject_mesh(ds, mesh)
        openings = len(mesh.boundary_edges())
        if openings:
            warnings.warn(
                f"the mesh {mesh.geometry.get('name', '')!r} is open ({openings} boundary edges, around its holes and "
                "rim): the subsurface medium inside it is unbounded behind the face and through its openings, so "
                "renders within about 2 cm of them are not those of a closed head (docs/export.md); pass a closed mesh "
                "with the maps' UVs (--mesh) for a bounded interior",
                FacestatsWarning,
                stacklevel=2,
            )
    fill = FaceFill(ds["region"].values)
    manifest = write_exr_set(ds, out, mesh=mesh, fill=fill)
    alb = fill(np.asarray(ds["albedo"].values, np.float32))
    rho = fill(np.asarray(ds["ts_rho_s"].values, np.float32))
    w = blend_weight(alb)
    scale = np.float32(plastic / (1 - w))
    write_exr(os.path.join(out, "mitsuba_diffuse.exr"), {c: alb[..., i] * scale for i, c in enumerate("RGB")})
    write_exr(os.path.join(out, "mitsuba_specular.exr"), {"Y": 4 * rho / w})
    if probe is None:
        probe_name = write_studio_probe(os.path.join(out, "probe.exr"))
    else:
        probe_name = os.path.join(out, "probe" + os.path.splitext(os.fspath(probe))[1].lower())
        shutil.copyfile(probe, probe_name)
    files = {
        "mesh": manifest["mesh"]["file"],
        "probe": os.path.basename(probe_name),
        "ts_m": "ts_m.exr",
        "mitsuba_diffuse": "mitsuba_diffuse.exr",
        "mitsuba_specular": "mitsuba_specular.exr",
    }
    spec = scene_spec(files, manifest["coefficients"], material=material, weight=w, **view)
    with open(os.path.join(out, "scene.xml"), "w", encoding="utf-8") as fh:
        fh.write(spec_to_xml(spec))
    with open(os.path.join(out, "scene.json"), "w", encoding="utf-8") as fh:
        json.dump(spec, fh, indent=2, allow_nan=False)
    return spec


def render_scene(scene, *, base_dir=None, spp=None, seed=0) -> np.ndarray:
    """Render a scene with Mitsuba 3 (``scalar_rgb``): a :func:`scene_spec` dict or a ``scene.xml`` path.

    Parameters
    ----------
    scene : dict or str or path-like
        A :func:`scene_spec` dict, or the path of an existing ``scene.xml``.
    base_dir : str or path-like, optional
        For a dict: the folder its file names are relative to (:func:`spec_to_dict`).
    spp : int, optional
        Samples per pixel in [1, 65536], instead of the scene's own.
    seed : int
        Seed of the sampler.

    Returns
    -------
    ndarray of float32, shape (height, width, 3)
        Linear RGB radiance, row 0 at the top.
    """
    mi = require_mitsuba()
    if isinstance(scene, dict):
        loaded = mi.load_dict(spec_to_dict(scene, base_dir))
    else:
        path = os.fspath(scene)
        if not os.path.isfile(path):
            raise ValidationError(f"scene must be a scene dict or an existing scene.xml, got {path!r}")
        loaded = mi.load_file(path)
    kw = {"seed": int(seed)}
    if spp is not None:
        kw["spp"] = check_integer(spp, "spp", 1, 1 << 16)
    return np.asarray(mi.render(loaded, **kw), np.float32)[..., :3]
