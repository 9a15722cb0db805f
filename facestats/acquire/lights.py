"""Known lights of a scene and the irradiance c_k they put into each patch (Suzuki et al. eq. 16, with shadows).

Three kinds of light, each a small dataclass with a JSON form:

* :class:`PointLight` — an isotropic point source (e.g. an LED) at ``position``
  (mm) with radiant ``intensity`` (per channel), optionally restricted by
  planar ``cuts`` through the light (a straight occluder edge between a point
  source and the object casts a shadow boundary that is exactly the plane
  through the source and the edge; two cuts make a stripe, four a rectangle, as
  a projector would) and by a ``cone`` (a spot: half-angle around an axis);
* :class:`DirectionalLight` — a distant source along ``direction`` (towards the
  light) with irradiance E⊥, optionally restricted by ``cuts``: half-spaces
  n·(x − p) ≥ 0 (a projected edge or stripe of parallel light);
* :class:`EnvironmentLight` — directions with radiance × solid angle L·δΩ (the
  quadrature of eq. 16).  A light probe must be resampled to such directions
  first (a light-probe module's job; see ``docs/translucency_from_image.md``).

:func:`patch_irradiance` evaluates c_k (shape (m, 3)) for patches with the pure
functions of :mod:`facestats.model.irradiance`; visibility combines the masks
above with self-shadowing from shadow maps of the patches' mesh
(:class:`facestats.acquire.visibility.ShadowMaps`), one map per point light and
per direction (directions are rendered from a far point, 100 scene radii
away, which makes the projection nearly parallel).

JSON: ``{"eta": 1.3, "lights": [{"type": "point", "position_mm": [x, y, z],
"intensity": v or [r, g, b], "cuts": [[nx, ny, nz], …], "cone": {"axis": […],
"half_angle_deg": a}}, {"type": "directional", "direction": […], "irradiance":
v or [r, g, b], "cuts": [{"normal": […], "point_mm": […]}]}, {"type":
"environment", "directions": [[…], …], "radiance_solid_angle": [v, …] or
[[r, g, b], …], "shadows": true}]}`` (``shadows`` optional, default true).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import numpy as np

from facestats.acquire.visibility import ShadowMaps
from facestats.core.validate import as_finite, as_scalar, check_shape, described
from facestats.errors import FormatError, ValidationError
from facestats.io.layout import read_regular_file
from facestats.model.dipole import check_dipole_eta
from facestats.model.irradiance import (
    SUZUKI_ETA,
    directional_light_irradiance,
    environment_irradiance,
    point_light_irradiance,
)
from facestats.model.sphere import latlong_light_samples, median_cut_light_samples

__all__ = [
    "PointLight",
    "DirectionalLight",
    "EnvironmentLight",
    "lights_from_dict",
    "lights_to_dict",
    "load_lights",
    "save_lights",
    "light_masks",
    "patch_irradiance",
]


def _unit(v, name):
    a = check_shape(as_finite(v, name, dtype=np.float64), name, (3,))
    n = float(np.linalg.norm(a))
    if n == 0:
        raise ValidationError(f"{name} must be a non-zero 3-vector, got {a.tolist()}")
    return a / n


def _rgb(v, name):
    a = as_finite(v, name, 0, None, dtype=np.float64)
    if a.ndim == 0:
        return np.full(3, float(a))
    return check_shape(a, name, (3,))


@dataclass
class PointLight:
    """Isotropic point light (module docstring).

    Attributes
    ----------
    position : ndarray of float64, shape (3,)
        Position, mm.
    intensity : ndarray of float64, shape (3,)
        Radiant intensity per channel, ≥ 0 (e.g. W sr⁻¹); a scalar is repeated to the three channels.
    cuts : tuple of ndarray, each shape (3,)
        Normals n of planes through the light, normalised; lit points x satisfy n·(x − position) ≥ 0.  Default none.
    cone : tuple or None
        (unit axis, half-angle in radians, in (0, π/2]): a spot lighting only points within the half-angle of the
        axis; default None (no cone).
    """

    position: np.ndarray
    intensity: np.ndarray
    cuts: tuple = ()
    cone: tuple | None = None

    def __post_init__(self):
        self.position = check_shape(as_finite(self.position, "position", dtype=np.float64), "position", (3,))
        self.intensity = _rgb(self.intensity, "intensity")
        self.cuts = tuple(_unit(n, "cuts") for n in self.cuts)
        if self.cone is not None:
            axis, half = self.cone
            half = as_scalar(half, "cone half-angle", 0, np.pi / 2, low_inclusive=False, unit="rad")
            self.cone = (_unit(axis, "cone axis"), half)

    def mask(self, points) -> np.ndarray:
        """(m,) bool: points inside every cut's half-space and the cone.

        Parameters
        ----------
        points : array_like, shape (m, 3)
            Points, mm.

        Returns
        -------
        ndarray of bool, shape (m,)
        """
        d = np.asarray(points, np.float64) - self.position
        ok = np.ones(d.shape[0], bool)
        for n in self.cuts:  # loop over the few cut planes
            ok &= d @ n >= 0
        if self.cone is not None:
            axis, half = self.cone
            ok &= (d @ axis) >= np.cos(half) * np.linalg.norm(d, axis=1)
        return ok

    def to_dict(self) -> dict:
        """The light as a JSON-ready dict (position in mm, intensity, cuts, cone)."""
        out = {"type": "point", "position_mm": self.position.tolist(), "intensity": self.intensity.tolist()}
        if self.cuts:
            out["cuts"] = [n.tolist() for n in self.cuts]
        if self.cone is not None:
            out["cone"] = {"axis": self.cone[0].tolist(), "half_angle_deg": float(np.degrees(self.cone[1]))}
        return out


@dataclass
class DirectionalLight:
    """Distant light (module docstring).

    Attributes
    ----------
    direction : ndarray of float64, shape (3,)
        Unit direction towards the light (normalised).
    irradiance : ndarray of float64, shape (3,)
        E⊥ per channel, the irradiance on a plane facing the light, ≥ 0 (e.g. W mm⁻²); a scalar is repeated to
        the three channels.
    cuts : tuple of (ndarray, ndarray)
        ((normal, point), …): half-spaces n·(x − p) ≥ 0 that are lit, n normalised and p in mm.  Default none.
    """

    direction: np.ndarray
    irradiance: np.ndarray
    cuts: tuple = ()

    def __post_init__(self):
        self.direction = _unit(self.direction, "direction")
        self.irradiance = _rgb(self.irradiance, "irradiance")
        self.cuts = tuple(
            (_unit(n, "cut normal"), check_shape(as_finite(p, "cut point", dtype=np.float64), "cut point", (3,)))
            for n, p in self.cuts
        )

    def mask(self, points) -> np.ndarray:
        """(m,) bool: points in every cut's half-space n·(x − p) ≥ 0.

        Parameters
        ----------
        points : array_like, shape (m, 3)
            Points, mm.

        Returns
        -------
        ndarray of bool, shape (m,)
        """
        x = np.asarray(points, np.float64)
        ok = np.ones(x.shape[0], bool)
        for n, p in self.cuts:  # loop over the few cut planes
            ok &= (x - p) @ n >= 0
        return ok

    def to_dict(self) -> dict:
        """The light as a JSON-ready dict (direction, irradiance, cuts)."""
        out = {"type": "directional", "direction": self.direction.tolist(), "irradiance": self.irradiance.tolist()}
        if self.cuts:
            out["cuts"] = [{"normal": n.tolist(), "point_mm": p.tolist()} for n, p in self.cuts]
        return out


@dataclass
class EnvironmentLight:
    """Environment lighting as directions (D, 3) with radiance × solid angle (D, 3) (module docstring).

    Attributes
    ----------
    directions : ndarray of float64, shape (D, 3)
        Directions towards the lights, normalised (non-zero).
    radiance_solid_angle : ndarray of float64, shape (D, 3)
        L·δΩ per direction and channel, ≥ 0 (the irradiance of each as a distant light); (D,) is repeated to the
        three channels.
    shadows : bool
        Self-shadowing by the patches' mesh for this light (:func:`light_masks`); default True.  Written by
        :meth:`to_dict` as ``"shadows"`` (a description without it: True).
    """

    directions: np.ndarray
    radiance_solid_angle: np.ndarray
    shadows: bool = field(default=True)

    def __post_init__(self):
        d = check_shape(as_finite(self.directions, "directions", dtype=np.float64), "directions", (None, 3))
        norm = np.linalg.norm(d, axis=1)
        if np.any(norm == 0):
            raise ValidationError("directions must be non-zero 3-vectors, got a zero vector")
        self.directions = d / norm[:, None]
        e = as_finite(self.radiance_solid_angle, "radiance_solid_angle", 0, None, dtype=np.float64)
        e = np.repeat(e[:, None], 3, axis=1) if e.ndim == 1 else e
        self.radiance_solid_angle = check_shape(e, "radiance_solid_angle", (d.shape[0], 3))

    @classmethod
    def from_probe(cls, probe, samples=(16, 32), *, shadows: bool = True) -> "EnvironmentLight":
        """Environment lighting from a lat-long light probe (an (H, W, 3) array or an HDR file).

        The probe follows :mod:`facestats.model.sphere`'s convention and is read with
        :func:`facestats.io.probes.read_light_probe`; it becomes ``samples`` = (rows, columns)
        directional lights of L·δΩ each (:func:`facestats.model.sphere.latlong_light_samples`), or, for an
        int N, the N lights of a median cut (:func:`facestats.model.sphere.median_cut_light_samples`).

        Parameters
        ----------
        probe : ndarray or str or path-like
            An (H, W, 3) lat-long array of linear radiance (W = 2H), or a probe file (anything not an ndarray is
            read as one).
        samples : tuple of int or int
            (rows, columns) of blocks, which must divide H and W; or an int N, the most lights of a median cut.
        shadows : bool
            As the class's ``shadows``.

        Returns
        -------
        EnvironmentLight

        Raises
        ------
        ValidationError
            ``samples`` neither an int nor a pair, or a probe or sample count the sampling refuses.
        """
        # local import: keeps facestats.io (22 modules) out of this module's import
        from facestats.io.probes import read_light_probe

        img = probe if isinstance(probe, np.ndarray) else read_light_probe(probe)
        if np.ndim(samples) == 0:
            directions, power = median_cut_light_samples(img, samples)
        elif np.ndim(samples) == 1 and len(samples) == 2:
            directions, power = latlong_light_samples(img, *samples)
        else:
            raise ValidationError(f"samples must be an int (median cut) or (rows, columns) (blocks), got {samples!r}")
        return cls(directions, power, shadows)

    def to_dict(self) -> dict:
        """The light as a JSON-ready dict (directions, radiance × solid angle, shadows)."""
        return {
            "type": "environment",
            "directions": self.directions.tolist(),
            "radiance_solid_angle": self.radiance_solid_angle.tolist(),
            "shadows": bool(self.shadows),
        }


def _light_from_dict(d: dict):
    kind = d.get("type")
    try:
        if kind == "point":
            cone = d.get("cone")
            return PointLight(
                d["position_mm"],
                d["intensity"],
                tuple(d.get("cuts", ())),
                None if cone is None else (cone["axis"], np.radians(cone["half_angle_deg"])),
            )
        if kind == "directional":
            cuts = tuple((c["normal"], c["point_mm"]) for c in d.get("cuts", ()))
            return DirectionalLight(d["direction"], d["irradiance"], cuts)
        if kind == "environment":
            shadows = d.get("shadows", True)  # absent before facestats wrote it: the class's default
            if not isinstance(shadows, bool):
                raise FormatError(f"environment light's shadows must be true or false, got {shadows!r}")
            return EnvironmentLight(d["directions"], d["radiance_solid_angle"], shadows)
    except KeyError as exc:
        raise FormatError(f"{kind} light is missing the key {exc.args[0]!r}") from None
    raise FormatError(f"light type must be one of ['directional', 'environment', 'point'], got {kind!r}")


def lights_from_dict(d: dict):
    """``(lights, eta)`` from the JSON form of the module docstring (``eta`` defaults to 1.3).

    Parameters
    ----------
    d : dict
        The parsed JSON object: ``lights`` (a non-empty list) and optionally ``eta``.

    Returns
    -------
    lights : list of PointLight, DirectionalLight or EnvironmentLight
    eta : float
        Relative index of refraction, in [1, 3].

    Raises
    ------
    FormatError
        Not an object with a non-empty list ``lights``, a light of unknown ``type`` or missing a key, or an
        environment light's ``shadows`` not a boolean.
    ValidationError
        ``eta`` outside [1, 3], or a light's values out of their domain.
    """
    if not isinstance(d, dict) or not isinstance(d.get("lights"), list) or not d["lights"]:
        raise FormatError("a light description must be an object with a non-empty list 'lights'")
    eta = float(check_dipole_eta(d.get("eta", SUZUKI_ETA)))  # the dipole's domain: the fit needs it
    return [_light_from_dict(x) for x in d["lights"]], eta


def lights_to_dict(lights, eta=SUZUKI_ETA) -> dict:
    """The lights and the relative index of refraction ``eta`` as one JSON-ready dict.

    Parameters
    ----------
    lights : iterable of PointLight, DirectionalLight or EnvironmentLight
    eta : float
        Relative index of refraction (default Suzuki et al.'s 1.3); not checked here.

    Returns
    -------
    dict
        ``{"eta": eta, "lights": [...]}``, the form :func:`lights_from_dict` reads.
    """
    return {"eta": float(eta), "lights": [light.to_dict() for light in lights]}


def load_lights(path):
    """``(lights, eta)`` from a JSON file (module docstring).

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    lights : list of PointLight, DirectionalLight or EnvironmentLight
    eta : float

    Raises
    ------
    FormatError
        The file cannot be read or is not JSON, or its content is malformed (naming the file).
    ValidationError
        A value out of its domain (:func:`lights_from_dict`), naming the file.
    """
    try:
        doc = json.loads(read_regular_file(path))
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: not JSON, or not UTF-8
        raise FormatError(f"cannot read the light description {os.fspath(path)}: {exc}") from None
    return described(lights_from_dict, doc, f"light description {os.fspath(path)}")


def save_lights(path, lights, eta=SUZUKI_ETA):
    """Write :func:`lights_to_dict` to ``path`` as JSON; return the path.

    Parameters
    ----------
    path : str or path-like
    lights, eta
        As :func:`lights_to_dict`.

    Returns
    -------
    str
        ``path`` as a string.
    """
    with open(path, "w") as f:
        json.dump(lights_to_dict(lights, eta), f, indent=1)
    return os.fspath(path)


def _far_eyes(directions, patches):
    """Viewpoints 100 scene radii away along each direction, for shadow maps of distant lights."""
    centre = 0.5 * (patches.centre.min(0) + patches.centre.max(0))
    radius = max(float(np.linalg.norm(patches.centre - centre, axis=1).max()), 1.0)
    return centre + 100 * radius * np.asarray(directions)


def light_masks(patches, lights, *, shadows=True, resolution=512) -> list:
    """Per light, the (m, K) bool visibility of the patches (K = 1, or directions for an environment).

    Combines each light's cuts and cone with self-shadowing from shadow maps of
    the patches' mesh (when ``shadows`` and the patches carry a mesh).

    Parameters
    ----------
    patches : facestats.acquire.patches.Patches
    lights : sequence of PointLight, DirectionalLight or EnvironmentLight
    shadows : bool
        Self-shadowing by the patches' mesh (an environment light also needs its own ``shadows``).
    resolution : int
        Shadow-map side in pixels.

    Returns
    -------
    list of ndarray of bool
        One (m, 1) mask per point or directional light, one (m, K) per environment light of K directions.
    """

    out = []
    use_maps = shadows and patches.has_mesh
    for light in lights:  # loop over the scene's few lights
        if isinstance(light, EnvironmentLight):
            vis = np.ones((len(patches), light.directions.shape[0]), bool)
            eyes = _far_eyes(light.directions, patches) if use_maps and light.shadows else None
        else:
            vis = light.mask(patches.centre)[:, None]
            if isinstance(light, PointLight):
                eyes = light.position[None]
            else:
                eyes = _far_eyes(light.direction[None], patches)
            eyes = eyes if use_maps else None
        if eyes is not None:
            maps = ShadowMaps(patches.mesh_vertices, patches.mesh_faces, eyes, resolution=resolution)
            vis &= maps.visible(patches.centre, patches.normal)
        out.append(vis)
    return out


def patch_irradiance(patches, lights, *, eta=SUZUKI_ETA, shadows=True, resolution=512) -> np.ndarray:
    """c_k of Suzuki eq. 16 for every patch, summed over the lights, shape (m, 3) (module docstring).

    Parameters
    ----------
    patches : facestats.acquire.patches.Patches
    lights : list of PointLight, DirectionalLight, EnvironmentLight
    eta : float
        Relative index of refraction of F_t,i (Suzuki: 1.3).
    shadows : bool
        Self-shadowing by the patches' mesh (shadow maps).
    resolution : int
        Shadow-map side in pixels.

    Returns
    -------
    ndarray, shape (m, 3)
        c_k per patch and channel.
    """
    if not lights:
        raise ValidationError("lights must hold at least one light, got none")
    masks = light_masks(patches, lights, shadows=shadows, resolution=resolution)
    c = np.zeros((len(patches), 3))
    for light, vis in zip(lights, masks):  # loop over the scene's few lights
        if isinstance(light, PointLight):
            c += point_light_irradiance(
                patches.centre, patches.normal, light.position[None], light.intensity[None], visible=vis, eta=eta
            )
        elif isinstance(light, DirectionalLight):
            c += directional_light_irradiance(
                patches.normal, light.direction[None], light.irradiance[None], visible=vis, eta=eta
            )
        elif isinstance(light, EnvironmentLight):
            c += environment_irradiance(
                patches.normal, light.directions, light.radiance_solid_angle, visible=vis, eta=eta
            )
        else:
            raise ValidationError(f"lights must hold PointLight, DirectionalLight or EnvironmentLight, got {light!r}")
    return c
