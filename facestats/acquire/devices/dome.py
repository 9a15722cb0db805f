"""The dome's LED and camera-trigger controller (Weyrich et al. 2006 §5: 150 LEDs, 16 cameras, two exposures).

Commands (:mod:`facestats.acquire.devices.protocol`; every reply is a frame):

=========================  ===================================================================
``?``                      list the commands
``ver``                    identity: ``facestats-dome <model> <version> protocol=1``
``st``                     status: ``leds=150 cameras=16 exposures=2 exposure_us=16667,125000
                           bits=12 frame_us=83333 led=-1 exposure=0 brightness=255
                           colour=255,255,255 lines=65535``
``l.<i>``                  light LED i alone (0-based; the others go off)
``x``                      every LED off
``sb.<v>``                 brightness 0-255 of the lit LED
``sc.<r>.<g>.<b>``         colour 0-255 per channel (white LEDs: a per-channel drive)
``se.<k>``                 exposure setting k of the cameras (index of ``exposure_us``)
``tm.<mask>``              which camera trigger lines pulse: bit c for camera c (power-up: all)
``tr.<frame>``             pulse the enabled trigger lines; the cameras expose under the present
                           light; answered after the exposure with ``frame=… led=… exposure=…
                           brightness=… colour=… lines=…``: the state the pictures were taken under
``reboot``                 restart (the state is lost; a ``BOOT`` frame follows)
=========================  ===================================================================

:class:`DomeController` drives it; its :meth:`~DomeController.check` compares the
device's status with the calibration before a session takes any picture.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facestats.acquire.devices.cameras import Trigger
from facestats.acquire.devices.controller import Controller, status_field_error
from facestats.acquire.photographs import EXPOSURE_TOLERANCE, exposures_agree
from facestats.core.validate import check_integer
from facestats.errors import DeviceError

#: Fields a dome's ``tr`` reply must carry (``lines`` may be missing: firmware without trigger masks pulses all).
DOME_TRIGGER_FIELDS = ("frame", "led", "exposure", "brightness", "colour")

__all__ = ["DomeController", "DomeStatus"]


def _ints(text: str) -> tuple:
    return tuple(int(v) for v in text.split(",") if v)


@dataclass(frozen=True)
class DomeStatus:
    """A dome controller's ``st`` reply: its wiring, camera settings and present light state.

    Attributes
    ----------
    n_leds : int
        LEDs the controller drives (``leds``).
    n_cameras : int
        Camera trigger lines (``cameras``).
    exposure_s : tuple of float
        The cameras' exposure settings, s (``exposure_us`` / 10⁶).
    bits : int
        Code depth of the cameras' frames.
    frame_interval_s : float
        Shortest time between triggers, s (``frame_us`` / 10⁶).
    led : int
        The LED lit (−1: none).
    exposure : int
        The exposure setting selected (index of ``exposure_s``).
    brightness : int
        LED brightness, 0-255.
    colour : tuple of int
        LED colour (R, G, B), 0-255.
    lines : int
        Trigger-line mask, bit c for camera c; −1 when the firmware reports none (it pulses every line).
    """

    n_leds: int
    n_cameras: int
    exposure_s: tuple
    bits: int
    frame_interval_s: float
    led: int
    exposure: int
    brightness: int
    colour: tuple
    lines: int = -1

    @classmethod
    def from_fields(cls, f: dict, port: str = "") -> "DomeStatus":
        """The status of a ``status`` reply's fields; :class:`DeviceError` naming a missing or malformed field.

        Parameters
        ----------
        f : dict
            The reply's ``key=value`` fields (:meth:`~facestats.acquire.devices.protocol.Reply.fields`).
        port : str
            The device's port, for the messages.

        Returns
        -------
        DomeStatus

        Raises
        ------
        DeviceError
            A missing or malformed field, or fewer than one LED or camera.
        """
        try:
            st = cls(
                n_leds=int(f["leds"]),
                n_cameras=int(f["cameras"]),
                exposure_s=tuple(v / 1e6 for v in _ints(f["exposure_us"])),
                bits=int(f["bits"]),
                frame_interval_s=int(f["frame_us"]) / 1e6,
                led=int(f["led"]),
                exposure=int(f["exposure"]),
                brightness=int(f["brightness"]),
                colour=_ints(f["colour"]),
                lines=int(f.get("lines", -1)),  # firmware without trigger masks pulses every line
            )
        except (KeyError, ValueError) as exc:
            raise status_field_error("dome", port, exc, f) from None
        if st.n_leds < 1 or st.n_cameras < 1:  # camera c is bit c of the trigger-line mask: a shift by c
            raise DeviceError(
                f"the dome on {port} reports {st.n_leds} LEDs and {st.n_cameras} cameras; expected at least one "
                f"of each: {f!r:.120}"
            )
        return st


class DomeController(Controller):
    """Driver of the dome controller (module docstring); a context manager that switches every LED off on leaving.

    Parameters
    ----------
    port : str, optional
        Device path or pyserial URL (:class:`~facestats.acquire.devices.controller.Controller`).

    Other Parameters
    ----------------
    **kwargs
        Keyword arguments of :class:`~facestats.acquire.devices.controller.Controller` (``link``, ``log`` and the
        :class:`~facestats.acquire.devices.serial_link.SerialLink` options).

    Raises
    ------
    DeviceError
        The device is not a facestats dome controller, or its status is missing or malformed.
    """

    kind = "dome"

    def dome_status(self) -> DomeStatus:
        """The dome's current status (a ``status`` request)."""
        return DomeStatus.from_fields(self.status(), self.port)

    def __init__(self, port: str | None = None, **kwargs):
        super().__init__(port, **kwargs)
        try:
            st = self.dome_status()
        except BaseException:
            self.link.close()
            raise
        self.n_cameras = st.n_cameras
        self.remember("lines", st.lines if st.lines >= 0 else (1 << st.n_cameras) - 1)

    def light(self, led: int):
        """Light LED ``led`` alone.

        Parameters
        ----------
        led : int
            0-based LED index (≥ 0; the device refuses one beyond its LEDs).
        """
        self.link.request("l", check_integer(led, "led", 0))
        self.remember("led", int(led))

    def set_brightness(self, value: int):
        """Set the LEDs' brightness, 0-255.

        Parameters
        ----------
        value : int
            Brightness, 0-255.
        """
        self.link.request("sb", check_integer(value, "brightness", 0, 255))
        self.remember("brightness", int(value))

    def set_colour(self, colour):
        """Set the LEDs' colour, three values 0-255 (R, G, B).

        Parameters
        ----------
        colour : sequence of int
            (R, G, B) drive, each 0-255.

        Raises
        ------
        DeviceError
            Not three values.
        """
        rgb = tuple(check_integer(v, "colour", 0, 255) for v in colour)
        if len(rgb) != 3:
            raise DeviceError(f"colour must be three values 0-255 (R, G, B), got {colour!r}")
        self.link.request("sc", *rgb)
        self.remember("colour", rgb)

    def set_exposure(self, k: int):
        """Select the cameras' exposure setting ``k`` (an index into the status's exposures).

        Parameters
        ----------
        k : int
            Index of :attr:`DomeStatus.exposure_s` (≥ 0).
        """
        self.link.request("se", check_integer(k, "exposure", 0))
        self.remember("exposure", int(k))

    def set_trigger_lines(self, cameras):
        """Pulse only these cameras' trigger lines at the next triggers.

        Parameters
        ----------
        cameras : iterable of int
            0-based camera indices, 0 to 62.

        Raises
        ------
        DeviceError
            No camera given.
        """
        mask = sum(1 << check_integer(c, "camera", 0, 62) for c in set(cameras))
        if not mask:
            raise DeviceError("set_trigger_lines needs at least one camera")
        self.link.request("tm", mask)
        self.remember("lines", mask)

    def ensure(self, led: int, exposure: int, brightness: int = 255, colour=(255, 255, 255), cameras=None):
        """Bring the device to this state, sending only what it is not known to hold (again after a reboot).

        Parameters
        ----------
        led : int
            The LED to light alone.
        exposure : int
            The cameras' exposure setting.
        brightness : int
            LED brightness, 0-255.
        colour : sequence of int
            LED colour (R, G, B), 0-255.
        cameras : iterable of int, optional
            The trigger lines to enable (default: every camera of the status).
        """
        for _ in range(3):  # a reboot on the way loses what was set before it: set everything again
            epoch = self.epoch
            lines = cameras if cameras is not None else range(self.n_cameras)
            if self.changed("lines", sum(1 << c for c in set(lines))):
                self.set_trigger_lines(lines)
            if self.changed("exposure", exposure):
                self.set_exposure(exposure)
            if self.changed("brightness", brightness):
                self.set_brightness(brightness)
            if self.changed("colour", tuple(colour)):
                self.set_colour(colour)
            if self.changed("led", led):
                self.light(led)
            if self.epoch == epoch:
                return

    def trigger(self, frame: int, timeout: float | None = None) -> Trigger:
        """Pulse the cameras' trigger lines; the state the device reports the exposure was taken under.

        Parameters
        ----------
        frame : int
            Frame id of the trigger (≥ 0); the reply must name it.
        timeout : float, optional
            Seconds to wait for the reply (answered after the exposure); default the link's timeout.

        Returns
        -------
        Trigger
            The reply's frame, LED, exposure, brightness, colour and trigger lines.

        Raises
        ------
        DeviceError
            A reply without a required field, with a malformed one, or naming another frame id.
        """
        reply = self.link.request("tr", check_integer(frame, "frame", 0), timeout=timeout)
        return Trigger.from_fields(reply.fields(), DOME_TRIGGER_FIELDS, frame)

    def check(self, n_leds: int, n_cameras: int, exposure_s, bits: int | None = None) -> DomeStatus:
        """Raise :class:`DeviceError` unless the device is wired and set up as the calibration says.

        Parameters
        ----------
        n_leds : int
            The calibration's LED count.
        n_cameras : int
            The calibration's camera count (trigger lines).
        exposure_s : sequence of float
            The calibration's exposure times, s; the device's must agree within ``EXPOSURE_TOLERANCE``.
        bits : int, optional
            The code depth of the calibration's response (not checked when None).

        Returns
        -------
        DomeStatus
            The device's status.

        Raises
        ------
        DeviceError
            A count, exposure time or code depth that differs.
        """
        st = self.dome_status()
        where = f"the dome on {self.port}"
        fix = "fix the wiring or the controller's configuration (or recalibrate); no picture was taken"
        if st.n_leds != n_leds:
            raise DeviceError(f"{where} reports {st.n_leds} LEDs, the calibration has {n_leds}: {fix}")
        if st.n_cameras != n_cameras:
            raise DeviceError(
                f"{where} reports {st.n_cameras} camera trigger lines, the calibration has {n_cameras}: {fix}"
            )
        want = np.asarray(exposure_s, float)
        got = np.asarray(st.exposure_s, float)
        if not exposures_agree(got, want):
            raise DeviceError(
                f"{where} exposes for {[round(float(v), 6) for v in got]} s, the calibration for "
                f"{[round(float(v), 6) for v in want]} s (agreement within {EXPOSURE_TOLERANCE * 100:g} % "
                f"needed): {fix}"
            )
        if bits is not None and st.bits != bits:
            raise DeviceError(f"{where} records {st.bits}-bit codes, the calibration's response has {bits} bits: {fix}")
        return st
