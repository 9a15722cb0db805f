"""Capture plans: the paper's two sequences as numbered steps, with the files they produce and their duration.

**Dome** (:class:`DomePlan`, Weyrich et al. 2006 §5): "the system sequentially
turns on each light while simultaneously capturing images with all 16 cameras",
and HDR comes from "immediately repeating the capture sequence with two different
exposure settings".  Step s is exposure e = s // L, LED l = s mod L (two passes
through the L LEDs); each step is one trigger of every camera, C frames, stored as
``cam{c:02d}/led{l:03d}_e{e}.png`` (:func:`facestats.acquire.synthetic.photographs.frame_name`,
the layout of the capture folder, ``docs/photographs.md``).  Duration on the
hardware: Σ over steps of max(Δt_e, frame interval) — the sequence is "limited by
the frame rate of the cameras" (§5: about 25 s for the two passes).

**Contact sensor** (:class:`SensorPlan`, §5.4): "23 images bracketed by 2/3
f-stops" at "three points …: forehead, cheek, and below the chin".  Step s is
site s // E (in the order of :data:`facestats.core.conventions.SITES`: cheek,
forehead, neck), exposure j = s mod E; one frame per step, stored as
``sensor/<site>_e{j:02d}.png``.  Duration: Σ (t_j + readout) per site — with the
default bracket (1 ms · 2^(2j/3), 69 s of exposure) and a 0.8 s readout, 88 s per
site, the paper's "total acquisition time is about 88 seconds".

A plan is a JSON document; its SHA-256 (:meth:`fingerprint`) identifies it in the
session journal, so a journal is never continued with another plan.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass

import numpy as np

from facestats.core.conventions import CONDITIONS, GENDERS, SITES
from facestats.core.validate import as_finite, check_choice, check_integer
from facestats.errors import ValidationError

__all__ = ["DomePlan", "SensorPlan", "subject_record", "PLAN_FORMAT"]

PLAN_FORMAT = "facestats.capture-plan/1"
SUBJECT_FIELDS = ("subject_id", "person_id", "age", "gender", "skin_type", "condition")


def subject_record(subject_id, *, person_id=None, age, gender, skin_type, condition="normal") -> dict:
    """The subject metadata a capture folder's manifest holds, checked.

    Parameters
    ----------
    subject_id : str
        The subject's id (:func:`facestats.io.ids.check_subject_id`).
    person_id : str, optional
        The person measured (several subjects may be one person); default ``subject_id``.
    age : int
        Years, 0 to 150.
    gender : {"M", "F"}
    skin_type : int
        Fitzpatrick skin type, 1 to 6.
    condition : str
        One of :data:`facestats.core.conventions.CONDITIONS`, default ``"normal"``.

    Returns
    -------
    dict
        ``subject_id``, ``person_id``, ``age``, ``gender``, ``skin_type`` and ``condition``.

    Raises
    ------
    ValidationError
        Naming the first field that is invalid.
    """
    # local import: keeps facestats.io (22 modules) out of this module's import
    from facestats.io.ids import check_subject_id

    sid = check_subject_id(subject_id)
    return {
        "subject_id": sid,
        "person_id": check_subject_id(person_id or sid),
        "age": check_integer(age, "age", 0, 150),
        "gender": check_choice(gender, "gender", GENDERS),
        "skin_type": check_integer(skin_type, "skin_type", 1, 6),
        "condition": check_choice(condition, "condition", CONDITIONS),
    }


def _canonical(doc) -> bytes:
    return json.dumps(doc, sort_keys=True, separators=(",", ":")).encode()


class _Plan:
    """What both plans share: identity, fingerprint, subject."""

    kind = ""

    def to_dict(self) -> dict:
        """The plan as a JSON-ready dict, with its format and kind."""
        return {"format": PLAN_FORMAT, "kind": self.kind, **asdict(self)}

    def fingerprint(self) -> str:
        """SHA-256 of the plan's canonical JSON: a resumed session must match it."""
        return hashlib.sha256(_canonical(self.to_dict())).hexdigest()

    @property
    def subject_id(self) -> str:
        return self.subject["subject_id"]

    def differences(self, other) -> list:
        """Names of the fields in which ``other`` (a plan dict) differs from this plan."""
        mine = json.loads(_canonical(self.to_dict()))
        return sorted(k for k in set(mine) | set(other) if mine.get(k) != other.get(k))


