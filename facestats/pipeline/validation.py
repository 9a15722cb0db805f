"""Validation renders of a fitted subject (Weyrich et al. 2006 §5.3 Fig. 7 and §6 Fig. 13): model beside capture.

:func:`render_led` renders the fitted skin model for one dome camera under one
LED with the capture's calibration and compares it with the capture's
radiance (the photograph, or the simulation for synthetic subjects):
rendered image, reference image, error image and RMSE.  :func:`render_probe`
renders the same camera under a latitude-longitude light probe
(:mod:`facestats.model.sphere`), with mesh shadows
(:class:`facestats.acquire.visibility.ShadowMaps`); there is no reference then.
:func:`camera_rmse` is the held-out-camera figure over every LED.

Model (eq. 6 with eq. 5's 1/π, :func:`facestats.model.skin.skin_radiance`):

* specular: the fitted Torrance-Sparrow (or Blinn-Phong) lobe, evaluated with
  the diffuse normal map, the normal the lobe was fitted with (eq. 14); with
  ``micro_normals=True``, with the camera's **micro-normal** map instead (§5.1,
  Fig. 6c: "one diffuse and per-view micro-normal maps").  That is not the
  default: the stored micro-normals are the paper's estimate, the half vector of
  each view's largest sample, so they lie on the grid of half vectors the dome's
  150 LEDs make, and on a simulated subject, whose skin has no micro-geometry,
  they only add that error.  For S001 of ``facestats build --size 24`` the
  fitted normals are a median 0.14° from the simulated ones and the
  micro-normals 9.2° (90th percentile 18°), and camera 5 under LED 20 renders
  with a relative RMSE of 75.2 % with them against 2.8 % without
  (``docs/export.md``, *Validation render*);
* diffuse: modulation M = α/α_avg (eq. 7) times the **spatial** dipole
  transport ∫ R_d(‖xo − xi‖) F_t(ωi) E(xi) dA(xi) over the lumitexels
  (:class:`facestats.model.skin.SubsurfaceTransport` in surface mode, σ's and
  σa of the subject, §5.4), with the diffuse normal.

Images interpolate the lumitexels' values between their projections in the camera's image
(:func:`facestats.pipeline.render.camera_image`); error = rendered − reference; relative RMSE = RMSE /
RMS(reference) over the samples valid in both (the lumitexels, not the image's pixels), all channels.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from facestats.acquire.capture import Lumitexels
from facestats.acquire.dome import default_dome
from facestats.acquire.synthetic.population import default_population, synthesize_population
from facestats.acquire.synthetic.simulate import DomeSimulator, simulate_capture
from facestats.acquire.visibility import DISTANT_LIGHT_MM, ShadowMaps
from facestats.core.conventions import DEFAULT_SEED
from facestats.core.published import ETA_SKIN
from facestats.core.validate import check_choice, check_integer
from facestats.errors import ValidationError
from facestats.face.geometry import uv_to_texel
from facestats.face.named import named_face, parse_face_name
from facestats.io.mesh import check_face_extent, load_face_mesh, recorded_geometry, subject_mesh
from facestats.io.probes import read_light_probe
from facestats.io.schema import modulation, provenance
from facestats.model.skin import SPECULAR_MODELS, SubsurfaceTransport, skin_radiance
from facestats.model.sphere import latlong_light_samples, median_cut_light_samples
from facestats.pipeline.render import camera_image
from facestats.pipeline.settings import MAP_VARS, MODEL_PREFIX

__all__ = [
    "Render",
    "render_led",
    "probe_radiance",
    "render_probe",
    "camera_rmse",
    "check_micro_normals",
    "check_led_view",
    "led_view_counts",
    "MIN_LED_SAMPLES",
    "default_capture",
    "face_view",
    "FaceView",
]


@dataclass
class Render:
    """A validation render: images (H, W, 3) in the capture's radiance units, NaN where nothing projects.

    Attributes
    ----------
    rendered : ndarray, shape (H, W, 3)
        The fitted model's image.
    reference : ndarray, shape (H, W, 3), or None
        The capture's radiance (:func:`render_led`); None under a probe (:func:`render_probe`).
    camera : int
        The dome camera.
    light : str
        ``"LED k"`` or ``"probe"``.
    rmse : float or None
        Root mean square of rendered − captured radiance over the samples valid in both; None under a probe.
    relative_rmse : float or None
        ``rmse`` over the root mean square of the captured radiance; None under a probe.
    """

    rendered: np.ndarray
    reference: np.ndarray | None
    camera: int
    light: str
    rmse: float | None = None
    relative_rmse: float | None = None

    @property
    def error(self) -> np.ndarray | None:
        """rendered − reference (None under a probe)."""
        return None if self.reference is None else self.rendered - self.reference

    def figure(self):
        """Rendered, reference and error side by side (matplotlib figure)."""
        import matplotlib.pyplot as plt

        panels = [("rendered", self.rendered)]
        if self.reference is not None:
            panels += [("capture", self.reference), ("error (rendered − capture)", self.error)]
        fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels), 3.4), squeeze=False)
        white = np.nanpercentile(np.concatenate([p[np.isfinite(p)] for _, p in panels[:2]]), 99.5) or 1.0
        for ax, (title, img) in zip(axes[0], panels):
            if title.startswith("error"):
                lim = np.nanmax(np.abs(img)) or 1.0
                ax.imshow(np.nan_to_num(img.mean(-1)) / lim, cmap="RdBu_r", vmin=-1, vmax=1)
            else:
                ax.imshow(np.clip(np.nan_to_num(img) / white, 0, 1) ** (1 / 2.2))
            ax.set_title(title, fontsize=9)
            ax.axis("off")
        if self.relative_rmse is not None:
            fig.suptitle(f"camera {self.camera}, {self.light}: relative RMSE {100 * self.relative_rmse:.2f} %")
        fig.tight_layout()
        return fig


#: Largest share of a capture's lumitexels that may fall outside the subject's face (map texels of region 0).
OFF_FACE_SHARE = 0.01


def _texels(subject, capture):
    """The capture's lumitexels and their texels (v, u) in the subject's maps; a capture whose lumitexels fall
    outside the subject's face (another face or UV layout) is refused."""
    lt = capture.lumitexels()
    tex = uv_to_texel(lt.uv, int(subject.sizes["u"]))
    off = float(np.mean(np.asarray(subject["region"].values)[tex[:, 0], tex[:, 1]] == 0)) if lt.n else 0.0
    if off > OFF_FACE_SHARE:
        raise ValidationError(
            f"the capture (of subject {capture.attrs.get('subject_id', '?')!r}) does not fit subject "
            f"{subject.attrs.get('subject_id', '?')!r}: {100 * off:.1f} % of its lumitexels fall outside the subject's "
            "face in its maps (a capture of another face or UV layout); pass the subject's own capture"
        )
    return lt, tex[:, 0], tex[:, 1]


