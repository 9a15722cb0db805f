"""What the emulated devices see: a subject in the dome's cameras and on the contact sensor's fibres.

**Truth.** :func:`subject_truth` takes a subject of the synthetic population
(:func:`facestats.acquire.synthetic.population.synthesize_population`) or a store
subject (its fitted maps and scattering coefficients become the truth; see the
function for how unusable fitted texels are filled).

**Dome frames** (:class:`DomeScene`).  The subject is rendered as
:func:`facestats.acquire.synthetic.photographs.write_capture_photographs` renders
it: the procedural face is written as the lab's mesh and read back, the
noise-free radiance of every (lumitexel, camera, LED) comes from
:class:`facestats.acquire.synthetic.simulate.DomeSimulator`, and each camera's
pixels show their lumitexel through
:class:`facestats.acquire.synthetic.photographs.FrameRenderer`.  A frame exposes
electrons = radiance × ``camera_scale`` × Δt_k × drive (the LED's colour and
brightness, each /255: the calibration holds full drive), with shot and read
noise and the camera's known response (:class:`facestats.acquire.response.ResponseCurve`).
Pixels without signal (off the face, unlit) draw their codes from the exact code
distribution of read noise alone, by inverse-CDF lookup of 16-bit uniform
numbers (:func:`dark_code_table`); pixels with signal go through
:meth:`ResponseCurve.encode`.  Every frame's noise is seeded by (scene seed,
camera, LED, exposure, drive), so a frame taken twice is the same frame, whatever
happened in between — the property that makes resumed sessions byte-identical.

**Sensor frames** (:class:`SensorScene`).  The dipole profile R(r) of each site's
(σ's, σa) at the fibre distances (:func:`facestats.model.dipole.dipole_profile`,
Jensen et al. 2001's dipole in Suzuki et al.'s notation, eq. 3-13, as used by Weyrich et al. 2006 §5.4), imaged as the
round spots of :class:`facestats.acquire.devices.sensor.FiberLayout`: every
pixel of fibre k's spot collects ``scale`` × R(r_k) electrons per second
(:class:`facestats.acquire.sensor.ContactSensor`), read by the sensor's linear
camera with shot and read noise (:func:`facestats.acquire.hdr.expose`).  Dark
while the lamp is off or the shutter closed.
"""

from __future__ import annotations

import hashlib
import json
import pathlib
from dataclasses import replace

import numpy as np

from facestats.acquire.devices.sensor import FiberLayout
from facestats.acquire.hdr import expose
from facestats.acquire.response import ResponseCurve
from facestats.acquire.sensor import ContactSensor
from facestats.acquire.synthetic.photographs import FrameRenderer
from facestats.acquire.synthetic.population import SubjectTruth, check_population_id, synthesize_population
from facestats.core.compiled import resolve_backend
from facestats.core.progress import progress_bar
from facestats.core.published import ETA_SKIN
from facestats.core.validate import check_integer
from facestats.errors import ValidationError
from facestats.face.named import face_geometry, named_face
from facestats.model.dipole import dipole_profile, total_diffuse_reflectance, transport_coefficient

__all__ = ["subject_truth", "DomeScene", "SensorScene", "dark_code_table"]

#: Entries of the dark-code lookup table (16-bit uniform numbers).
TABLE_SIZE = 65536