@dataclass(frozen=True)
class DomePlan(_Plan):
    """Every LED × every camera × each exposure setting (module docstring).

    Attributes
    ----------
    subject : dict
        Manifest metadata (:func:`subject_record`).
    n_leds, n_cameras : int
    exposure_s : tuple of float
        The calibration's exposure times, s.
    image_size : tuple of (int, int)
        Each camera's (width, height).
    bits : int
        Code depth of the frames, 8 to 16 (a capture folder's range).
    calibration_sha256 : str
        SHA-256 of the calibration file the plan was made from.
    brightness, colour
        LED drive (0-255).
    frame_interval_s : float
        The cameras' shortest time between frames (duration estimate).
    extension : str
        Frame file extension.
    """

    subject: dict
    n_leds: int
    n_cameras: int
    exposure_s: tuple
    image_size: tuple
    bits: int
    calibration_sha256: str
    brightness: int = 255
    colour: tuple = (255, 255, 255)
    frame_interval_s: float = 1 / 12
    extension: str = ".png"

    kind = "dome"

    def __post_init__(self):
        object.__setattr__(self, "bits", check_integer(self.bits, "bits", 8, 16))  # frozen: set through object
        check_integer(self.brightness, "brightness", 0, 255)
        if len(self.colour) != 3:
            raise ValidationError(f"colour must be three LED drive values (R, G, B), got {self.colour!r}")
        for value in self.colour:
            check_integer(value, "colour", 0, 255)
        as_finite(self.frame_interval_s, "frame_interval_s", 0, None)

    @classmethod
    def from_calibration(cls, dome, calibration_bytes: bytes, subject: dict, **options) -> "DomePlan":
        """The plan of a calibrated dome (:class:`facestats.acquire.dome.Dome`); ``bits`` from its response.

        Parameters
        ----------
        dome : Dome
            The calibration: LED and camera counts, exposure times, image sizes and camera response.
        calibration_bytes : bytes
            The calibration file's bytes (the plan holds their SHA-256).
        subject : dict
            Manifest metadata (:func:`subject_record`).
        **options
            Further fields (``brightness``, ``colour``, ``frame_interval_s``, ``extension``) and ``bits`` (an
            integer in [8, 16]), which defaults (when absent or None) to log2 of the response's levels, or 12
            without a response.

        Returns
        -------
        DomePlan

        Raises
        ------
        ValidationError
            ``bits`` (given or from the response) not an integer in [8, 16], or another field out of its domain.
        """
        levels = None if dome.camera_log_response is None else dome.camera_log_response.shape[1]
        bits = options.pop("bits", None)
        if bits is None:  # not ``or``: a given 0 is refused, not replaced by the default
            bits = int(np.log2(levels)) if levels else 12
        return cls(
            subject=subject,
            n_leds=dome.n_leds,
            n_cameras=dome.n_cameras,
            exposure_s=tuple(float(t) for t in dome.exposure_times),
            image_size=tuple((int(w), int(h)) for w, h in dome.image_size),
            bits=bits,
            calibration_sha256=hashlib.sha256(calibration_bytes).hexdigest(),
            **options,
        )

    @property
    def n_steps(self) -> int:
        return len(self.exposure_s) * self.n_leds

    @property
    def frames_per_step(self) -> int:
        return self.n_cameras

    def step(self, s: int) -> dict:
        """The state of step ``s``: ``{"exposure": e, "led": l}``.

        Parameters
        ----------
        s : int
            0-based step: exposure ``s // n_leds``, LED ``s % n_leds``.

        Returns
        -------
        dict
        """
        return {"exposure": s // self.n_leds, "led": s % self.n_leds}

    def ensure(self, controller, s: int):
        """Bring the dome to step ``s`` (its LED and exposure, the plan's brightness and colour).

        Parameters
        ----------
        controller : DomeController
            The open dome controller (its :meth:`~facestats.acquire.devices.dome.DomeController.ensure`).
        s : int
            0-based step.
        """
        st = self.step(s)
        controller.ensure(st["led"], st["exposure"], self.brightness, self.colour)

    def matches(self, s: int, trigger) -> bool:
        """True if the device reports the state of step ``s`` for ``trigger``.

        Parameters
        ----------
        s : int
            0-based step.
        trigger : Trigger
            The device's trigger reply.

        Returns
        -------
        bool
            The step's LED and exposure, the plan's brightness and colour, and every camera's line pulsed.
        """
        st = self.step(s)
        state = (trigger.led, trigger.exposure, trigger.brightness, tuple(trigger.colour))
        every = all(trigger.fires(c) for c in range(self.n_cameras))  # every camera's trigger line pulsed
        return every and state == (st["led"], st["exposure"], self.brightness, tuple(self.colour))

    def check_device(self, controller):
        """Raise before any picture unless the dome is wired and set up as planned.

        Parameters
        ----------
        controller : DomeController
            The open dome controller (:meth:`~facestats.acquire.devices.dome.DomeController.check`).

        Raises
        ------
        DeviceError
            LED or camera count, exposure times or code depth differ from the plan's.
        """
        controller.check(self.n_leds, self.n_cameras, self.exposure_s, self.bits)

    def trigger_timeout(self, s: int, link_timeout: float) -> float:
        """How long the trigger's reply may take: the exposure (or frame interval) plus the link's timeout, s.

        Parameters
        ----------
        s : int
            0-based step.
        link_timeout : float
            The serial link's reply timeout, s.

        Returns
        -------
        float
            max(exposure time of the step, frame interval) + ``link_timeout``, s.
        """
        return max(self.exposure_s[self.step(s)["exposure"]], self.frame_interval_s) + link_timeout

    def file(self, s: int, camera: int) -> str:
        """The capture folder's file name of ``camera``'s frame at step ``s``.

        Parameters
        ----------
        s : int
            0-based step.
        camera : int
            0-based camera index.

        Returns
        -------
        str
            ``cam{c:02d}/led{l:03d}_e{e}<extension>``
            (:func:`~facestats.acquire.synthetic.photographs.frame_name`).
        """
        # local import: keeps 22 modules out of this module's import
        from facestats.acquire.synthetic.photographs import frame_name

        st = self.step(s)
        return frame_name(camera, st["led"], st["exposure"], self.extension)

    def duration_s(self) -> float:
        """Σ over steps of max(exposure, frame interval), s (module docstring)."""
        return float(sum(max(t, self.frame_interval_s) for t in self.exposure_s) * self.n_leds)

    def describe(self) -> str:
        """A few lines for the operator: steps, frames, exposures and the data to expect."""
        w, h = self.image_size[0]
        raw = self.n_steps * self.n_cameras * sum(wc * hc for wc, hc in self.image_size) / self.n_cameras * 6
        return "\n".join(
            [
                f"dome capture of {self.subject_id}: {len(self.exposure_s)} passes × {self.n_leds} LEDs = "
                f"{self.n_steps} triggers × {self.n_cameras} cameras = {self.n_steps * self.n_cameras} frames",
                "exposures: "
                + ", ".join(f"{t * 1e3:.3g} ms" for t in self.exposure_s)
                + f"; LED drive {self.brightness}/255, colour {','.join(map(str, self.colour))}",
                f"frames: {w}×{h} px (camera 0), {self.bits}-bit codes in 16-bit {self.extension[1:].upper()}, "
                f"at most {raw / 1e9:.2f} GB uncompressed",
                f"estimated duration on the hardware: {self.duration_s():.1f} s (exposures and a camera frame "
                f"interval of {self.frame_interval_s * 1e3:.0f} ms; Weyrich et al. 2006 §5 report about 25 s)",
            ]
        )


@dataclass(frozen=True)
class SensorPlan(_Plan):
    """Three sites × the HDR bracket (module docstring).

    Attributes
    ----------
    subject : dict
    exposure_s : tuple of float
        The bracket's exposure times, s.
    n_fibers : int
    image_size : (int, int)
        The sensor camera's frame (width, height).
    calibration_sha256 : str
    sensor : dict
        The sensor's description (:meth:`facestats.acquire.sensor.ContactSensor.to_attrs`).
    layout : dict
        The fibre layout (:class:`facestats.acquire.devices.sensor.FiberLayout`).
    readout_s : float
        Time to read out one frame (duration estimate).
    sites : tuple of int
        Indices of :data:`SITES` in capture order.
    extension : str
        Frame file extension.
    """

    subject: dict
    exposure_s: tuple
    n_fibers: int
    image_size: tuple
    calibration_sha256: str
    sensor: dict
    layout: dict
    readout_s: float = 0.8
    sites: tuple = (0, 1, 2)
    extension: str = ".png"

    kind = "sensor"

    def __post_init__(self):
        as_finite(self.readout_s, "readout_s", 0, None)
        if sorted(self.sites) != list(range(len(SITES))):
            raise ValidationError(f"sites must hold each of 0..{len(SITES) - 1} once ({SITES}), got {self.sites!r}")

    @classmethod
    def from_calibration(cls, sensor, layout, calibration_bytes: bytes, subject: dict, **options) -> "SensorPlan":
        """The plan for a sensor, its fibre layout and the calibration file it was made from.

        Parameters
        ----------
        sensor : ContactSensor
            The sensor: exposure times, fibre count and description (:meth:`ContactSensor.to_attrs`).
        layout : FiberLayout
            Where the fibres appear in the sensor camera's image (its ``size`` is the plan's ``image_size``).
        calibration_bytes : bytes
            The calibration file's bytes (the plan holds their SHA-256).
        subject : dict
            Manifest metadata (:func:`subject_record`).
        **options
            Further fields: ``readout_s``, ``sites``, ``extension``.

        Returns
        -------
        SensorPlan
        """
        return cls(
            subject=subject,
            exposure_s=tuple(float(t) for t in sensor.exposure_times),
            n_fibers=sensor.n_fibers,
            image_size=tuple(int(v) for v in layout.size),
            calibration_sha256=hashlib.sha256(calibration_bytes).hexdigest(),
            sensor=sensor.to_attrs(),
            layout=layout.to_dict(),
            **options,
        )

    @property
    def n_steps(self) -> int:
        return len(self.sites) * len(self.exposure_s)

    @property
    def frames_per_step(self) -> int:
        return 1

    def step(self, s: int) -> dict:
        """The site and exposure of step ``s`` (sites in order, each through the bracket).

        Parameters
        ----------
        s : int
            0-based step: site ``sites[s // E]``, exposure ``s % E`` for E exposures.

        Returns
        -------
        dict
            ``{"site": index of SITES, "exposure": j}``.
        """
        e = len(self.exposure_s)
        return {"site": self.sites[s // e], "exposure": s % e}

    def ensure(self, controller, s: int):
        """Bring the sensor to step ``s`` (its site and exposure).

        Parameters
        ----------
        controller : SensorController
            The open sensor controller (its :meth:`~facestats.acquire.devices.sensor.SensorController.ensure`:
            also lamp on, shutter open).
        s : int
            0-based step.
        """
        st = self.step(s)
        controller.ensure(st["site"], st["exposure"])

    def matches(self, s: int, trigger) -> bool:
        """Whether ``trigger`` is the frame of step ``s`` (its site and exposure, lamp on, shutter open).

        Parameters
        ----------
        s : int
            0-based step.
        trigger : Trigger
            The device's trigger reply.

        Returns
        -------
        bool
        """
        st = self.step(s)
        return (trigger.site, trigger.exposure, trigger.lamp, trigger.shutter) == (st["site"], st["exposure"], 1, 1)

    def check_device(self, controller):
        """Raise before any picture unless the sensor has the planned fibres, bracket and image size.

        Parameters
        ----------
        controller : SensorController
            The open sensor controller (:meth:`~facestats.acquire.devices.sensor.SensorController.check`).

        Raises
        ------
        DeviceError
            Fibre count, exposure times or image size differ from the plan's.
        """
        controller.check(self.n_fibers, self.exposure_s, self.image_size)

    def trigger_timeout(self, s: int, link_timeout: float) -> float:
        """Seconds to wait for the frame of step ``s``: its exposure, the readout and ``link_timeout``.

        Parameters
        ----------
        s : int
            0-based step.
        link_timeout : float
            The serial link's reply timeout, s.

        Returns
        -------
        float
            Exposure time of the step + ``readout_s`` + ``link_timeout``, s.
        """
        return self.exposure_s[self.step(s)["exposure"]] + self.readout_s + link_timeout

    def file(self, s: int, camera: int = 0) -> str:
        """The capture folder's file name of the frame at step ``s``.

        Parameters
        ----------
        s : int
            0-based step.
        camera : int
            Unused: the sensor has one camera (the argument matches :meth:`DomePlan.file`).

        Returns
        -------
        str
            ``sensor/<site>_e{j:02d}<extension>``.
        """
        st = self.step(s)
        return f"sensor/{SITES[st['site']]}_e{st['exposure']:02d}{self.extension}"

    def duration_s(self) -> float:
        """Estimated seconds of the whole capture: every site's exposures and readouts."""
        return float(len(self.sites) * (sum(self.exposure_s) + self.readout_s * len(self.exposure_s)))

    def describe(self) -> str:
        """A few lines for the operator: sites, bracket, fibres and frame size."""
        t = self.exposure_s
        return "\n".join(
            [
                f"contact-sensor capture of {self.subject_id}: {len(self.sites)} sites "
                f"({', '.join(SITES[s] for s in self.sites)}) × {len(t)} exposures = {self.n_steps} frames",
                f"bracket: {t[0] * 1e3:.3g} ms … {t[-1]:.3g} s ({sum(t):.1f} s of exposure per site), "
                f"{self.n_fibers} fibres in {self.image_size[0]}×{self.image_size[1]} px frames",
                f"estimated duration on the hardware: {self.duration_s():.0f} s "
                f"({self.duration_s() / len(self.sites):.0f} s per site with a {self.readout_s:g} s readout; "
                "Weyrich et al. 2006 §5.4 report about 88 s), "
                "plus placing the sensor head",
            ]
        )