def _unit(v):
    v = np.asarray(v, np.float64)
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _radiance(subject, capture, camera, wi, irr, *, specular, eta, micro_normals):
    """Model radiance (N, L, 3) of every lumitexel seen by ``camera`` for lights (wi, irr of shape (N, L, 3))."""

    lt, v, u = _texels(subject, capture)
    normal = _unit(np.asarray(subject["normal"].values)[v, u])
    if micro_normals:  # per-view micro-normals for the specular term (§5.1, Fig. 6c)
        spec_normal = _unit(np.asarray(subject["micro_normal"].values)[camera, v, u])
        bad = ~np.all(np.isfinite(spec_normal), axis=1) | (np.linalg.norm(spec_normal, axis=1) < 0.5)
        spec_normal[bad] = normal[bad]
    else:
        spec_normal = normal
    rho_var, lobe_var, _ = MAP_VARS[MODEL_PREFIX[specular]]
    transport = SubsurfaceTransport(
        subject["sigma_s_prime"].values, subject["sigma_a"].values, eta,
        positions=lt.position.astype(np.float64), areas=lt.area.astype(np.float64),
    )  # fmt: skip
    wo = lt.wo[:, camera : camera + 1].astype(np.float64)
    common = dict(
        rho_s=np.asarray(subject[rho_var].values)[v, u], roughness=np.asarray(subject[lobe_var].values)[v, u],
        modulation=np.asarray(modulation(subject).values)[v, u], subsurface=transport, specular=specular, eta=eta,
        components=True,
    )  # fmt: skip
    spec, _ = skin_radiance(spec_normal, wi, irr, wo, **common)
    _, diff = skin_radiance(normal, wi, irr, wo, **common)
    return (spec + diff)[:, 0], normal


def _led_samples(subject, capture, camera, light, specular, eta, micro_normals):
    """Predicted and captured radiance (N, 3) of every lumitexel for one camera and LED (NaN where invalid)."""
    lt = capture.lumitexels()
    wi = lt.wi[:, light : light + 1].astype(np.float64)
    normal = _unit(np.asarray(subject["normal"].values)[_texels(subject, capture)[1:]])
    cos = np.clip(np.einsum("nk,nlk->nl", normal, wi), 0, None)
    # Light reaches a lumitexel only where the capture has it lit and unshadowed (valid in some camera).
    lit = np.any(lt.valid[:, :, light], axis=1)
    irr = lt.irradiance[:, light : light + 1].astype(np.float64) * (cos * lit[:, None])[..., None]
    pred, _ = _radiance(subject, capture, camera, wi, irr, specular=specular, eta=eta, micro_normals=micro_normals)
    valid = lt.valid[:, camera, light]
    pred = np.where(valid[:, None], pred[:, 0], np.nan)
    meas = np.where(valid[:, None], lt.radiance[:, camera, light].astype(np.float64), np.nan)
    return pred, meas


