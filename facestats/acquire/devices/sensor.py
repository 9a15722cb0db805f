"""The contact sensor's controller (Weyrich et al. 2006 §5.4): source lamp, shutter, the 23-image HDR bracket.

Commands (:mod:`facestats.acquire.devices.protocol`; every reply is a frame):

=========================  ===================================================================
``?``, ``ver``, ``reboot``  as on the dome (identity ``facestats-sensor …``)
``st``                     status: ``fibers=28 exposures=23 exposure_us=1000,1587,…
                           image=233x17 lamp=0 shutter=0 exposure=0 site=0``
``lamp.<0|1>``             the white LED coupled into the source fibre
``sh.<0|1>``               the camera's shutter (closed: dark frames)
``se.<j>``                 exposure j of the bracket (t_j = t₀ 2^(stop·j), ``exposure_us``)
``pos.<s>``                placement label: the site the operator has put the head on
                           (0 cheek, 1 forehead, 2 neck), recorded with every frame
``tr.<frame>``             take one picture of the detector fibres; answered with ``frame=…
                           exposure=… lamp=… shutter=… site=…``
``x``                      lamp off, shutter closed
=========================  ===================================================================

The camera images the 28 detector fibres as a row of round spots (:class:`FiberLayout`;
a documented choice: the paper's Fig. 9 shows such a row).  :func:`merge_bracket`
turns one site's bracket into the profile R(r) the fit reads: per pixel the
inverse-variance HDR merge of :func:`facestats.acquire.hdr.merge_exposures`,
then per fibre the mean over its spot (each spot pixel collects ``scale`` · R(r)
electrons per second, :class:`facestats.acquire.sensor.ContactSensor`) and the
standard deviation of that mean.

The sensor's calibration file (``facestats.sensor-calibration/1``, JSON) holds the
:meth:`ContactSensor.to_attrs` description and the fibre layout.
"""

from __future__ import annotations

import json
import pathlib
from dataclasses import asdict, dataclass

import numpy as np

from facestats.acquire.devices.cameras import Trigger
from facestats.acquire.devices.controller import Controller, status_field_error
from facestats.acquire.hdr import merge_exposures
from facestats.acquire.photographs import EXPOSURE_TOLERANCE, exposures_agree, read_sensor_file
from facestats.acquire.sensor import ContactSensor
from facestats.core.conventions import SITES
from facestats.core.published import N_FIBERS
from facestats.core.validate import check_integer
from facestats.errors import DeviceError, FormatError, ValidationError
from facestats.io.layout import read_regular_file

__all__ = [
    "FiberLayout",
    "merge_bracket",
    "SensorBracket",
    "read_bracket",
    "SensorController",
    "SensorStatus",
    "save_sensor_calibration",
    "load_sensor_calibration",
    "CALIBRATION_FORMAT",
]

#: Fields a contact sensor's ``tr`` reply must carry.
SENSOR_TRIGGER_FIELDS = ("frame", "exposure", "lamp", "shutter", "site")
CALIBRATION_FORMAT = "facestats.sensor-calibration/1"


@dataclass(frozen=True)
class FiberLayout:
    """Where the detector fibres appear in the sensor camera's image: a row of round spots.

    Fibre k's spot is centred at pixel (margin + k·pitch, margin) (pixel centres at
    integers) and holds the pixels within ``radius_px`` of it; the image is
    (2·margin + (n − 1)·pitch + 1) × (2·margin + 1) pixels.

    Attributes
    ----------
    n_fibers : int
        Detector fibres n (≥ 1).
    pitch_px : int
        Distance between neighbouring spot centres, pixels (≥ 1).
    radius_px : float
        Spot radius, pixels, in [0.5, min(pitch / 2, margin + 0.5)) so spots stay apart and inside the image.
    margin_px : int
        The margin around the row of spots: the first spot is centred at pixel (margin, margin) (≥ 1).
    """

    n_fibers: int = N_FIBERS
    pitch_px: int = 8
    radius_px: float = 2.5
    margin_px: int = 8

    def __post_init__(self):
        check_integer(self.n_fibers, "n_fibers", 1)
        check_integer(self.pitch_px, "pitch_px", 1)
        check_integer(self.margin_px, "margin_px", 1)
        if not 0.5 <= self.radius_px < min(self.pitch_px / 2, self.margin_px + 0.5):
            raise ValidationError(
                f"radius_px must lie in [0.5, {min(self.pitch_px / 2, self.margin_px + 0.5):g}) so spots stay apart "
                f"and inside the image, got {self.radius_px!r}"
            )

    @property
    def size(self) -> tuple:
        """(width, height) of the image, pixels."""
        return 2 * self.margin_px + (self.n_fibers - 1) * self.pitch_px + 1, 2 * self.margin_px + 1

    def labels(self) -> np.ndarray:
        """(H, W) int64: the fibre each pixel belongs to, −1 between the spots."""
        w, h = self.size
        v, u = np.mgrid[0:h, 0:w]
        k = np.rint((u - self.margin_px) / self.pitch_px).astype(np.int64)
        du = u - (self.margin_px + k * self.pitch_px)
        inside = (k >= 0) & (k < self.n_fibers) & (du**2 + (v - self.margin_px) ** 2 <= self.radius_px**2)
        return np.where(inside, k, -1)

    def to_dict(self) -> dict:
        """The layout as a JSON-ready dict."""
        return asdict(self)


