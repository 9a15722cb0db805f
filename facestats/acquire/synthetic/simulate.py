"""Simulator of the face-scanning dome and the contact sensor (Weyrich et al. 2006 §5, §5.4).

Turns a subject's ground truth (:class:`facestats.acquire.synthetic.population.SubjectTruth`)
into the raw capture the real devices would produce (:class:`Capture`), using
the skin model of :mod:`facestats.model` as the forward model — no second copy
of the physics:

1. **Geometry and visibility** (per face geometry and dome, cached across
   subjects): directions to every LED and camera, the calibrated LED irradiance
   E⊥ (inverse square law and beam polynomial, :meth:`Dome.incident`), shadow
   maps of the mesh from every LED and camera
   (:class:`facestats.acquire.visibility.ShadowMaps`), the in-frame test, and the
   list of valid (lumitexel, camera, light) samples; the parameter-free factors of
   the Torrance-Sparrow BRDF per sample
   (:func:`facestats.model.brdf.torrance_sparrow_geometry`).
2. **Radiance** per valid sample: specular f_s E (Torrance-Sparrow or Blinn-Phong
   truth maps) plus the diffuse subsurface term M F_t(ωo)/π ∫R_d F_t(ωi) E dA
   through :class:`facestats.model.skin.SubsurfaceTransport` (the dipole over the
   lumitexels' surface when the subject is simulated in one block; the flat-patch
   limit per block when streaming large subjects).
3. **Camera**: two exposures (§5) with shot and read noise and 12-bit clipping
   (:mod:`facestats.acquire.hdr`), merged to HDR; samples clipped in both
   exposures are invalid.
4. **Optional head motion**: each light's pass sees the head rotated by a small
   random angle (σ = ``head_motion_deg``) about its centre; the capture still
   records the nominal geometry, as a real registration would.
5. **Scanner normals**: the capture's ``scan_normal`` is the true normal tilted by
   a random angle (σ = ``scan_normal_noise_deg``, default 2°): the fit must
   recover normals by photometric stereo.
6. **Contact sensor**: at cheek, forehead and neck the dipole profile of the site's
   (σ's, σa) at the 28 fibre distances, captured with the 23-image HDR bracket of
   :class:`facestats.acquire.sensor.ContactSensor`.

Determinism: every random draw comes from the subject's seed (and the block index
when streaming), so the same truth, seed and block size give bit-identical
captures.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np

from facestats.acquire.capture import PER_LUMITEXEL, Capture, CaptureWriter
from facestats.acquire.dome import Dome, default_dome
from facestats.acquire.hdr import expose, merge_exposures
from facestats.acquire.sensor import ContactSensor
from facestats.acquire.visibility import ShadowMaps, dome_shadow_maps, sample_visibility
from facestats.core.progress import progress_bar
from facestats.core.published import ETA_SKIN
from facestats.core.validate import as_finite, check_choice, check_integer
from facestats.core.version import __version__
from facestats.errors import ValidationError
from facestats.face.geometry import FaceGeometry
from facestats.face.named import named_face
from facestats.model import brdf as _brdf
from facestats.model import dipole
from facestats.model.dipole import check_dipole_eta, dipole_profile
from facestats.model.fresnel import fresnel_reflectance_unchecked
from facestats.model.skin import SPECULAR_MODELS, SubsurfaceTransport, neighbour_pairs

__all__ = ["DomeSimulator", "simulate_capture"]


@dataclass
class _Block:
    """Truth-independent geometry of one block of lumitexels."""

    start: int
    stop: int
    normal: np.ndarray  # (n, 3) true normals
    e_perp: np.ndarray  # (n, L, 3) float32
    cos_i: np.ndarray  # (n, L) float32, clipped at 0, 0 where unlit
    ft_i: np.ndarray  # (n, L) float32
    ft_o: np.ndarray  # (n, C) float32
    t: np.ndarray  # (S,) sample lumitexel (block-local)
    c: np.ndarray  # (S,) sample camera
    l: np.ndarray  # (S,) sample light
    cos_delta: np.ndarray  # (S,) float32
    k_ts: np.ndarray  # (S,) float32
    neighbours: tuple | None = None


class DomeSimulator:
    """Simulate dome and contact-sensor captures of subjects on one face geometry.

    Parameters
    ----------
    geometry : FaceGeometry
        Lumitexels, normals (the truth) and shadowing mesh.
    dome : Dome, optional
        Calibration of the rig; default :func:`facestats.acquire.dome.default_dome`.
    sensor : ContactSensor, optional
        Contact sensor; default :class:`ContactSensor`.
    specular : {"torrance_sparrow", "blinn_phong"}
        Which of the truth's BRDF maps renders the highlights.
    noise : bool
        Simulate camera and sensor noise (False: exact radiance, no clipping).
    head_motion_deg : float
        Standard deviation of the per-light head rotation, degrees, ≥ 0 (0 = still).
    scan_normal_noise_deg : float
        Standard deviation of the scanner-normal tilt, degrees, ≥ 0.
    block : int
        Lumitexels per block (≥ 1).  When the geometry fits one block, the geometry
        is cached across subjects and the dipole transport runs over the whole face.
    subsurface_radius : float
        Neighbourhood radius of the dipole transport, mm, > 0 (the energy beyond it
        is returned locally; 12 mm keeps > 98 % of red-channel energy in the
        neighbourhood for σtr ≥ 0.45 mm⁻¹).
    shadow_resolution : int, optional
        Shadow-map side in pixels (≥ 1); default twice the mesh grid (about one
        pixel per half triangle edge).
    eta : float
        Relative index of refraction of skin, in [1, 3] (default 1.38).
    camera_visibility : bool
        Keep only samples the camera sees (shadow map, in frame).  False renders
        every front-facing (lumitexel, camera) pair that is lit — the radiance a
        renderer needs, which resolves occlusion itself
        (:mod:`facestats.acquire.synthetic.photographs`).
    """

    def __init__(
        self,
        geometry: FaceGeometry,
        dome: Dome | None = None,
        sensor: ContactSensor | None = None,
        *,
        specular: str = "torrance_sparrow",
        noise: bool = True,
        head_motion_deg: float = 0.0,
        scan_normal_noise_deg: float = 2.0,
        block: int = 8192,
        subsurface_radius: float = 12.0,
        shadow_resolution: int | None = None,
        eta: float = ETA_SKIN,
        camera_visibility: bool = True,
    ):
        if not isinstance(geometry, FaceGeometry):
            raise ValidationError(f"geometry must be a FaceGeometry, got {type(geometry).__name__}")
        if dome is not None and not isinstance(dome, Dome):
            raise ValidationError(f"dome must be a Dome (or None for the default), got {type(dome).__name__}")
        if sensor is not None and not isinstance(sensor, ContactSensor):
            raise ValidationError(
                f"sensor must be a ContactSensor (or None for the default), got {type(sensor).__name__}"
            )
        check_choice(specular, "specular", SPECULAR_MODELS)
        as_finite(head_motion_deg, "head_motion_deg", 0, None, unit="deg")
        as_finite(scan_normal_noise_deg, "scan_normal_noise_deg", 0, None, unit="deg")
        check_integer(block, "block", 1)
        as_finite(subsurface_radius, "subsurface_radius", 0, None, low_inclusive=False, unit="mm")
        if shadow_resolution is not None:
            check_integer(shadow_resolution, "shadow_resolution", 1)
        check_dipole_eta(eta)
        self.geometry = geometry
        self.dome = default_dome() if dome is None else dome
        self.sensor = ContactSensor() if sensor is None else sensor
        self.specular = specular
        self.noise = bool(noise)
        self.head_motion_deg = float(head_motion_deg)
        self.scan_normal_noise_deg = float(scan_normal_noise_deg)
        self.block = int(block)
        self.subsurface_radius = float(subsurface_radius)
        self.eta = float(eta)
        self.camera_visibility = bool(camera_visibility)
        mesh_grid = int(geometry.meta.get("mesh_grid", 128))
        self.shadow_resolution = int(shadow_resolution or 2 * mesh_grid)
        self._shadows = None  # made on first use: a build's own process only draws the sensor profiles
        self._cache: dict = {}
        self._texels = None  # face texel of every lumitexel (FaceGeometry.face_texel_index), on first use

    @property
    def shadows(self) -> ShadowMaps:
        """Shadow maps of the geometry's mesh from every LED, then every camera (:func:`dome_shadow_maps` at
        ``shadow_resolution``), made on first use and kept.

        Only the rendering of a capture reads them: the process of a build with worker processes draws the
        sensor profiles of every subject with its simulator but renders none, and no longer makes them.
        """
        if self._shadows is None:
            self._shadows = dome_shadow_maps(self.geometry, self.dome, self.shadow_resolution)
        return self._shadows

    @property
    def single_block(self) -> bool:
        """Whether the whole geometry is one block (geometry cached, dipole over the whole face)."""
        return self.geometry.n_points <= self.block

    def _ranges(self):
        """``(start, stop)`` of every block of lumitexels."""
        n = self.geometry.n_points
        return [(s, min(s + self.block, n)) for s in range(0, n, self.block)]

    # -- geometry -------------------------------------------------------------------
    def _block_geometry(self, start: int, stop: int) -> _Block:
        key = (start, stop)
        if key in self._cache:
            return self._cache[key]
        g = self.geometry
        pos, nrm = g.position[start:stop], g.normal[start:stop]
        sv = sample_visibility(self.dome, self.shadows, pos, nrm)
        wi, wo, e_perp, cos_i, cos_o, lit = sv.wi, sv.wo, sv.e_perp, sv.cos_i, sv.cos_o, sv.lit
        seen = sv.seen if self.camera_visibility else cos_o > 0
        t, c, l = np.nonzero(seen[:, :, None] & lit[:, None, :])
        cos_delta, k_ts = _brdf.torrance_sparrow_geometry(
            nrm[t].astype(np.float32), wi[t, l].astype(np.float32), wo[t, c].astype(np.float32), self.eta
        )
        eta = np.float32(self.eta)
        ci = np.where(lit, cos_i, 0).astype(np.float32)
        blk = _Block(
            start=start,
            stop=stop,
            normal=nrm,
            e_perp=e_perp.astype(np.float32),
            cos_i=ci,
            ft_i=(1 - fresnel_reflectance_unchecked(np.clip(ci, 0, 1), eta)).astype(np.float32),
            ft_o=(1 - fresnel_reflectance_unchecked(np.clip(cos_o, 0, 1).astype(np.float32), eta)).astype(np.float32),
            t=t.astype(np.int32),
            c=c.astype(np.int32),
            l=l.astype(np.int32),
            cos_delta=cos_delta.astype(np.float32),
            k_ts=k_ts.astype(np.float32),
        )
        if self.single_block:
            blk.neighbours = neighbour_pairs(pos, self.subsurface_radius)
            self._cache[key] = blk
        return blk

    def samples_per_lumitexel(self) -> np.ndarray:
        """Number of valid (camera, light) samples of each lumitexel before noise and clipping."""
        out = np.zeros(self.geometry.n_points, np.int64)
        for start, stop in self._ranges():
            b = self._block_geometry(start, stop)
            out[start:stop] = np.bincount(b.t, minlength=stop - start)
        return out

    # -- per subject ---------------------------------------------------------------------
    def _truth_at_lumitexels(self, truth, sl):
        """Albedo (n, 3), ρs and lobe parameter (n,) of the truth maps at lumitexels ``sl``, float32.

        The maps are read at each lumitexel's face texel (:meth:`FaceGeometry.face_texel_index`):
        with maps finer than the lumitexel grid, a lumitexel's own texel can lie off the face,
        where the truth maps hold no skin.
        """
        if self._texels is None:
            self._texels = self.geometry.face_texel_index()
        v, u = self._texels[sl, 0], self._texels[sl, 1]
        if self.specular == "torrance_sparrow":
            rho, lobe = truth.ts_rho_s[v, u], truth.ts_m[v, u]
        else:
            rho, lobe = truth.bp_rho_s[v, u], truth.bp_exponent[v, u]
        return truth.albedo[v, u].astype(np.float32), rho.astype(np.float32), lobe.astype(np.float32)

    def _motion(self, blk, rng):
        """Per-sample geometry with the head rotated for each light's pass (module docstring, item 4)."""
        dome, g = self.dome, self.geometry
        n_led = dome.n_leds
        sigma = np.radians(self.head_motion_deg)
        axis = rng.standard_normal((n_led, 3))
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        ang = sigma * rng.standard_normal(n_led)
        kx = np.zeros((n_led, 3, 3))
        kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
        kx = kx - np.swapaxes(kx, 1, 2)
        rot = np.eye(3) + np.sin(ang)[:, None, None] * kx + (1 - np.cos(ang))[:, None, None] * (kx @ kx)  # Rodrigues
        centre = 0.5 * (g.mesh_vertices.min(0) + g.mesh_vertices.max(0))
        # Rotating the head by R equals rotating lights and cameras by Rᵀ about its centre.
        led = centre + np.einsum("lji,lj->li", rot, dome.led_position - centre)
        cams = centre + np.einsum("lji,cj->lci", rot, dome.camera_position - centre)  # (L, C, 3)
        pos = g.position[blk.start : blk.stop]
        p = pos[blk.t]
        wi = led[blk.l] - p
        wi /= np.linalg.norm(wi, axis=1, keepdims=True)
        wo = cams[blk.l, blk.c] - p
        wo /= np.linalg.norm(wo, axis=1, keepdims=True)
        nrm = blk.normal[blk.t]
        cos_delta, k_ts = _brdf.torrance_sparrow_geometry(
            nrm.astype(np.float32), wi.astype(np.float32), wo.astype(np.float32), self.eta
        )
        eta = np.float32(self.eta)
        ci = np.clip(np.einsum("sk,sk->s", nrm, wi), 0, 1).astype(np.float32)
        co = np.clip(np.einsum("sk,sk->s", nrm, wo), 0, 1).astype(np.float32)
        return (
            cos_delta,
            k_ts,
            ci,
            1 - fresnel_reflectance_unchecked(ci, eta),
            1 - fresnel_reflectance_unchecked(co, eta),
        )

    def _radiance_block(self, truth, blk: _Block, rng) -> np.ndarray:
        """Simulated HDR radiance of one block, dense (n, C, L, 3) float16 with NaN for invalid samples."""
        dome = self.dome
        n, n_cam, n_led = blk.stop - blk.start, dome.n_cameras, dome.n_leds
        albedo, rho, lobe = self._truth_at_lumitexels(truth, slice(blk.start, blk.stop))
        modulation = albedo / truth.albedo_avg.astype(np.float32)
        t, c, l = blk.t, blk.c, blk.l
        if self.head_motion_deg > 0:
            cos_delta, k_ts, cos_i_s, ft_i_s, ft_o_s = self._motion(blk, rng)
        else:
            cos_delta, k_ts = blk.cos_delta, blk.k_ts
            cos_i_s, ft_i_s, ft_o_s = blk.cos_i[t, l], blk.ft_i[t, l], blk.ft_o[t, c]
        # Specular (grey BRDF × light colour), Weyrich eq. 11-13.
        if self.specular == "torrance_sparrow":
            f_s = rho[t] * _brdf.beckmann_distribution_unchecked(cos_delta, lobe[t]) * k_ts
        else:
            f_s = rho[t] * _brdf.blinn_phong_lobe_unchecked(cos_delta, lobe[t])
        e_s = blk.e_perp[t, l] * cos_i_s[:, None]  # (S, 3) irradiance E = E⊥ cos θi
        # Diffuse: entering flux F_t(ωi) E per (lumitexel, light), dipole transport, exit.
        e_tl = blk.e_perp * blk.cos_i[..., None]
        # (σ's, σa) from α_avg and σtrAvg at the simulator's η (the truth's own properties assume skin's 1.38;
        # at another η the rendered diffuse reflectance missed α_avg by 2-6 %, found by an audit).
        sp, sa = dipole.scattering_from_albedo(truth.albedo_avg, truth.sigma_tr, self.eta)
        if self.single_block and self.head_motion_deg == 0:
            transport = SubsurfaceTransport(
                sp,
                sa,
                self.eta,
                positions=self.geometry.position[blk.start : blk.stop],
                areas=self.geometry.area[blk.start : blk.stop],
                radius=self.subsurface_radius,
                neighbours=blk.neighbours,
            )
        else:
            transport = SubsurfaceTransport(sp, sa, self.eta)
        exitance = transport.apply((blk.ft_i[..., None] * e_tl).astype(np.float32)).astype(np.float32)  # (n, L, 3)
        if self.head_motion_deg > 0:  # flux of the moved geometry, local transport
            exitance_s = (transport.total_reflectance.astype(np.float32) * (ft_i_s[:, None] * e_s)).astype(np.float32)
        else:
            exitance_s = exitance[t, l]
        radiance = f_s[:, None] * e_s + (modulation[t] * (ft_o_s / np.float32(np.pi))[:, None]) * exitance_s
        if self.noise:
            rate = radiance * np.float32(dome.camera_scale)
            dn = expose(rate, dome.exposure_times, dome.response, rng)
            rate_hat, _, n_used = merge_exposures(dn, dome.exposure_times, dome.response)
            radiance = rate_hat / np.float32(dome.camera_scale)
            radiance[np.any(n_used == 0, axis=-1)] = np.nan
        # NaN everywhere, filled as its uint16 bit pattern: numpy fills float16 element by element
        # (about 30 times slower); the bits are the same.
        out = np.empty((n * n_cam * n_led, 3), np.uint16)
        out.fill(np.float16(np.nan).view(np.uint16))
        out = out.view(np.float16)
        out[(t.astype(np.int64) * n_cam + c) * n_led + l] = radiance.astype(np.float16)
        return out.reshape(n, n_cam, n_led, 3)

    def _geometry_arrays(self, sl):
        """The capture's per-lumitexel geometry arrays (except ``scan_normal``) of lumitexels ``sl``."""
        g = self.geometry
        return {
            "position": g.position[sl].astype(np.float32),
            "uv": g.uv[sl].astype(np.float32),
            "area": g.area[sl].astype(np.float32),
            "region": g.region[sl],
        }

    def _scan_normals(self, sl, rng):
        """Scanner normals of lumitexels ``sl``: the true normals tilted (module docstring, item 5)."""
        nrm = self.geometry.normal[sl]
        if self.scan_normal_noise_deg == 0:
            return nrm.astype(np.float32)
        tilt = rng.standard_normal(nrm.shape) * np.radians(self.scan_normal_noise_deg) / np.sqrt(2)
        tilt -= np.einsum("nk,nk->n", tilt, nrm)[:, None] * nrm  # tangent perturbation
        out = nrm + tilt
        return (out / np.linalg.norm(out, axis=1, keepdims=True)).astype(np.float32)

    def _sensor(self, truth, rng):
        """Sensor profiles and their std (site, fiber, channel) of the truth's sites (module docstring, item 6)."""
        sp, sa = dipole.scattering_from_albedo(truth.site_albedo, truth.site_sigma_tr, self.eta)  # at the η rendered
        r = self.sensor.fiber_distance
        prof = dipole_profile(r[None, :, None], sp[:, None, :], sa[:, None, :], self.eta)  # (site, fiber, channel)
        if not self.noise:
            return prof, np.zeros_like(prof)
        return self.sensor.capture(prof, rng)

    def _attrs(self, truth, seed):
        """Capture attributes: metadata, calibration and provenance."""
        prov = {
            "source": "facestats simulator",
            "software": f"facestats {__version__}",
            "seed": int(seed),
            "specular": self.specular,
            "noise": self.noise,
            "head_motion_deg": self.head_motion_deg,
            "scan_normal_noise_deg": self.scan_normal_noise_deg,
            "geometry": self.geometry.name,
            "subsurface": "dipole" if (self.single_block and self.head_motion_deg == 0) else "local",
            "block": self.block,
            "eta": self.eta,
        }
        return dict(
            truth.metadata(),
            dome=json.dumps(self.dome.to_dict()),
            sensor=json.dumps(self.sensor.to_attrs()),
            map_size=int(truth.region_map.shape[0]),
            provenance=json.dumps(prov),
        )

    def _streams(self, seed, n_blocks):
        """Independent generators from ``seed``: scanner normals, sensor, and one per block."""
        ss = np.random.SeedSequence(int(seed))
        normals_ss, sensor_ss, *blocks = ss.spawn(2 + n_blocks)
        return (
            np.random.default_rng(normals_ss),
            np.random.default_rng(sensor_ss),
            [np.random.default_rng(b) for b in blocks],
        )

    def _check_truth(self, truth):
        """Raise unless the truth's maps have the geometry's map size and skin at every lumitexel."""
        if truth.region_map.shape[0] != self.geometry.map_size:
            raise ValidationError(
                f"truth maps are {truth.region_map.shape[0]}² but the geometry's map_size is {self.geometry.map_size}"
            )
        _, rho, lobe = self._truth_at_lumitexels(truth, slice(None))
        name = "ts_m" if self.specular == "torrance_sparrow" else "bp_exponent"
        bad = ~(lobe > 0) if self.specular == "torrance_sparrow" else ~(lobe >= 0)
        bad |= ~(rho >= 0)
        if np.any(bad):
            drawn = truth.geometry
            hint = (
                f" (the truth was drawn on {drawn!r}, the simulator's face is {self.geometry.name!r}: draw the "
                "population with geometry= this face)"
                if drawn and drawn != self.geometry.name
                else ""
            )
            raise ValidationError(
                f"truth of {truth.subject_id} must hold skin (rho_s >= 0, {name} > 0 for Torrance-Sparrow, >= 0 "
                f"for Blinn-Phong) at every lumitexel's texel; {int(bad.sum())} lumitexel(s) read "
                f"e.g. rho_s={float(rho[bad][0])!r}, {name}={float(lobe[bad][0])!r}{hint}"
            )

    # -- public -------------------------------------------------------------------------
    def simulate(self, truth, seed: int | None = None) -> Capture:
        """Simulate one subject in memory (use :meth:`simulate_to_zarr` for large geometries).

        Parameters
        ----------
        truth : SubjectTruth
            The subject; its maps must have the geometry's map size.
        seed : int, optional
            Seed of every random draw; default ``truth.seed``.

        Returns
        -------
        Capture
            Per-lumitexel geometry, scanner normals, irradiance and radiance (N, C, L, 3) float16 (NaN: invalid
            sample), the region map and the contact-sensor profiles.

        Raises
        ------
        ValidationError
            Truth maps of another size, or without skin at a lumitexel's texel.
        """
        self._check_truth(truth)
        seed = truth.seed if seed is None else seed
        ranges = self._ranges()
        rng_n, rng_s, rngs = self._streams(seed, len(ranges))
        radiance = np.concatenate(
            [self._radiance_block(truth, self._block_geometry(a, b), r) for (a, b), r in zip(ranges, rngs)]
        )
        irr = np.concatenate([self._block_geometry(a, b).e_perp for a, b in ranges])
        prof, std = self._sensor(truth, rng_s)
        arrays = dict(
            self._geometry_arrays(slice(None)),
            scan_normal=self._scan_normals(slice(None), rng_n),
            irradiance=irr,
            radiance=radiance,
            region_map=truth.region_map,
            sensor_profile=prof,
            sensor_profile_std=std,
            fiber_distance=self.sensor.fiber_distance,
        )
        return Capture(arrays=arrays, attrs=self._attrs(truth, seed))

    def simulate_to_zarr(self, truth, path, seed: int | None = None, progress: bool = False, chunk: int = 2048) -> str:
        """Simulate one subject block by block straight into a zarr capture (bounded memory).

        Parameters
        ----------
        truth : SubjectTruth
            The subject; its maps must have the geometry's map size.
        path : str or path-like
            The zarr capture to write (:class:`~facestats.acquire.capture.CaptureWriter`).
        seed : int, optional
            Seed of every random draw; default ``truth.seed``.
        progress : bool
            Progress bar over the blocks.
        chunk : int
            The lumitexel chunk of the zarr arrays (a fit reads blocks of this size without decoding a chunk
            twice); it is independent of the simulation block.

        Returns
        -------
        str
            ``path``.

        Raises
        ------
        ValidationError
            Truth maps of another size, or without skin at a lumitexel's texel.
        """
        self._check_truth(truth)
        seed = truth.seed if seed is None else seed
        g = self.geometry
        ranges = self._ranges()
        rng_n, rng_s, rngs = self._streams(seed, len(ranges))
        writer = CaptureWriter(
            path,
            n_lumitexels=g.n_points,
            n_cameras=self.dome.n_cameras,
            n_lights=self.dome.n_leds,
            map_size=g.map_size,
            n_fibers=self.sensor.n_fibers,
            attrs=self._attrs(truth, seed),
            chunk=int(chunk),
        )
        it = zip(ranges, rngs)
        it = progress_bar(list(it), desc=f"simulate {truth.subject_id}", unit="block", enabled=progress)
        for (a, b), r in it:
            blk = self._block_geometry(a, b)
            sl = slice(a, b)
            arrays = dict(
                self._geometry_arrays(sl),
                scan_normal=self._scan_normals(sl, rng_n),
                irradiance=blk.e_perp,
                radiance=self._radiance_block(truth, blk, r),
            )
            assert set(arrays) == set(PER_LUMITEXEL)
            writer.write_block(a, arrays)
        prof, std = self._sensor(truth, rng_s)
        writer.write_global(
            {
                "region_map": truth.region_map,
                "sensor_profile": prof,
                "sensor_profile_std": std,
                "fiber_distance": self.sensor.fiber_distance,
            }
        )
        return str(path)


def simulate_capture(truth, geometry: FaceGeometry | None = None, **kwargs) -> Capture:
    """Simulate one subject on ``geometry`` (default: the face its truth was drawn on, ``truth.geometry``,
    rebuilt by :func:`facestats.face.named.named_face` at the truth's map size).

    Parameters
    ----------
    truth : SubjectTruth
        The subject's ground truth (:mod:`facestats.acquire.synthetic.population`); its ``seed`` seeds the noise.
    geometry : FaceGeometry, optional
        The face to simulate on.
    **kwargs
        Keyword arguments of :class:`DomeSimulator` (``dome``, ``sensor``, ``noise``, ``eta``, …).

    Returns
    -------
    Capture
        In memory (:meth:`DomeSimulator.simulate`).

    Raises
    ------
    ValidationError
        ``truth.geometry`` names no face facestats can rebuild (when ``geometry`` is None), or an argument of
        :class:`DomeSimulator` out of its domain.
    """
    if geometry is None:
        geometry = named_face(truth.geometry, truth.region_map.shape[0])
    return DomeSimulator(geometry, **kwargs).simulate(truth)
