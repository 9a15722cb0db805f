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
  the camera's **micro-normal** map where the subject has one (§5.1, Fig. 6c:
  "one diffuse and per-view micro-normal maps"), else the diffuse normal map;
* diffuse: modulation M = α/α_avg (eq. 7) times the **spatial** dipole
  transport ∫ R_d(‖xo − xi‖) F_t(ωi) E(xi) dA(xi) over the lumitexels
  (:class:`facestats.model.skin.SubsurfaceTransport` in surface mode, σ's and
  σa of the subject, §5.4), with the diffuse normal.

Images are splatted lumitexels in the camera's image (one pixel per lumitexel,
:func:`facestats.pipeline.render.camera_image`); error = rendered − reference;
relative RMSE = RMSE / RMS(reference) over the pixels valid in both, all channels.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from facestats.acquire.geometry import uv_to_texel
from facestats.acquire.synthetic.population import default_population
from facestats.acquire.synthetic.simulate import simulate_capture
from facestats.acquire.visibility import ShadowMaps
from facestats.core.published import ETA_SKIN
from facestats.core.validate import check_choice, check_integer
from facestats.errors import ValidationError
from facestats.io.mesh import subject_mesh
from facestats.io.probes import read_light_probe
from facestats.io.schema import modulation, provenance
from facestats.model.skin import SPECULAR_MODELS, SubsurfaceTransport, skin_radiance
from facestats.model.sphere import latlong_light_samples
from facestats.pipeline.render import camera_image
from facestats.pipeline.settings import MAP_VARS, MODEL_PREFIX

__all__ = ["Render", "render_led", "render_probe", "camera_rmse", "default_capture"]


@dataclass
class Render:
    """A validation render: images (H, W, 3) in the capture's radiance units, NaN where nothing projects."""

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


def _radiance(subject, capture, camera, wi, irr, *, specular, eta):
    """Model radiance (N, L, 3) of every lumitexel seen by ``camera`` for lights (wi, irr of shape (N, L, 3))."""

    lt, v, u = _texels(subject, capture)
    normal = _unit(np.asarray(subject["normal"].values)[v, u])
    if "micro_normal" in subject.data_vars:  # per-view micro-normals for the specular term (§5.1, Fig. 6c)
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


def _led_samples(subject, capture, camera, light, specular, eta):
    """Predicted and captured radiance (N, 3) of every lumitexel for one camera and LED (NaN where invalid)."""
    lt = capture.lumitexels()
    wi = lt.wi[:, light : light + 1].astype(np.float64)
    normal = _unit(np.asarray(subject["normal"].values)[_texels(subject, capture)[1:]])
    cos = np.clip(np.einsum("nk,nlk->nl", normal, wi), 0, None)
    # Light reaches a lumitexel only where the capture has it lit and unshadowed (valid in some camera).
    lit = np.any(lt.valid[:, :, light], axis=1)
    irr = lt.irradiance[:, light : light + 1].astype(np.float64) * (cos * lit[:, None])[..., None]
    pred, _ = _radiance(subject, capture, camera, wi, irr, specular=specular, eta=eta)
    valid = lt.valid[:, camera, light]
    pred = np.where(valid[:, None], pred[:, 0], np.nan)
    meas = np.where(valid[:, None], lt.radiance[:, camera, light].astype(np.float64), np.nan)
    return pred, meas


def render_led(subject, capture, camera: int, light: int, *, specular="torrance_sparrow", eta=ETA_SKIN) -> Render:
    """The fitted model for ``camera`` under LED ``light``, beside the capture's radiance (module docstring).

    Parameters
    ----------
    subject : xarray.Dataset
        A fitted map subject (``normal`` required; ``micro_normal`` used if present).
    capture : Capture
        The capture (or a re-simulation) of that subject.
    camera, light : int
        Dome camera and LED.
    specular : {"torrance_sparrow", "blinn_phong"}
    eta : float

    Returns
    -------
    Render
    """

    _check(subject, capture, camera, light, specular)
    pred, meas = _led_samples(subject, capture, camera, light, specular, eta)
    ok = np.isfinite(pred).all(1) & np.isfinite(meas).all(1)
    if not ok.any():
        raise ValidationError(f"camera {camera} sees no lumitexel lit by LED {light} in this capture")
    rmse = float(np.sqrt(np.mean((pred[ok] - meas[ok]) ** 2)))
    rel = rmse / float(np.sqrt(np.mean(meas[ok] ** 2)))
    rendered = camera_image(pred, capture, camera, light)
    reference = camera_image(meas, capture, camera, light)
    return Render(rendered, reference, camera, f"LED {light}", rmse, rel)


def _check(subject, capture, camera, light, specular):
    check_choice(specular, "specular", SPECULAR_MODELS)
    check_integer(camera, "camera", 0, capture.dome.n_cameras - 1)
    if light is not None:
        check_integer(light, "light", 0, capture.dome.n_leds - 1)
    if "normal" not in subject.data_vars:
        raise ValidationError("subject must hold the fitted 'normal' map (a Dataset from fit_subject)")