def merge_bracket(stack, times, sensor, layout: FiberLayout):
    """R(r) per fibre (mm⁻²) and its standard deviation from one site's bracket of sensor frames.

    Parameters
    ----------
    stack : array_like, shape (E, H, W, 3)
        Linear raw codes (DN) of the E exposures.
    times : array_like, shape (E,)
        Exposure times, s.
    sensor : ContactSensor
        Its ``camera`` (noise model) and ``scale`` (electrons s⁻¹ per mm⁻² of R, per spot pixel).
    layout : FiberLayout

    Returns
    -------
    profile, std : ndarray, shape (F, 3)
        Mean over each fibre's spot of the merged rate / ``scale``, and
        sqrt(Σ σ²)/P / ``scale`` for its P pixels; NaN where a spot pixel clipped
        in every exposure.
    """

    dn = np.moveaxis(np.asarray(stack, np.float64), 0, -1)  # (H, W, 3, E)
    labels = layout.labels()
    if dn.shape[:2] != labels.shape or dn.shape[2] != 3:
        raise ValidationError(
            f"stack must hold (E, {labels.shape[0]}, {labels.shape[1]}, 3) frames, got {np.shape(stack)}"
        )
    rate, std, _ = merge_exposures(dn, times, sensor.camera)
    spot = labels >= 0
    k = labels[spot]
    count = np.bincount(k, minlength=layout.n_fibers)[:, None]
    total = np.stack([np.bincount(k, rate[spot][:, c], layout.n_fibers) for c in range(3)], 1)
    var = np.stack([np.bincount(k, std[spot][:, c] ** 2, layout.n_fibers) for c in range(3)], 1)
    return total / count / sensor.scale, np.sqrt(var) / count / sensor.scale


@dataclass
class SensorBracket:
    """A sensor session's result: the raw bracket per site and the merged profiles (:func:`read_bracket`).

    Attributes
    ----------
    sites : tuple of str
        :data:`~facestats.core.conventions.SITES`, the order of the site axis of ``readings`` and the profiles.
    fiber_distance : ndarray, shape (F,)
        mm.
    exposure_s : ndarray, shape (E,)
    readings : ndarray, shape (site, E, F, 3)
        Mean code of each fibre's spot in each frame, DN (black level included).
    profile, profile_std : ndarray, shape (site, F, 3)
        Merged R(r), mm⁻², and its standard deviation; NaN in both where a fibre has no reading (its spot clipped in
        every exposure).
    max_dn : int
        The camera's largest code (saturation).
    """

    sites: tuple
    fiber_distance: np.ndarray
    exposure_s: np.ndarray
    readings: np.ndarray
    profile: np.ndarray
    profile_std: np.ndarray
    max_dn: int