def render_led(
    subject,
    capture,
    camera: int,
    light: int,
    *,
    specular="torrance_sparrow",
    eta=ETA_SKIN,
    micro_normals=False,
    size=None,
    names=("camera", "light"),
) -> Render:
    """The fitted model for ``camera`` under LED ``light``, beside the capture's radiance (module docstring).

    Parameters
    ----------
    subject : xarray.Dataset
        A fitted map subject (``normal`` required; ``micro_normal`` with ``micro_normals``).
    capture : Capture
        The capture (or a re-simulation) of that subject.
    camera, light : int
        Dome camera and LED.
    specular : {"torrance_sparrow", "blinn_phong"}
    eta : float
    micro_normals : bool
        Evaluate the specular lobe with the camera's micro-normals (Fig. 6c) instead of the diffuse normal
        (module docstring: why that is not the default).
    size : int, optional
        Image side in pixels (:func:`facestats.pipeline.render.camera_image`).
    names : (str, str)
        What :func:`check_led_view`'s message and warning call the camera and the LED (the command line's
        ``("--camera", "--light")``).

    Returns
    -------
    Render

    Raises
    ------
    ValidationError
        Bad arguments, or a camera and LED that see fewer than :data:`MIN_LED_SAMPLES` lumitexels lit
        (:func:`check_led_view`).
    """

    _check(subject, capture, camera, light, specular, micro_normals)
    if size is not None:  # before the render
        check_integer(size, "size", 16, 2048)
    check_led_view(capture, camera, light, names=names)
    pred, meas = _led_samples(subject, capture, camera, light, specular, eta, micro_normals)
    ok = np.isfinite(pred).all(1) & np.isfinite(meas).all(1)
    rmse = float(np.sqrt(np.mean((pred[ok] - meas[ok]) ** 2)))
    rel = rmse / float(np.sqrt(np.mean(meas[ok] ** 2)))
    rendered = camera_image(pred, capture, camera, light, size=size)
    reference = camera_image(meas, capture, camera, light, size=size)
    return Render(rendered, reference, camera, f"LED {light}", rmse, rel)


#: Fewest lumitexels seen and lit that :func:`render_led` compares: the relative RMSE of n samples has a sampling
#: error of about 1/√(2n) of itself (the standard error of a root mean square of n independent normal residuals),
#: 10 % at 50.
MIN_LED_SAMPLES = 50


def led_view_counts(capture) -> np.ndarray:
    """Lumitexels each (camera, LED) pair sees lit: valid samples of the capture (seen, lit, unshadowed, unclipped).

    Parameters
    ----------
    capture : Capture
        A capture (or a re-simulation) with its samples.

    Returns
    -------
    ndarray of int64, shape (C, L)
        The count per camera and LED.
    """
    return capture.lumitexels().valid.sum(0).astype(np.int64)