def subject_truth(subject_id: str, *, store=None, map_size: int = 16, seed: int = 2006):
    """The truth of an emulated subject: from the synthetic population, or from a store subject.

    Parameters
    ----------
    subject_id : str
    store : str, path-like or Store, optional
        A store (``"default"``: the embedded one); None takes the synthetic
        population drawn with ``seed`` at ``map_size`` on the procedural head (its mesh
        vertices are its lumitexels: 172 at 16², where the ICT face's mesh has about 5,000,
        which keeps the emulated rig's per-frame work small).  A store subject keeps the
        face its capture provenance names (``ict-48`` for the embedded default).
    map_size : int
        Map side of a population subject (a store subject keeps its own).
    seed : int
        Seed of the synthetic population (``store=None`` only).

    Returns
    -------
    facestats.acquire.synthetic.population.SubjectTruth
        The subject's truth on its face.

    Notes
    -----
    A store subject's fitted maps become the truth on its face texels; texels
    whose fitted value is not usable (NaN, ρs < 0, m ≤ 0 or n < 0) take the
    median of the usable face texels of that map.  The site albedos are the total
    diffuse reflectances of the fitted site (σ's, σa) (Weyrich et al. 2006 eq. 16,
    :func:`facestats.model.dipole.total_diffuse_reflectance`), so the truth's
    site scattering reproduces the stored coefficients; σtr is the subject's
    (Weyrich eq. 15).
    """

    if store is None:
        check_population_id(subject_id, seed)  # one id, named as such: before the head is built
        head = face_geometry("procedural", map_size)
        return synthesize_population(seed=seed, map_size=map_size, geometry=head, subjects=[subject_id])[subject_id]
    return _truth_from_store(store, subject_id)


def _truth_from_store(store, subject_id):
    # local import: keeps facestats.io (22 modules) out of this module's import
    from facestats.io import open_store
    from facestats.io.schema import provenance

    st = open_store() if store == "default" else open_store(store) if isinstance(store, (str, pathlib.Path)) else store
    ds = st.subject(subject_id, exclude=["micro_normal"])  # the emulated scene uses the diffuse normal
    missing = [v for v in ("region", "albedo", "ts_rho_s", "ts_m", "site_sigma_s_prime", "site_sigma_a") if v not in ds]
    if missing:
        raise ValidationError(
            f"store subject {subject_id} has no maps to emulate (missing {missing}); use a map subject"
        )
    region = np.asarray(ds["region"].values, np.int64)
    face = region > 0

    def usable(name, ok):
        a = np.array(ds[name].values, np.float32)
        good = face & ok(a) if a.ndim == 2 else face & np.all(ok(a), axis=-1)
        if not good.any():
            raise ValidationError(f"store subject {subject_id} has no usable {name} texel on its face")
        fill = np.median(a[good], axis=0)
        a[face & ~good] = fill
        a[~face] = 0
        return a

    with np.errstate(invalid="ignore"):
        albedo = usable("albedo", lambda a: np.isfinite(a) & (a > 0) & (a < 1))
        rho = usable("ts_rho_s", lambda a: np.isfinite(a) & (a >= 0))
        m = usable("ts_m", lambda a: np.isfinite(a) & (a > 0))
        bp_rho = usable("bp_rho_s", lambda a: np.isfinite(a) & (a >= 0)) if "bp_rho_s" in ds else rho
        bp_n = usable("bp_exponent", lambda a: np.isfinite(a) & (a >= 0)) if "bp_exponent" in ds else m
    sp, sa = np.asarray(ds["site_sigma_s_prime"].values, float), np.asarray(ds["site_sigma_a"].values, float)
    if "sigma_s_prime" in ds and "sigma_a" in ds:
        sigma_tr = transport_coefficient(np.asarray(ds["sigma_a"].values), np.asarray(ds["sigma_s_prime"].values))
    else:
        sigma_tr = transport_coefficient(sa[:2], sp[:2]).mean(axis=0)
    meta = {k: ds.attrs[k] for k in ("subject_id", "person_id", "age", "gender", "skin_type", "condition")}
    return SubjectTruth(
        **meta,
        geometry=str(provenance(ds).get("capture_provenance", {}).get("geometry", "")),
        region_map=region.astype(np.uint8),
        albedo=albedo,
        ts_rho_s=rho,
        ts_m=m,
        bp_rho_s=bp_rho,
        bp_exponent=bp_n,
        site_sigma_tr=transport_coefficient(sa, sp),
        site_albedo=total_diffuse_reflectance(sp, sa, ETA_SKIN),
        sigma_tr=np.asarray(sigma_tr, float),
        seed=int.from_bytes(subject_id.encode()[:4].ljust(4, b"\0"), "big"),
    )