def read_bracket(folder) -> SensorBracket:
    """The sensor session of a capture folder: its ``sensor.json`` and the raw frames it lists.

    Fibre spots are located with the :class:`FiberLayout` the session merged with (``sensor.json`` field
    ``fiber_layout``); a file written before that field was stored: the default layout of the sensor's fibre count.

    Parameters
    ----------
    folder : str or path-like
        A capture directory holding a completed sensor session (:mod:`facestats.acquire.devices.session`).

    Returns
    -------
    SensorBracket
        Sites in :data:`~facestats.core.conventions.SITES` order (cheek, forehead, neck), whatever order they were
        captured in: the order ``sensor.json`` stores the profiles in.

    Raises
    ------
    FormatError
        No ``sensor.json``, or one :func:`~facestats.acquire.photographs.read_sensor_file` refuses (format,
        ``sensor``, ``profile``, ``profile_std``: shapes, ±inf, negative standard deviations, null in one field
        only), or one without ``frames``; a malformed ``fiber_layout`` or frame entry (``site``, ``exposure``,
        ``file``); a frame that cannot be read or whose size is not the fibre layout's.
    """
    # local import: keeps facestats.io (23 modules) out of this module's import
    from facestats.io.images import decode_integer_image

    folder = pathlib.Path(folder)
    frames, sensor, layout, profile, std = _read_session_file(folder)
    labels = layout.labels()
    spot = labels >= 0
    k = labels[spot]
    count = np.bincount(k, minlength=sensor.n_fibers)[:, None]
    readings = np.zeros((len(SITES), sensor.n_exposures, sensor.n_fibers, 3))
    for f in frames:
        site, j, name = _frame_of(f, folder, sensor.n_exposures)
        try:
            codes = decode_integer_image((folder / name).read_bytes(), name)[0].astype(np.float64)
        except OSError as exc:
            raise FormatError(f"sensor frame {folder / name} cannot be read: {exc.strerror or exc}") from None
        if codes.shape != (*labels.shape, 3):
            raise FormatError(
                f"sensor frame {folder / name} has shape {codes.shape} (height, width, channel), the fibre layout "
                f"{layout.to_dict()} needs {(*labels.shape, 3)}"
            )
        sums = np.stack([np.bincount(k, codes[spot][:, c], sensor.n_fibers) for c in range(3)], 1)
        readings[site, j] = sums / count
    return SensorBracket(
        SITES, sensor.fiber_distance, sensor.exposure_times, readings, profile, std, sensor.camera.max_dn
    )


def _read_session_file(folder):
    """``(frames, sensor, layout, profile, profile_std)`` of ``folder/sensor.json``, checked (:func:`read_bracket`)."""
    path = folder / "sensor.json"
    if not path.exists():
        raise FormatError(f"{folder} holds no completed sensor session (no sensor.json)")
    doc, sensor, profile, std = read_sensor_file(path)
    try:
        frames = list(doc["frames"])
    except (KeyError, TypeError) as exc:
        raise FormatError(f"{path} holds no frames (not a device session's file): {exc}") from None
    try:
        layout = FiberLayout(**doc.get("fiber_layout", {"n_fibers": sensor.n_fibers}))  # older files: the default
    except (AttributeError, TypeError, ValueError) as exc:
        raise FormatError(f"{path} has a malformed field 'fiber_layout': {exc}") from None
    if layout.n_fibers != sensor.n_fibers:
        raise FormatError(f"{path} field 'fiber_layout' has {layout.n_fibers} fibres, its sensor {sensor.n_fibers}")
    return frames, sensor, layout, profile, std


def _frame_of(entry, folder, n_exposures):
    """``(site index in SITES, exposure index, file)`` of a ``sensor.json`` frame entry, checked."""
    try:
        site, j, name = SITES.index(entry["site"]), entry["exposure"], entry["file"]
        if not isinstance(j, int) or isinstance(j, bool) or not 0 <= j < n_exposures or not isinstance(name, str):
            raise ValueError(f"exposure {j!r} (0..{n_exposures - 1}) and file {name!r:.60}")
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(
            f"{folder / 'sensor.json'} has a frame with a missing or malformed field {exc} (sites {SITES})"
        ) from None
    return site, j, name