def render_probe(subject, capture, camera: int, probe, *, samples=(8, 16), specular="torrance_sparrow", eta=ETA_SKIN):
    """The fitted model for ``camera`` under a lat-long light probe, shadowed by the face mesh.

    The probe is averaged down to ``samples`` = (rows, columns) directions
    (area-weighted block means), each a directional light of irradiance
    E = L Δω (N·ω) (:func:`facestats.model.sphere.latlong_light_samples`), occluded
    where the subject's face mesh (:func:`facestats.io.mesh.subject_mesh`)
    shadows it.

    Parameters
    ----------
    probe : str, os.PathLike or ndarray (H, W, 3)
        Lat-long probe (a file is read with :func:`facestats.io.probes.read_light_probe`).
    samples : (int, int)
        Light directions (rows, columns); must divide the probe's size.

    Returns
    -------
    Render
        Without a reference.
    """

    check_integer(camera, "camera", 0, capture.dome.n_cameras - 1)
    img = read_light_probe(probe) if not isinstance(probe, np.ndarray) else np.asarray(probe, np.float64)
    h, w = (check_integer(s, "samples", 1) for s in samples)
    d, power = latlong_light_samples(img, h, w)
    lt, v, u = _texels(subject, capture)
    normal = _unit(np.asarray(subject["normal"].values)[v, u])
    mesh = subject_mesh(subject, mesh_grid=64)
    centre = mesh.vertices.mean(0)
    vis = ShadowMaps(mesh.vertices, mesh.faces, centre + 2000.0 * d, target=centre, resolution=128).visible(
        lt.position.astype(np.float64), normal
    )
    cos = np.clip(normal @ d.T, 0, None) * vis
    irr = cos[..., None] * power[None]
    wi = np.broadcast_to(d, (len(normal),) + d.shape)
    pred, _ = _radiance(subject, capture, camera, wi, irr, specular=specular, eta=eta)
    _, in_frame, _ = capture.dome.view(lt.position.astype(np.float64), cameras=[camera])
    values = np.where(in_frame[:, :1], pred.sum(axis=1), np.nan)
    return Render(camera_image(values, capture, camera, 0), None, camera, "probe")


def camera_rmse(
    subject, capture, camera: int, *, specular="torrance_sparrow", lights=None, eta=ETA_SKIN, max_angle_deg=80.0
) -> float:
    """Relative RMSE of the model for one camera over every LED (or ``lights``), pooled over the valid samples.

    Samples count where θi and θo about the fitted normal are within
    ``max_angle_deg`` (the domain eq. 14 fits, as
    :func:`facestats.pipeline.render.held_out_camera_error`).
    """
    _check(subject, capture, camera, None, specular)
    lt, v, u = _texels(subject, capture)
    normal = _unit(np.asarray(subject["normal"].values)[v, u])
    lim = np.cos(np.radians(float(max_angle_deg)))
    inside = (np.einsum("nk,nlk->nl", normal, lt.wi) > lim) & (np.einsum("nk,nk->n", normal, lt.wo[:, camera]) > lim)[
        :, None
    ]
    lights = range(capture.dome.n_leds) if lights is None else lights
    num = den = 0.0
    for light in lights:  # LEDs one by one: each is one product with the spatial transport
        pred, meas = _led_samples(subject, capture, camera, int(check_integer(light, "light")), specular, eta)
        ok = np.isfinite(pred).all(1) & np.isfinite(meas).all(1) & inside[:, int(light)]
        num += float(np.sum((pred[ok] - meas[ok]) ** 2))
        den += float(np.sum(meas[ok] ** 2))
    if den == 0:
        raise ValidationError(f"camera {camera} sees no lit lumitexel in this capture")
    return float(np.sqrt(num / den))


def default_capture(subject):
    """Re-simulate the capture of a subject of the embedded default store (same truth, seed and dome).

    Parameters
    ----------
    subject : str or xarray.Dataset
        A subject id of the default population, or a fitted subject: then its
        provenance must show that it was fitted from the default simulation of
        that subject (simulator, seed, geometry and specular model), so that a
        subject of another store is never compared with a capture it was not
        fitted to.

    The last two are cached (a simulation takes seconds); treat the capture as read-only.
    """

    subject_id = subject if isinstance(subject, str) else str(subject.attrs.get("subject_id", ""))
    truth = _default_truth(subject_id)
    if not isinstance(subject, str):
        got = provenance(subject).get("capture_provenance", {})
        want = {
            "source": "facestats simulator",
            "seed": truth.seed,
            "geometry": truth.geometry,
            "specular": "torrance_sparrow",
        }
        differ = {k: got.get(k) for k, v in want.items() if got.get(k) != v}
        if differ:
            expected = {k: want[k] for k in differ}
            raise ValidationError(
                f"subject {subject_id!r} was not fitted from the default simulation of that subject (its capture "
                f"provenance has {differ}, the default has {expected}); pass the capture it was fitted to "
                "(--capture PATH on the command line)"
            )
    return _simulated_default(subject_id)


def _default_truth(subject_id):
    try:
        return default_population()[subject_id]
    except (KeyError, IndexError):
        raise ValidationError(f"subject_id must name a subject of the default population, got {subject_id!r}") from None


@functools.lru_cache(maxsize=2)
def _simulated_default(subject_id):
    return simulate_capture(_default_truth(subject_id))