def check_led_view(capture, camera: int, light: int, *, names=("camera", "light")) -> int:
    """Refuse a (camera, LED) pair that sees too few lumitexels lit for a relative RMSE, suggesting the pair that
    sees the most (:func:`led_view_counts`; the lowest camera, then LED, of equals).

    The pair must see at least :data:`MIN_LED_SAMPLES` lumitexels lit, or, in a capture where no pair sees that
    many (a build at 8² or 12²), half as many as the pair that sees the most; below :data:`MIN_LED_SAMPLES` a
    :class:`~facestats.errors.FacestatsWarning` gives the figure's sampling error, 1/√(2n).

    Parameters
    ----------
    capture : Capture
    camera, light : int
        Dome camera and LED (checked against the dome).
    names : (str, str)
        What the message calls the camera and the LED (the command line's ``("--camera", "--light")``).

    Returns
    -------
    int
        The lumitexels the pair sees lit.

    Raises
    ------
    ValidationError
        Too few lumitexels, the message naming both values, the count, the least count and the pair suggested.
    """
    import warnings

    from facestats.errors import FacestatsWarning

    check_integer(camera, names[0], 0, capture.dome.n_cameras - 1)
    check_integer(light, names[1], 0, capture.dome.n_leds - 1)
    counts = led_view_counts(capture)
    n = int(counts[camera, light])
    best_camera, best_light = np.unravel_index(int(np.argmax(counts)), counts.shape)
    best = int(counts[best_camera, best_light])
    least = max(1, min(MIN_LED_SAMPLES, -(-best // 2)))
    if n < least:
        raise ValidationError(
            f"{names[0]} {camera} with {names[1]} {light} sees {n} of the {capture.n_lumitexels} lumitexels lit, "
            f"fewer than the {least} a relative RMSE needs (its sampling error is about 1/sqrt(2n) of itself: 10 % "
            f"at {MIN_LED_SAMPLES}); {names[0]} {best_camera} with {names[1]} {best_light} sees the most, {best}"
        )
    if n < MIN_LED_SAMPLES:
        warnings.warn(
            f"{names[0]} {camera} with {names[1]} {light} sees {n} lumitexels lit (this capture has "
            f"{capture.n_lumitexels}): the relative RMSE's sampling error is about {100 / np.sqrt(2 * n):.0f} % of it",
            FacestatsWarning,
            stacklevel=2,
        )
    return n


def _check(subject, capture, camera, light, specular, micro_normals):
    check_choice(specular, "specular", SPECULAR_MODELS)
    check_micro_normals(subject, micro_normals)
    check_integer(camera, "camera", 0, capture.dome.n_cameras - 1)
    if light is not None:
        check_integer(light, "light", 0, capture.dome.n_leds - 1)
    if "normal" not in subject.data_vars:
        raise ValidationError("subject must hold the fitted 'normal' map (a Dataset from fit_subject)")


def check_micro_normals(subject, micro_normals):
    """``micro_normals`` of the renders checked: a bool, True only for a subject that stores ``micro_normal``.

    Parameters
    ----------
    subject : xarray.Dataset
        The subject to render.
    micro_normals : bool
        Whether the render evaluates the specular lobe with the per-view micro-normals (:func:`render_led`).

    Raises
    ------
    ValidationError
        Not a bool, or True for a subject without micro-normal maps.
    """
    if not isinstance(micro_normals, (bool, np.bool_)):
        raise ValidationError(f"micro_normals must be True or False, got {micro_normals!r}")
    if micro_normals and "micro_normal" not in subject.data_vars:
        raise ValidationError(
            f"micro_normals=True needs the subject's micro-normal maps, and subject "
            f"{subject.attrs.get('subject_id', '?')!r} has none (the embedded default and builds with "
            "--no-micro-normals store none)"
        )


class FaceView:
    """What :func:`render_probe` reads of a capture, from the face geometry alone: its lumitexels and the dome.

    The lumitexels are the geometry's (as a simulated capture stores them: float32 positions, UVs and areas),
    seen by ``dome`` (default :func:`facestats.acquire.dome.default_dome`, the simulator's); they hold no
    samples (``irradiance`` and ``radiance`` have no light or camera), so only a render without a reference can
    use them.  Made by :func:`face_view`.

    Parameters
    ----------
    geometry : facestats.face.geometry.FaceGeometry
        The face: its lumitexels' positions, normals, UVs, areas and regions, and its ``name``.
    subject_id : str
        The subject's id, kept with the geometry's name in :attr:`attrs`.
    dome : facestats.acquire.dome.Dome, optional
        The dome the lumitexels are seen by (default :func:`facestats.acquire.dome.default_dome`).
    """

    def __init__(self, geometry, subject_id: str, dome=None):
        self.dome = default_dome() if dome is None else dome
        self.attrs = {"subject_id": str(subject_id), "geometry": str(geometry.name)}
        self._position = np.asarray(geometry.position, np.float32)
        self._geometry = geometry
        self._lumitexels = None

    def array(self, name, sl=slice(None)) -> np.ndarray:
        """``position``, ``scan_normal`` (N, 3) or ``uv`` (N, 2), float32, as
        :meth:`facestats.acquire.capture.Capture.array`.

        Parameters
        ----------
        name : {"position", "scan_normal", "uv"}
            The array: positions (mm), the geometry's unit normals, or texture coordinates (u right, v down).
        sl : slice
            The lumitexels to read (default all).

        Returns
        -------
        ndarray of float32, shape (N, 3) or (N, 2)

        Raises
        ------
        ValidationError
            ``name`` is none of them.
        """
        arrays = {"position": self._position, "scan_normal": self._geometry.normal, "uv": self._geometry.uv}
        if name not in arrays:
            raise ValidationError(f"a face view holds the lumitexels' position, scan_normal and uv only, not {name!r}")
        return np.asarray(arrays[name], np.float32)[sl]

    def lumitexels(self) -> Lumitexels:
        """Every lumitexel with its directions to the dome's LEDs and cameras (computed once)."""
        if self._lumitexels is None:
            g, n = self._geometry, len(self._position)
            pos = self._position.astype(np.float64)
            wi, wo = self.dome.directions32(pos)
            self._lumitexels = Lumitexels(
                index=np.arange(n), position=pos, scan_normal=np.asarray(g.normal, np.float64),
                uv=np.asarray(g.uv, np.float32).astype(np.float64),
                area=np.asarray(g.area, np.float32).astype(np.float64), region=np.asarray(g.region), wi=wi, wo=wo,
                irradiance=np.zeros((n, 0, 3), np.float32), radiance=np.zeros((n, 0, 0, 3), np.float16),
            )  # fmt: skip
        return self._lumitexels


def face_view(subject, mesh=None, *, scale: float = 1.0) -> FaceView:
    """The lumitexels of a subject's face seen by the default dome: the stand-in for a capture in :func:`render_probe`.

    The face is the one the subject's provenance records (:func:`facestats.io.mesh.recorded_geometry`; an
    edit's: its source's), or ``mesh``: the scan its maps belong to (an OBJ/PLY with per-vertex UVs, mm times
    ``scale``, in the dome's frame), for a subject fitted on a scan (ingested photographs), whose lumitexels are
    the scan's vertices labelled by the subject's ``region`` map (:func:`facestats.io.mesh.load_face_mesh`).

    Parameters
    ----------
    subject : xarray.Dataset
        A stored subject (its ``subject_id`` attribute, provenance and, with ``mesh``, its ``region`` map).
    mesh : str or os.PathLike, optional
        The scan the subject's maps belong to; default the face its provenance records.
    scale : float
        Factor from the mesh file's units to mm (default 1: the file is in mm); used with ``mesh`` only.

    Returns
    -------
    FaceView
        The face's lumitexels seen by :func:`facestats.acquire.dome.default_dome` (no samples).

    Raises
    ------
    ValidationError
        A face facestats cannot rebuild and no ``mesh`` (a subject fitted on a scan: pass the scan, or its capture
        to :func:`render_probe`); a ``mesh`` that after ``scale`` is not a face's size in mm
        (:func:`facestats.io.mesh.check_face_extent`).
    """
    sid = str(subject.attrs.get("subject_id", "?"))
    if mesh is not None:
        geometry = load_face_mesh(mesh, np.asarray(subject["region"].values), scale=scale)
        check_face_extent(geometry.mesh_vertices, mesh, scale)  # a scan in m read as mm: the dome would miss it
        return FaceView(geometry, sid)
    name = recorded_geometry(subject)
    try:
        geometry = named_face(str(name))
    except ValidationError:
        raise ValidationError(
            f"subject {sid!r} records geometry {name!r}, not a face facestats can rebuild: pass the scan its maps "
            "belong to (mesh=PATH; --mesh PATH on the command line) or the capture it was fitted to (--capture PATH)"
        ) from None
    return FaceView(geometry, sid)


#: Most directional lights :func:`render_probe` sums a probe into (a shadow map each: 2,048 take minutes at 48²).
MAX_PROBE_LIGHTS = 2048


#: Lights a probe is cut into by default (:func:`facestats.model.sphere.median_cut_light_samples`).
DEFAULT_PROBE_LIGHTS = 512


def probe_lights(shape, samples=None, name="samples"):
    """The directional lights a lat-long probe of ``shape`` is summed into (:func:`render_probe`), checked.

    ``samples`` None: :data:`DEFAULT_PROBE_LIGHTS` lights by median cut.  An int N: N lights by median cut
    (2 ≤ N ≤ :data:`MAX_PROBE_LIGHTS`).  (rows, columns): equal blocks (each ≥ 2, dividing the probe's rows and
    columns, at most :data:`MAX_PROBE_LIGHTS` lights).  Errors name ``name``.

    Returns
    -------
    int or (int, int)
        The median cut's number of lights, or the blocks.
    """
    ph, pw = int(shape[0]), int(shape[1])
    if samples is None:
        return DEFAULT_PROBE_LIGHTS
    if np.ndim(samples) == 0:
        return check_integer(samples, name, 2, MAX_PROBE_LIGHTS)
    if np.ndim(samples) != 1 or len(samples) != 2:
        raise ValidationError(f"{name} must be an int (median cut) or (rows, columns) (blocks), got {samples!r}")
    r, c = (check_integer(v, name, 2) for v in samples)
    if r * c > MAX_PROBE_LIGHTS:
        raise ValidationError(f"{name} must make at most {MAX_PROBE_LIGHTS} lights, got {r} x {c} = {r * c}")
    if ph % r or pw % c:
        raise ValidationError(f"{name} {r} x {c} must divide the probe's size {ph} x {pw} (rows x columns)")
    return r, c


def probe_radiance(
    subject,
    capture,
    camera: int,
    probe,
    *,
    samples=None,
    specular="torrance_sparrow",
    eta=ETA_SKIN,
    mesh=None,
    scale: float = 1.0,
    micro_normals=False,
    hidden=False,
):
    """Radiance of the fitted model at each lumitexel seen by ``camera`` under a lat-long light probe.

    The probe is summed into directional lights (:func:`probe_lights`): by default 512 regions of a median cut
    (:func:`facestats.model.sphere.median_cut_light_samples`), or ``samples`` = (rows, columns) equal blocks
    (:func:`facestats.model.sphere.latlong_light_samples`); each light has irradiance E = (Σ L Δω) (N·ω) from
    its region's power-weighted mean direction, occluded where the subject's face mesh
    (:func:`facestats.io.mesh.subject_mesh`: the face its provenance records, or ``mesh``) shadows it, seen
    from :data:`facestats.acquire.visibility.DISTANT_LIGHT_MM` away (a distant light, as the relighting's
    stage sees it; until 2026-12-07 from 2 m, whose diverging rays shadowed more of the face under light from
    high above).  The radiance is Weyrich et al. 2006 eq. 6 through :func:`facestats.model.skin.skin_radiance`
    (the fitted specular lobe, and the diffuse term carried between lumitexels by the dipole, as the fit
    models the capture).  Lumitexels the camera does not see (facing away from it, or hidden behind the face
    by the mesh, by a shadow map from the camera) are NaN: until 2026-12-07 they were rendered as if seen and
    drawn into the image over the surface in front of them (17 % of the default S001's lumitexels in
    camera 5's frame, at radiance 0 when facing away).

    Nothing is compared with a capture, so none is needed: ``capture`` None takes the lumitexels of the
    subject's face seen by the default dome (:func:`face_view`; for a simulated subject the same lumitexels and
    dome as its capture's; for a subject fitted on a scan, the vertices of ``mesh``, which must then be in the
    default dome's frame: pass the capture otherwise).

    Parameters
    ----------
    subject : xarray.Dataset
        A fitted map subject (``normal`` required; ``micro_normal`` with ``micro_normals``).
    capture : Capture, FaceView or None
        The subject's capture (its lumitexels and dome calibration), or None (:func:`face_view`).
    camera : int
        Dome camera.
    probe : str, os.PathLike or ndarray (H, W, 3)
        Lat-long probe (a file is read with :func:`facestats.io.probes.read_light_probe`), radiance per sr.
    samples : int or (int, int), optional
        The lights: N regions of a median cut, or (rows, columns) equal blocks, each dividing the probe's size;
        at most :data:`MAX_PROBE_LIGHTS` in all (each light costs a shadow map).  Default: a median cut into
        512 (before 2026-12-06 equal blocks, 16 × 32 where they divided the probe).  The Lambertian irradiance
        of 2,000 random normals against the full probe's (``benchmarks/bench_relight.py``
        ``bench_probe_lights``), at the 99th percentile / worst: median cut 512 0.5-4.5 % / 0.9-6.0 % under the
        Probulator (pisa, ennis, wells), park, lobby and studio probes; 16 × 32 blocks 0.8-13.6 % /
        1.6-25.7 % (the studio's small softbox the worst).  The cost grows with the lights: at 48² about 4 s
        for 512.
    specular : {"torrance_sparrow", "blinn_phong"}
        The subject's fitted model to render.
    eta : float
        Relative index of refraction of the Fresnel terms.
    mesh : str or os.PathLike, optional
        The scan the subject's maps belong to (OBJ/PLY with per-vertex UVs), for a subject whose recorded face
        facestats cannot rebuild (ingested photographs): the shadowing mesh, and without ``capture`` the
        lumitexels (:func:`face_view`).
    scale : float
        Factor from ``mesh``'s unit to mm.
    micro_normals : bool
        As :func:`render_led`.
    hidden : bool
        Also the radiance of the lumitexels that face the camera but are hidden by the face (a cheek behind the
        nose), for an image: :func:`facestats.pipeline.render.camera_image`'s depth buffer hides them, and their
        values fill the visible surface beside them; NaN only where the lumitexel faces away or is out of frame.
        :func:`render_probe` passes True; default False.

    Returns
    -------
    values : ndarray of float64, shape (N, 3)
        Radiance per lumitexel of ``capture`` (``capture.array("position")``'s order), in the probe's unit; NaN
        where ``camera`` does not see the lumitexel (with ``hidden``: where it faces away).
    capture : Capture or FaceView
        The lumitexels' source (``capture``, or the :func:`face_view` made for None).

    Raises
    ------
    ValidationError
        ``camera`` sees none of the lumitexels (e.g. a scan outside the default dome's frame without its capture,
        or a normal map that faces away from the camera).
    """

    check_micro_normals(subject, micro_normals)
    if capture is None:
        capture = face_view(subject, mesh, scale=scale)
    check_integer(camera, "camera", 0, capture.dome.n_cameras - 1)
    img = read_light_probe(probe) if not isinstance(probe, np.ndarray) else np.asarray(probe, np.float64)
    lights = probe_lights(img.shape, samples)
    if np.ndim(lights) == 0:
        d, power = median_cut_light_samples(img, lights)
    else:
        d, power = latlong_light_samples(img, *lights)
    lt, v, u = _texels(subject, capture)
    position = lt.position.astype(np.float64)
    _, in_frame, _ = capture.dome.view(position, cameras=[camera])
    if not in_frame.any():  # before the shadow maps: a scan in another frame must not cost them
        raise ValidationError(
            f"camera {camera} sees none of the {lt.n} lumitexels of subject {subject.attrs.get('subject_id', '?')!r} "
            "(a scan outside the dome's frame, or a camera facing away): pass the capture it was fitted to"
        )
    normal = _unit(np.asarray(subject["normal"].values)[v, u])
    mesh = subject_mesh(subject, mesh, scale=scale, mesh_grid=64)
    centre = mesh.vertices.mean(0)
    vis = ShadowMaps(mesh.vertices, mesh.faces, centre + DISTANT_LIGHT_MM * d, target=centre, resolution=128).visible(
        position, normal
    )
    eye = np.asarray(capture.dome.camera_position, np.float64)[camera : camera + 1]
    seen = ShadowMaps(mesh.vertices, mesh.faces, eye, target=centre, resolution=512).visible(position, normal)[:, 0]
    cos = np.clip(normal @ d.T, 0, None) * vis
    irr = cos[..., None] * power[None]
    wi = np.broadcast_to(d, (len(normal),) + d.shape)
    seen &= in_frame[:, 0]
    if not seen.any():  # as render_led: an image with nothing on it is an error, not a black file
        raise ValidationError(
            f"camera {camera} sees none of the {lt.n} lumitexels of subject {subject.attrs.get('subject_id', '?')!r}: "
            "those in its frame face away from it or are hidden by the face (check the subject's normal map)"
        )
    pred, _ = _radiance(subject, capture, camera, wi, irr, specular=specular, eta=eta, micro_normals=micro_normals)
    if hidden:  # every lumitexel facing the camera in its frame: the image's depth buffer hides those behind
        seen = in_frame[:, 0] & (np.einsum("nk,nk->n", normal, lt.wo[:, camera]) > 0)
    return np.where(seen[:, None], pred.sum(axis=1), np.nan), capture


def render_probe(
    subject,
    capture,
    camera: int,
    probe,
    *,
    samples=None,
    specular="torrance_sparrow",
    eta=ETA_SKIN,
    mesh=None,
    scale: float = 1.0,
    micro_normals=False,
    size=None,
):
    """The fitted model for ``camera`` under a lat-long light probe, shadowed by the face mesh: the image of
    :func:`probe_radiance`'s values for every lumitexel facing the camera (``hidden=True``), which the image's
    depth buffer hides behind the face (:func:`facestats.pipeline.render.camera_image`).

    Parameters
    ----------
    subject, capture, camera, probe, samples, specular, eta, mesh, scale, micro_normals
        As :func:`probe_radiance`.
    size : int, optional
        Image side in pixels (:func:`facestats.pipeline.render.camera_image`).

    Returns
    -------
    Render
        Without a reference.

    Raises
    ------
    ValidationError
        As :func:`probe_radiance`.
    """
    if size is not None:  # before the shadow maps
        check_integer(size, "size", 16, 2048)
    values, capture = probe_radiance(
        subject, capture, camera, probe, samples=samples, specular=specular, eta=eta, mesh=mesh, scale=scale,
        micro_normals=micro_normals, hidden=True,
    )  # fmt: skip
    return Render(camera_image(values, capture, camera, 0, size=size), None, camera, "probe")


def camera_rmse(
    subject,
    capture,
    camera: int,
    *,
    specular="torrance_sparrow",
    lights=None,
    eta=ETA_SKIN,
    max_angle_deg=80.0,
    micro_normals=False,
) -> float:
    """Relative RMSE of the model for one camera over every LED (or ``lights``), pooled over the valid samples.

    Samples count where θi and θo about the fitted normal are within
    ``max_angle_deg`` (the domain eq. 14 fits, as
    :func:`facestats.pipeline.render.held_out_camera_error`).

    Parameters
    ----------
    subject : xarray.Dataset
        A fitted map subject.
    capture : Capture
        The capture it was fitted from (or a re-simulation of it).
    camera : int
        Camera index.
    specular : {"torrance_sparrow", "blinn_phong"}
        Specular model of the prediction.
    lights : iterable of int, optional
        LED indices to pool (default every LED of the dome).
    eta : float
        Relative index of refraction of the subsurface term (default skin's 1.38).
    max_angle_deg : float
        Largest θi and θo counted, degrees.
    micro_normals : bool
        As :func:`render_led`.

    Returns
    -------
    float
        sqrt(Σ (predicted − measured)² / Σ measured²) over the counted samples and channels.

    Raises
    ------
    ValidationError
        Bad arguments, or no lit lumitexel within the angle.
    """
    _check(subject, capture, camera, None, specular, micro_normals)
    lt, v, u = _texels(subject, capture)
    normal = _unit(np.asarray(subject["normal"].values)[v, u])
    lim = np.cos(np.radians(float(max_angle_deg)))
    inside = (np.einsum("nk,nlk->nl", normal, lt.wi) > lim) & (np.einsum("nk,nk->n", normal, lt.wo[:, camera]) > lim)[
        :, None
    ]
    lights = range(capture.dome.n_leds) if lights is None else lights
    num = den = 0.0
    for light in lights:  # LEDs one by one: each is one product with the spatial transport
        light = int(check_integer(light, "light"))
        pred, meas = _led_samples(subject, capture, camera, light, specular, eta, micro_normals)
        ok = np.isfinite(pred).all(1) & np.isfinite(meas).all(1) & inside[:, int(light)]
        num += float(np.sum((pred[ok] - meas[ok]) ** 2))
        den += float(np.sum(meas[ok] ** 2))
    if den == 0:
        raise ValidationError(f"camera {camera} sees no lit lumitexel in this capture")
    return float(np.sqrt(num / den))


#: Capture provenance entries that set up the simulator (:class:`facestats.acquire.synthetic.simulate.DomeSimulator`).
SIMULATOR_SETTINGS = ("specular", "noise", "head_motion_deg", "scan_normal_noise_deg", "block", "eta")


def default_capture(subject, seed: int = DEFAULT_SEED):
    """Re-simulate the capture of a subject of the synthetic population (same truth, seed, face and dome).

    Parameters
    ----------
    subject : str or xarray.Dataset
        A subject id of the embedded default's population, or a fitted subject of any store
        ``facestats build`` wrote: its capture provenance (simulator settings, subject seed and face
        ``ict-N``/``procedural-N``, which sets the map size) says how it was simulated, and the
        re-simulation must reproduce it, so that a subject is never compared with a capture it was not fitted
        to.  The truth is drawn from the synthetic population of ``seed``; the subject seed it records must be
        the one that population gives that subject.
    seed : int
        Seed of the population (``facestats build --seed``, default 2006: the build's seed is not recorded in
        the store, only each subject's seed drawn from it).

    Raises
    ------
    ValidationError
        A subject whose capture cannot be re-simulated, saying what to pass instead: an edit (never captured),
        a subject fitted from photographs or another capture, another population seed.

    Returns
    -------
    facestats.acquire.capture.Capture
        The re-simulated capture.

    Notes
    -----
    The last two simulations are cached (a simulation takes seconds); treat the capture as read-only.
    """

    if isinstance(subject, str):
        _default_truth(subject)  # the message of an id outside the default
        return _simulated(subject, int(seed), None, ())
    sid = str(subject.attrs.get("subject_id", ""))
    prov = provenance(subject)
    got = prov.get("capture_provenance")
    capture = "(--capture PATH on the command line)"
    if not isinstance(got, dict) or not got:
        if isinstance(prov.get("source_provenance"), dict):
            raise ValidationError(
                f"subject {sid!r} is an edit (of {prov.get('source_subject', '?')!r}, facestats edit): it was never "
                "captured, so there is no capture to compare it with; render it under a light probe (--probe FILE), "
                "which needs none"
            )
        raise ValidationError(f"subject {sid!r} records no capture it was fitted from: pass that capture {capture}")
    if got.get("source") != "facestats simulator":
        raise ValidationError(
            f"subject {sid!r} was fitted from a capture facestats did not simulate (source {got.get('source')!r}): "
            f"pass that capture {capture}"
        )
    name = got.get("geometry")
    try:
        parse_face_name(str(name))
    except ValidationError:
        raise ValidationError(
            f"subject {sid!r} was simulated on geometry {name!r}, not a face facestats can rebuild: pass the "
            f"capture it was fitted to {capture}"
        ) from None
    truth = _population_truth(sid, int(seed), str(name))
    if truth.seed != got.get("seed"):
        raise ValidationError(
            f"subject {sid!r} was not fitted from the default simulation of that subject (its capture provenance "
            f"has {{'seed': {got.get('seed')!r}}}, the population of seed {seed} has {{'seed': {truth.seed}}}): a "
            "subject of a store built with another --seed needs that seed (--seed N; the store does not record it), "
            f"any other the capture it was fitted to {capture}"
        )
    settings = tuple((k, got[k]) for k in SIMULATOR_SETTINGS if k in got)
    cap = _simulated(sid, int(seed), str(name), settings)
    made = cap.provenance
    differ = {k: v for k, v in got.items() if k != "software" and made.get(k) != v}
    if differ:
        raise ValidationError(
            f"subject {sid!r} records a simulation this facestats does not reproduce (its capture provenance has "
            f"{differ}, the re-simulation {{{', '.join(f'{k!r}: {made.get(k)!r}' for k in differ)}}}): pass the "
            f"capture it was fitted to {capture}"
        )
    return cap


def _default_truth(subject_id):
    try:
        return default_population()[subject_id]
    except (KeyError, IndexError):
        raise ValidationError(f"subject_id must name a subject of the default population, got {subject_id!r}") from None


@functools.lru_cache(maxsize=4)
def _population_truth(subject_id, seed, face):
    """The truth of one subject of the synthetic population of ``seed`` drawn on face ``face`` (``ict-N``...)."""
    try:
        geometry = named_face(face)
        return synthesize_population(seed=seed, map_size=geometry.map_size, geometry=geometry, subjects=[subject_id])[
            subject_id
        ]
    except ValidationError:  # an id outside the population
        raise ValidationError(
            f"subject {subject_id!r} is not a subject of the synthetic population (S001-S149, and one subject's "
            "records under the other conditions, e.g. S008-lotion for seed 2006): "
            "pass the capture it was fitted to (--capture PATH on the command line)"
        ) from None


@functools.lru_cache(maxsize=2)
def _simulated(subject_id, seed, face, settings):
    """A simulated capture: of the default (``face`` None) or of the population of ``seed`` on ``face`` with the
    simulator ``settings`` ((name, value) pairs of :data:`SIMULATOR_SETTINGS`)."""
    if face is None:
        return simulate_capture(default_population(seed=seed)[subject_id])
    truth = _population_truth(subject_id, seed, face)
    return DomeSimulator(named_face(face), **dict(settings)).simulate(truth)