def save_sensor_calibration(path, sensor, layout: FiberLayout) -> pathlib.Path:
    """Write the sensor's calibration (module docstring) as JSON.

    Parameters
    ----------
    path : str or path-like
        The file to write (format ``facestats.sensor-calibration/1``).
    sensor : ContactSensor
        The sensor's description (:meth:`~facestats.acquire.sensor.ContactSensor.to_attrs`).
    layout : FiberLayout
        Where its fibres appear in the sensor camera's image.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    p = pathlib.Path(path)
    doc = {"format": CALIBRATION_FORMAT, "sensor": sensor.to_attrs(), "fiber_layout": layout.to_dict()}
    p.write_text(json.dumps(doc, indent=1))
    return p


def load_sensor_calibration(path):
    """``(ContactSensor, FiberLayout)`` of a sensor calibration file; :class:`FormatError` naming what is wrong.

    Parameters
    ----------
    path : str or path-like
        A file written by :func:`save_sensor_calibration`.

    Returns
    -------
    sensor : ContactSensor
    layout : FiberLayout

    Raises
    ------
    FormatError
        The file cannot be read or is not JSON, its ``format`` is not ``facestats.sensor-calibration/1``, or a
        field is missing or malformed.
    """

    try:
        doc = json.loads(read_regular_file(path))
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: not JSON, or not UTF-8
        raise FormatError(f"cannot read sensor calibration {path}: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != CALIBRATION_FORMAT:
        raise FormatError(f"sensor calibration {path} field 'format' must be {CALIBRATION_FORMAT!r}")
    try:
        return ContactSensor.from_attrs(doc["sensor"]), FiberLayout(**doc["fiber_layout"])
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"sensor calibration {path} has a missing or malformed field: {exc}") from None


@dataclass(frozen=True)
class SensorStatus:
    """A sensor controller's ``st`` reply.

    Attributes
    ----------
    n_fibers : int
        Detector fibres (``fibers``).
    exposure_s : tuple of float
        The bracket's exposure times, s (``exposure_us`` / 10⁶).
    image_size : (int, int)
        The sensor camera's frame (width, height) (``image=WxH``).
    lamp, shutter : int
        Source lamp on (1) or off (0); shutter open (1) or closed (0).
    exposure : int
        The bracket exposure selected (index of ``exposure_s``).
    site : int
        The placement label: 0 cheek, 1 forehead, 2 neck.
    """

    n_fibers: int
    exposure_s: tuple
    image_size: tuple
    lamp: int
    shutter: int
    exposure: int
    site: int

    @classmethod
    def from_fields(cls, f: dict, port: str = "") -> "SensorStatus":
        """The status of a ``status`` reply's fields; :class:`DeviceError` naming a missing or malformed field.

        Parameters
        ----------
        f : dict
            The reply's ``key=value`` fields (:meth:`~facestats.acquire.devices.protocol.Reply.fields`).
        port : str
            The device's port, for the messages.

        Returns
        -------
        SensorStatus

        Raises
        ------
        DeviceError
            A missing or malformed field.
        """
        try:
            w, h = (int(v) for v in f["image"].split("x"))
            return cls(
                n_fibers=int(f["fibers"]),
                exposure_s=tuple(int(v) / 1e6 for v in f["exposure_us"].split(",")),
                image_size=(w, h),
                lamp=int(f["lamp"]),
                shutter=int(f["shutter"]),
                exposure=int(f["exposure"]),
                site=int(f["site"]),
            )
        except (KeyError, ValueError) as exc:
            raise status_field_error("sensor", port, exc, f) from None


class SensorController(Controller):
    """Driver of the contact sensor (module docstring); a context manager that turns the lamp off on leaving.

    Parameters
    ----------
    port : str, optional
        Device path or pyserial URL (:class:`~facestats.acquire.devices.controller.Controller`).
    link : SerialLink, optional
        An open link to use instead of opening ``port``.
    log : callable, optional
        Receives one line per irregular event.

    Other Parameters
    ----------------
    **link_options
        Keyword arguments of :class:`~facestats.acquire.devices.serial_link.SerialLink`.

    Raises
    ------
    DeviceError
        The device does not identify itself as a facestats sensor controller (or cannot be reached).
    """

    kind = "sensor"

    def sensor_status(self) -> SensorStatus:
        """The sensor's current status (a ``status`` request)."""
        return SensorStatus.from_fields(self.status(), self.port)

    def lamp(self, on: bool):
        """Switch the source lamp on or off.

        Parameters
        ----------
        on : bool
            True: lamp on.
        """
        self.link.request("lamp", int(bool(on)))
        self.remember("lamp", int(bool(on)))

    def shutter(self, open_: bool):
        """Open or close the shutter.

        Parameters
        ----------
        open_ : bool
            True: shutter open.
        """
        self.link.request("sh", int(bool(open_)))
        self.remember("shutter", int(bool(open_)))

    def set_exposure(self, j: int):
        """Select the bracket's exposure ``j``.

        Parameters
        ----------
        j : int
            Index of the bracket's exposure times (≥ 0; the device refuses one beyond its bracket).
        """
        self.link.request("se", check_integer(j, "exposure", 0))
        self.remember("exposure", int(j))

    def place(self, site: int):
        """Record the site the head now sits on (0 cheek, 1 forehead, 2 neck).

        Parameters
        ----------
        site : int
            Index of :data:`~facestats.core.conventions.SITES`, 0 to 2.
        """
        self.link.request("pos", check_integer(site, "site", 0, 2))
        self.remember("site", int(site))

    def ensure(self, site: int, exposure: int, lamp: bool = True, shutter: bool = True):
        """Bring the device to this state, sending only what it is not known to hold (again after a reboot).

        Parameters
        ----------
        site : int
            The placement label, 0 cheek, 1 forehead, 2 neck.
        exposure : int
            The bracket's exposure index.
        lamp : bool
            Source lamp on.
        shutter : bool
            Shutter open.
        """
        for _ in range(3):  # a reboot on the way loses what was set before it: set everything again
            epoch = self.epoch
            if self.changed("site", site):
                self.place(site)
            if self.changed("exposure", exposure):
                self.set_exposure(exposure)
            if self.changed("lamp", int(lamp)):
                self.lamp(lamp)
            if self.changed("shutter", int(shutter)):
                self.shutter(shutter)
            if self.epoch == epoch:
                return

    def trigger(self, frame: int, timeout: float | None = None) -> Trigger:
        """Take one picture; the state the device reports it was taken under.

        Parameters
        ----------
        frame : int
            Frame id of the picture (≥ 0); the reply must name it.
        timeout : float, optional
            Seconds to wait for the reply (answered after exposure and readout); default the link's timeout.

        Returns
        -------
        Trigger
            The reply's frame, exposure, lamp, shutter and site.

        Raises
        ------
        DeviceError
            A reply without a required field, with a malformed one, or naming another frame id.
        """
        reply = self.link.request("tr", check_integer(frame, "frame", 0), timeout=timeout)
        return Trigger.from_fields(reply.fields(), SENSOR_TRIGGER_FIELDS, frame)

    def bracket(self, site: int, exposures, frames, timeout: float | None = None):
        """The :class:`Trigger` of each exposure index of ``exposures`` at ``site``, frame ids from ``frames``.

        A generator: each exposure is set (:meth:`ensure`, lamp on, shutter open) and triggered as it is consumed.

        Parameters
        ----------
        site : int
            The placement label, 0 cheek, 1 forehead, 2 neck.
        exposures : iterable of int
            Bracket exposure indices, in order.
        frames : iterable of int
            A frame id for each exposure (the pairs stop with the shorter).
        timeout : float, optional
            Seconds to wait for each trigger's reply; default the link's timeout.

        Yields
        ------
        Trigger
        """
        for j, frame in zip(exposures, frames):
            self.ensure(site, j)
            yield self.trigger(frame, timeout)

    def check(self, n_fibers: int, exposure_s, image_size) -> SensorStatus:
        """Raise :class:`DeviceError` unless the sensor matches its calibration (fibres, bracket, image size).

        Parameters
        ----------
        n_fibers : int
            The calibration's fibre count.
        exposure_s : sequence of float
            The calibration's bracket, s; the device's must agree within ``EXPOSURE_TOLERANCE``.
        image_size : (int, int)
            The fibre layout's (width, height).

        Returns
        -------
        SensorStatus
            The device's status.

        Raises
        ------
        DeviceError
            A fibre count, exposure time or image size that differs.
        """
        st = self.sensor_status()
        where = f"the sensor on {self.port}"
        fix = "fix the sensor's configuration or use its calibration file; no picture was taken"
        if st.n_fibers != n_fibers:
            raise DeviceError(f"{where} reports {st.n_fibers} detector fibres, the calibration has {n_fibers}: {fix}")
        want, got = np.asarray(exposure_s, float), np.asarray(st.exposure_s, float)
        if not exposures_agree(got, want):
            raise DeviceError(
                f"{where} brackets {got.size} exposures {[round(float(v), 6) for v in got[:3]]}… s, the calibration "
                f"{want.size} exposures {[round(float(v), 6) for v in want[:3]]}… s (agreement within "
                f"{EXPOSURE_TOLERANCE * 100:g} % needed): {fix}"
            )
        if tuple(st.image_size) != tuple(image_size):
            raise DeviceError(
                f"{where} images {st.image_size} pixels, the calibration's fibre layout {image_size}: {fix}"
            )
        return st