def dark_code_table(camera: ResponseCurve) -> np.ndarray:
    """Codes of a pixel without signal, indexed by a uniform 16-bit integer: the inverse CDF of read noise.

    ``camera.encode`` turns e = N(0, σ_read²) electrons into
    code = rint(f(e/full_well)·(levels − 1)) with f clipping at 0.  Code k is
    read for e in [x_k, x_{k+1}), with x_k the electron count at which the
    noiseless encoding steps to k, so P(code ≤ k) = Φ(x_{k+1}/σ_read); entry u of
    the table (u in [0, 65536)) is the smallest k with P(code ≤ k) > (u + ½)/65536.
    Tails below 2⁻¹⁶ (beyond about 4.2 σ) are not represented.

    Parameters
    ----------
    camera : ResponseCurve
        The camera's encoding: its ``read_noise`` (electrons), ``bits`` and ``encode``.

    Returns
    -------
    ndarray of uint8 (8-bit camera) or uint16, shape (65536,)
        The code of each uniform index; all 0 for a camera without read noise.
    """
    from scipy.special import ndtr

    sigma = float(camera.read_noise)
    if not sigma > 0:
        return np.zeros(TABLE_SIZE, np.uint16 if camera.bits > 8 else np.uint8)
    e = np.linspace(0.0, 8 * sigma, 16001)
    codes = camera.encode(e).astype(np.int64)
    steps = np.flatnonzero(np.diff(codes)) + 1  # e[steps[j]] is where code codes[steps[j]] starts
    cdf = ndtr(e[steps] / sigma)  # P(code < codes[steps[j]])
    u = (np.arange(TABLE_SIZE) + 0.5) / TABLE_SIZE
    table = codes[np.r_[0, steps]][np.searchsorted(cdf, u, side="right")]
    return table.astype(np.uint16 if camera.bits > 8 else np.uint8)


def _table_lookup(table, index, backend):
    """``table[index]`` for a 1-D ``index`` of unsigned integers (compiled or ``numpy.take``: the same values).

    The table must cover every value of the index's dtype (the compiled loop does not check bounds).
    """
    if table.size <= np.iinfo(index.dtype).max:
        raise ValidationError(
            f"table must have {np.iinfo(index.dtype).max + 1} entries for {index.dtype} indices, got {table.size}"
        )
    if backend == "numpy":
        return np.take(table, index)
    from facestats.acquire.devices.scene_numba import table_lookup

    out = np.empty(index.shape, table.dtype)
    table_lookup(table, index, out)
    return out


class DomeScene:
    """A subject in the emulated dome: the frames its cameras take (module docstring).

    Parameters
    ----------
    truth : SubjectTruth
    dome : Dome
        The emulated rig (its image size is the frames' size).
    workdir : path-like
        Where the lab's mesh (``face.obj``) and region image (``face.regions.npy``) are written.
    camera : ResponseCurve, optional
        The cameras' response; default 12-bit BT.709 with the dome's full well and read noise.
    seed : int
        Seeds every frame's noise (with the frame's camera, LED, exposure and drive).
    progress : bool
        Progress bar while the cameras' pixel maps are computed.
    cache : path-like, optional
        A directory keeping the cameras' pixel maps (``pixels-<key>.npz``, keyed by
        the SHA-256 of the mesh file and the rig): at 1024² pixels they take minutes
        to compute and depend on neither the subject nor the seed.
    backend : {"auto", "numba", "numpy"}
        The dark pixels' table look-up compiled (:mod:`facestats.acquire.devices.scene_numba`;
        default where numba is installed) or ``numpy.take``: the same frames.
    """

    def __init__(
        self,
        truth,
        dome,
        workdir,
        *,
        camera: ResponseCurve | None = None,
        seed: int = 0,
        progress: bool = False,
        cache=None,
        backend: str = "auto",
    ):
        # local import: keeps facestats.model (19 modules) out of this module's import
        from facestats.acquire.synthetic.simulate import DomeSimulator
        from facestats.io.mesh import load_face_mesh, save_face_mesh

        workdir = pathlib.Path(workdir)
        workdir.mkdir(parents=True, exist_ok=True)
        self.truth, self.dome, self.seed = truth, dome, int(seed)
        self.backend = resolve_backend(backend)
        self.camera = camera or ResponseCurve(12, dome.response.full_well, dome.response.read_noise)
        face = named_face(truth.geometry, truth.region_map.shape[0])
        self.mesh = pathlib.Path(save_face_mesh(face, workdir / "face.obj"))
        self.regions = workdir / "face.regions.npy"
        np.save(self.regions, truth.region_map)
        self.geometry = load_face_mesh(self.mesh, self.regions)  # the truth is the mesh the lab has
        sim = DomeSimulator(self.geometry, dome, noise=False, scan_normal_noise_deg=0.0, camera_visibility=False)
        self.radiance = sim.simulate(truth).array("radiance")  # (N, C, L, 3) float16, NaN: not rendered
        self.pixels = self._pixel_maps(cache, progress)
        self.dark = dark_code_table(self.camera)
        # per camera: the lumitexel of each face pixel and the flat indices of its three channels
        self._face = [(node[node >= 0], flat[node >= 0][:, None] * 3 + np.arange(3)) for flat, node in self.pixels]
        # (camera, LED, lumitexel, channel): one frame's radiance is a contiguous block (NaN, not rendered: dark)
        self._radiance = np.ascontiguousarray(np.moveaxis(np.nan_to_num(self.radiance.astype(np.float32)), 0, 2))

    def _pixel_maps(self, cache, progress):
        """Each camera's (flat pixel index, lumitexel) arrays (:meth:`FrameRenderer.pixels`), cached if asked."""

        key = hashlib.sha256(self.mesh.read_bytes() + json.dumps(self.dome.to_dict()).encode()).hexdigest()[:24]
        path = None if cache is None else pathlib.Path(cache) / f"pixels-{key}.npz"
        if path is not None and path.exists():
            with np.load(path) as z:
                return [(z[f"flat{c}"], z[f"node{c}"]) for c in range(self.dome.n_cameras)]
        renderer = FrameRenderer(self.geometry, self.dome)
        cams = range(self.dome.n_cameras)
        cams = progress_bar(cams, desc="emulated cameras", unit="camera", enabled=progress)
        maps = [renderer.pixels(c) for c in cams]
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_name(path.stem + ".part.npz")
            np.savez(tmp, **{f"{n}{c}": a for c, m in enumerate(maps) for n, a in zip(("flat", "node"), m)})
            tmp.replace(path)
        return maps

    @property
    def cameras(self) -> tuple:
        return tuple(range(self.dome.n_cameras))

    def calibration(self):
        """The rig as the lab's calibration file holds it: the true dome with the cameras' true response g."""

        g = np.repeat(self.camera.log_exposure()[:, None], 3, axis=1)
        return replace(self.dome, camera_log_response=g)

    def render(self, camera: int, trigger):
        """``(codes (H, W, 3), exposure time s)`` of ``camera`` for a dome :class:`~.cameras.Trigger`.

        Parameters
        ----------
        camera : int
            0-based camera index.
        trigger : Trigger
            Its ``exposure``, ``led`` (dark frame unless a LED of the dome), ``brightness`` and ``colour`` (the drive).

        Returns
        -------
        codes : ndarray, shape (H, W, 3)
            The camera's codes (uint16, uint8 for an 8-bit camera) at the dome's image size for ``camera``.
        exposure_s : float
            The exposure time of ``trigger.exposure``, s.

        Raises
        ------
        ValidationError
            ``camera`` or ``trigger.exposure`` out of range.
        """
        check_integer(camera, "camera", 0, self.dome.n_cameras - 1)
        exposure = check_integer(trigger.exposure, "exposure", 0, len(self.dome.exposure_times) - 1)
        t = float(self.dome.exposure_times[exposure])
        w, h = (int(v) for v in self.dome.image_size[camera])
        drive = np.asarray(trigger.colour, np.float32) / 255 * np.float32(trigger.brightness / 255)
        rng = np.random.default_rng([self.seed, camera, trigger.led + 1, exposure, trigger.brightness, *trigger.colour])
        n = h * w * 3  # uniform 16-bit table indices: four per raw 64-bit draw (3x faster than rng.integers)
        u = rng.bit_generator.random_raw(-(-n // 4)).view(np.uint16)[:n]
        codes = _table_lookup(self.dark, u, self.backend)
        if 0 <= trigger.led < self.dome.n_leds and np.any(drive > 0):
            node, index = self._face[camera]
            e = self._radiance[camera, trigger.led][node] * (drive * np.float32(self.dome.camera_scale * t))
            lit = e > 0
            codes[index[lit]] = self.camera.encode(e[lit], rng)
        return codes.reshape(h, w, 3), t


class SensorScene:
    """The contact sensor on a subject's three sites: the frames of its detector-fibre camera (module docstring).

    Parameters
    ----------
    sigma_s_prime, sigma_a : array_like, shape (site, channel)
        Each site's scattering coefficients, mm⁻¹.
    sensor : ContactSensor, optional
    layout : FiberLayout, optional
    eta : float
    seed : int
    """

    def __init__(self, sigma_s_prime, sigma_a, sensor=None, layout=None, *, eta: float = ETA_SKIN, seed: int = 0):
        self.sensor = ContactSensor() if sensor is None else sensor
        self.layout = FiberLayout(self.sensor.n_fibers) if layout is None else layout
        if self.layout.n_fibers != self.sensor.n_fibers:
            raise ValidationError(
                f"layout has {self.layout.n_fibers} fibres, the sensor {self.sensor.n_fibers}: they must agree"
            )
        sp, sa = np.asarray(sigma_s_prime, float), np.asarray(sigma_a, float)
        r = self.sensor.fiber_distance
        self.profile = dipole_profile(r[None, :, None], sp[:, None, :], sa[:, None, :], eta)  # (site, fiber, ch)
        self.seed = int(seed)
        self._labels = self.layout.labels().ravel()

    @classmethod
    def of(cls, truth, **kwargs) -> "SensorScene":
        """The scene of a :class:`SubjectTruth` (its site scattering).

        Parameters
        ----------
        truth : SubjectTruth
            Its :attr:`~facestats.acquire.synthetic.population.SubjectTruth.site_scattering` (σ's, σa), mm⁻¹.
        **kwargs
            Further arguments of :class:`SensorScene` (``sensor``, ``layout``, ``eta``, ``seed``).

        Returns
        -------
        SensorScene
        """
        sp, sa = truth.site_scattering
        return cls(sp, sa, **kwargs)

    @property
    def cameras(self) -> tuple:
        return (0,)

    def render(self, camera: int, trigger):
        """``(codes (H, W, 3) uint16, exposure time s)`` of the sensor camera for a sensor trigger.

        Parameters
        ----------
        camera : int
            Unused: the sensor has one camera (0).
        trigger : Trigger
            Its ``exposure`` (index in the bracket), ``site``, ``lamp`` and ``shutter`` (dark unless both are on).

        Returns
        -------
        codes : ndarray of uint16, shape (H, W, 3)
            Linear codes at the layout's size.
        exposure_s : float
            The bracket's exposure time, s.

        Raises
        ------
        ValidationError
            ``trigger.exposure`` or ``trigger.site`` out of range.
        """
        times = self.sensor.exposure_times
        j = check_integer(trigger.exposure, "exposure", 0, len(times) - 1)
        site = check_integer(trigger.site, "site", 0, self.profile.shape[0] - 1)
        w, h = self.layout.size
        rate = np.zeros((h * w, 3))
        if trigger.lamp and trigger.shutter:
            spot = self._labels >= 0
            rate[spot] = self.profile[site, self._labels[spot]] * self.sensor.scale

        rng = np.random.default_rng([self.seed, site, j, int(trigger.lamp), int(trigger.shutter)])
        dn = expose(rate, times[j : j + 1], self.sensor.camera, rng)[..., 0]
        return dn.reshape(h, w, 3).astype(np.uint16), float(times[j])
