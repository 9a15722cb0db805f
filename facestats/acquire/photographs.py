"""A folder of dome photographs: its manifest (format ``facestats.capture-folder/1``), checked frames, HDR samples.

A lab's capture arrives as a folder of photographs, one per (camera, LED,
exposure) — per target pose for calibration captures — and a ``manifest.json``
that lists them (the layout is documented in ``docs/photographs.md``)::

    {
      "format": "facestats.capture-folder/1",
      "kind": "face",                      # or "target" (LED calibration photographs)
      "bits": 12,                          # code depth of the frames (8-16)
      "n_cameras": 16, "n_leds": 150,
      "subject": {...},                    # face: subject_id, person_id, age, gender, skin_type, condition
      "sensor": "sensor.json",             # face: contact-sensor profiles (optional)
      "target": {...},                     # target: albedo, poses (calibration.py)
      "frames": [
        {"camera": 0, "led": 0, "exposure": 0, "exposure_s": 0.016667,
         "file": "cam00/led000_e0.png", "sha256": "…", "pose": 0},
        …
      ]
    }

Rules checked on opening (:func:`open_folder`; each violation is a
:class:`facestats.errors.FormatError` naming the file, the field and the value):
``cameras`` lists each camera once (every camera, unless a target); every
listed file exists; every (pose, camera, LED) has the same exposures 0..E−1 and
no frame twice; exposure times increase strictly with the exposure index.
Against a calibration (:func:`check_exposures`, before an ingest or an LED
calibration reads any frame): every ``exposure_s`` is the calibration's time of
its exposure index within 1 %.  Rules checked on reading a frame
(:meth:`CaptureFolder.read_codes`): the SHA-256 of the file's bytes matches; the
image decodes as 8- or 16-bit RGB with codes below 2^bits (an 8-bit file in a
12-bit manifest is refused); its size is the calibration's; an EXIF
``ExposureTime``, when present, agrees with ``exposure_s`` within 1 %.

HDR samples: :func:`bilinear_taps` gives, for sub-pixel positions (OpenCV
convention: pixel centres at integer coordinates), the four neighbouring pixels
and their bilinear weights; :func:`merge_at` merges a frame's exposures at those
pixels with :func:`facestats.acquire.response.merge_photographs` and
interpolates, so a 1-megapixel frame is decoded once and merged only where
lumitexels fall; :func:`exposure_consistency` measures how often the exposures
of a frame disagree over the face (the head-motion test of
:mod:`facestats.acquire.ingest`).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import pathlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from facestats.acquire.response import hat_weights, merge_photographs
from facestats.acquire.sensor import ContactSensor
from facestats.core.conventions import CHANNELS, SITES
from facestats.core.outputs import json_ready
from facestats.errors import FormatError, SchemaError, ValidationError
from facestats.io.schema import check_subject_metadata

__all__ = [
    "FORMAT",
    "MANIFEST",
    "CaptureFolder",
    "check_response",
    "check_exposures",
    "relative_inside",
    "EXPOSURE_TOLERANCE",
    "exposures_agree",
    "open_folder",
    "write_manifest",
    "write_sensor_file",
    "read_sensor_file",
    "frame_entry",
    "bilinear_taps",
    "merge_at",
    "exposure_consistency",
    "prefetch",
]

FORMAT = "facestats.capture-folder/1"
SENSOR_FORMAT = "facestats.sensor-profiles/1"
MANIFEST = "manifest.json"
SUBJECT_FIELDS = ("subject_id", "person_id", "age", "gender", "skin_type", "condition")
_FRAME_FIELDS = ("camera", "led", "exposure", "exposure_s", "file", "sha256")
#: Relative tolerance within which two statements of one exposure time must agree: a frame's EXIF ExposureTime and
#: its manifest ``exposure_s``, ``exposure_s`` and the calibration's ``exposure_times_s`` (:func:`check_exposures`),
#: and a device's reported exposure settings and the calibration's (``facestats capture``).
EXPOSURE_TOLERANCE = 0.01


def exposures_agree(got, want) -> bool:
    """True if the exposure times ``got`` have ``want``'s shape and each agrees with its own within
    :data:`EXPOSURE_TOLERANCE` (relative); times in s.

    Parameters
    ----------
    got, want : array_like
        Exposure times, s (``want`` > 0).

    Returns
    -------
    bool
    """
    got, want = np.asarray(got, float), np.asarray(want, float)
    return got.shape == want.shape and bool(np.all(np.abs(got / want - 1) <= EXPOSURE_TOLERANCE))


def write_sensor_file(path, sensor, profile, profile_std, **fields) -> pathlib.Path:
    """Write contact-sensor profiles (site, fiber, channel; mm⁻²) and the sensor's description as JSON.

    Parameters
    ----------
    path : str or path-like
        The file to write (format ``facestats.sensor-profiles/1``).
    sensor : ContactSensor
        The sensor's description (stored through :meth:`ContactSensor.to_attrs`).
    profile, profile_std : array_like, shape (sites, fibers, 3)
        Profile and its standard deviation in mm⁻² per site, fiber and channel; NaN (or ±inf) is written as
        ``null``, as anywhere in the file (strict JSON has no NaN; the readers read ``null`` back as NaN).
    **fields
        Further top-level entries (e.g. the raw bracket frames of a device capture); readers ignore them.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    doc = {
        "format": SENSOR_FORMAT,
        "sensor": sensor.to_attrs(),
        "profile": np.asarray(profile, np.float64),
        "profile_std": np.asarray(profile_std, np.float64),
        **fields,
    }
    p = pathlib.Path(path)
    p.write_text(json.dumps(json_ready(doc), allow_nan=False))
    return p


def frame_entry(folder, file, camera: int, led: int, exposure: int, exposure_s: float, pose: int = 0) -> dict:
    """The manifest entry of one frame already written at ``folder/file`` (its SHA-256 computed here).

    Parameters
    ----------
    folder : str or path-like
        The capture folder.
    file : str or path-like
        The frame's path relative to ``folder`` (stored as ``str(file)``).
    camera, led, exposure : int
        0-based camera, LED and exposure indices.
    exposure_s : float
        Exposure time in seconds.
    pose : int
        Target pose index (0 for a face capture).

    Returns
    -------
    dict
        ``camera``, ``led``, ``exposure``, ``exposure_s``, ``file``, ``sha256`` (hex) and ``pose``.
    """
    data = (pathlib.Path(folder) / file).read_bytes()
    return {
        "camera": int(camera),
        "led": int(led),
        "exposure": int(exposure),
        "exposure_s": float(exposure_s),
        "file": str(file),
        "sha256": hashlib.sha256(data).hexdigest(),
        "pose": int(pose),
    }


def write_manifest(folder, frames, *, kind="face", bits, n_cameras, n_leds, **fields) -> pathlib.Path:
    """Write ``manifest.json`` (module docstring) into ``folder``; ``fields`` add e.g. ``subject``, ``target``.

    Nothing is checked here (:func:`open_folder` checks on reading); the file is written to a temporary name and
    moved into place.

    Parameters
    ----------
    folder : str or path-like
        The capture folder (must exist).
    frames : iterable of dict
        Manifest entries, one per frame (:func:`frame_entry`).
    kind : {"face", "target"}
        A face capture or LED calibration target photographs.
    bits : int
        Code depth of the frames (8-16).
    n_cameras, n_leds : int
        Cameras and LEDs of the rig.
    **fields
        Further top-level manifest fields (JSON-serialisable).

    Returns
    -------
    pathlib.Path
        The path of the written ``manifest.json``.
    """
    doc = {"format": FORMAT, "kind": kind, "bits": int(bits), "n_cameras": int(n_cameras), "n_leds": int(n_leds)}
    doc.update(fields)
    doc["frames"] = list(frames)
    p = pathlib.Path(folder) / MANIFEST
    tmp = p.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(doc, indent=1))
    os.replace(tmp, p)
    return p


#: Most cameras a capture folder may declare (Weyrich et al.'s dome has 16; a light stage a few).
MAX_CAMERAS = 1024


def _positive_finite(v) -> bool:
    """True for a number > 0 that float64 holds finitely (a JSON integer of 400 digits is refused, not overflowed)."""
    try:
        return 0 < float(v) < math.inf
    except OverflowError:
        return False


def _field(doc, key, kind, where, check=None):
    """``doc[key]`` of type ``kind`` (and passing ``check``), else a FormatError naming ``where`` and the field."""
    if key not in doc:
        raise FormatError(f"{where} is missing the field {key!r}")
    v = doc[key]
    if isinstance(v, bool) or not isinstance(v, kind) or (check is not None and not check(v)):
        raise FormatError(f"{where} field {key!r} has an invalid value {v!r}")
    return v


@dataclass
class CaptureFolder:
    """An opened capture folder (module docstring): the manifest and the frame table.

    Attributes
    ----------
    path : pathlib.Path
    manifest : dict
    bits : int
    n_cameras, n_leds, n_poses, n_exposures : int
    cameras : list of int
        Cameras with frames (manifest field ``cameras``, default all; a subset is
        allowed for target folders only).
    files : ndarray of object, shape (n_poses, n_cameras, n_leds, n_exposures)
        Relative file of each frame (None for cameras without frames).
    sha256 : ndarray of object, same shape
    exposure_s : ndarray, same shape
        Exposure times, s.
    """

    path: pathlib.Path
    manifest: dict
    bits: int
    n_cameras: int
    n_leds: int
    n_poses: int
    n_exposures: int
    cameras: list
    files: np.ndarray
    sha256: np.ndarray
    exposure_s: np.ndarray

    @property
    def kind(self) -> str:
        return self.manifest.get("kind", "face")

    def times(self, camera: int, led: int, pose: int = 0) -> np.ndarray:
        """Exposure times (E,) of one frame, s.

        Parameters
        ----------
        camera, led : int
            The camera and the LED of the frame.
        pose : int
            The target pose (0 for a face capture).

        Returns
        -------
        ndarray of float64, shape (E,)
            Field ``exposure_s`` of each exposure index, increasing (NaN for a camera without frames); a view of
            :attr:`exposure_s`.
        """
        return self.exposure_s[pose, camera, led]

    def inside(self, rel: str, what: str) -> pathlib.Path:
        """The path of the folder's file ``rel`` (a relative path without '..', :func:`relative_inside`), refused
        when it resolves out of the folder: a symbolic link (of the file, or of a folder on its way) to
        elsewhere would read a file the folder does not hold.

        Parameters
        ----------
        rel : str
            The file's name as the manifest lists it.
        what : str
            What the file is, for the message (e.g. ``"frame"``).

        Returns
        -------
        pathlib.Path
            ``path / rel``, unresolved.

        Raises
        ------
        FormatError
            ``rel`` resolves to a place outside the folder.
        """
        p = self.path / rel
        root = os.path.realpath(self.path)
        if os.path.commonpath([root, os.path.realpath(p)]) != root:
            raise FormatError(
                f"{what} {rel} listed in {MANIFEST} must lie inside {self.path}, got a symbolic link to "
                f"{os.path.realpath(p)}"
            )
        return p

    def read_codes(self, camera: int, led: int, exposure: int, pose: int = 0, size=None) -> np.ndarray:
        """The codes (H, W, 3) of one frame, after the checks of the module docstring.

        Parameters
        ----------
        camera, led : int
            The camera and the LED of the frame.
        exposure : int
            The exposure index, in [0, :attr:`n_exposures`).
        pose : int
            The target pose (0 for a face capture).
        size : sequence of int, optional
            The calibration's (width, height) of the camera, which the frame must match (default not checked).

        Returns
        -------
        ndarray of uint8 or uint16, shape (H, W, 3)
            The frame's codes, at most 2**bits − 1.

        Raises
        ------
        FormatError
            The camera has no frames in the folder (not in :attr:`cameras`), the frame lies outside the folder,
            cannot be read or decoded, its SHA-256 differs from the manifest's, it is not RGB, of another bit depth
            or size, or its EXIF ``ExposureTime`` differs from ``exposure_s`` by more than
            :data:`EXPOSURE_TOLERANCE` (relative).
        """
        # local import: keeps facestats.io (24 modules) out of this module's import
        from facestats.io.exif import parse_exif
        from facestats.io.images import decode_integer_image
        from facestats.io.layout import read_regular_file

        rel = self.files[pose, camera, led, exposure]
        if rel is None:
            raise FormatError(
                f"camera {camera} has no frames in {self.path} (field 'cameras' of {MANIFEST} lists {self.cameras})"
            )
        p = self.inside(rel, "frame")
        try:
            data = read_regular_file(p)  # a FIFO planted as a frame is refused, never read
        except OSError as exc:
            raise FormatError(f"frame {rel} listed in {MANIFEST} cannot be read: {exc.strerror}") from None
        digest = hashlib.sha256(data).hexdigest()
        if digest != self.sha256[pose, camera, led, exposure]:
            raise FormatError(
                f"frame {rel}: field 'sha256' of {MANIFEST} is {self.sha256[pose, camera, led, exposure]}, "
                f"the file's checksum is {digest} (corrupt or replaced file)"
            )
        try:
            codes, file_bits = decode_integer_image(data, str(rel))
        except Exception as exc:  # any decoding failure names the frame
            raise FormatError(f"frame {rel} cannot be decoded: {exc}") from None
        self._check_frame(rel, codes, file_bits, size)
        t_exif = parse_exif(data, str(rel)).get("ExposureTime")
        t = self.exposure_s[pose, camera, led, exposure]
        if t_exif is not None and abs(t_exif / t - 1) > EXPOSURE_TOLERANCE:
            raise FormatError(
                f"frame {rel}: EXIF ExposureTime {t_exif:.6g} s disagrees with field 'exposure_s' {t:.6g} s"
            )
        return codes

    def _check_frame(self, rel, codes, file_bits, size):
        """Raise unless a decoded frame is RGB, of the manifest's bit depth and the calibration's size."""
        if codes.shape[2] != 3:
            raise FormatError(f"frame {rel} must be an RGB image, got {codes.shape[2]} channel(s)")
        if file_bits < self.bits:
            raise FormatError(f"frame {rel} is a {file_bits}-bit file, field 'bits' of {MANIFEST} is {self.bits}")
        top = int(codes.max())
        if top > 2**self.bits - 1:
            raise FormatError(
                f"frame {rel} holds code {top}, above {2**self.bits - 1} of field 'bits' = {self.bits} of {MANIFEST} "
                "(wrong bit depth)"
            )
        if size is not None and (codes.shape[1], codes.shape[0]) != (int(size[0]), int(size[1])):
            raise FormatError(
                f"frame {rel} is {codes.shape[1]}×{codes.shape[0]} pixels, the calibration's image_width×image_height "
                f"is {int(size[0])}×{int(size[1])}"
            )

    def read_stack(self, camera: int, led: int, pose: int = 0, size=None):
        """``(codes of each exposure, exposure times)`` of one (pose, camera, LED).

        Parameters
        ----------
        camera, led : int
            The camera and the LED of the frames.
        pose : int
            The target pose (0 for a face capture).
        size : sequence of int, optional
            As :meth:`read_codes`.

        Returns
        -------
        codes : list of ndarray, each (H, W, 3)
            :meth:`read_codes` of each exposure index in order.
        times : ndarray of float64, shape (E,)
            :meth:`times`, s.

        Raises
        ------
        FormatError
            As :meth:`read_codes`.
        """
        return [self.read_codes(camera, led, e, pose, size) for e in range(self.n_exposures)], self.times(
            camera, led, pose
        )

    def subject(self) -> dict:
        """The subject metadata of a face capture (manifest field ``subject``), checked."""
        sub = self.manifest.get("subject")
        if not isinstance(sub, dict):
            raise FormatError(f"{MANIFEST} of a face capture needs the field 'subject' (an object), got {sub!r:.60}")
        missing = [k for k in SUBJECT_FIELDS if k not in sub]
        if missing:
            raise FormatError(f"{MANIFEST} field 'subject' is missing {missing}")
        try:
            check_subject_metadata(sub, f"{self.path / MANIFEST} field 'subject'")
        except SchemaError as exc:
            raise FormatError(str(exc)) from None
        return {k: sub[k] for k in SUBJECT_FIELDS}

    def sensor(self):
        """``(ContactSensor, profile, profile_std)`` of the manifest's ``sensor`` file (format ``SENSOR_FORMAT``).

        Returns
        -------
        sensor : ContactSensor
        profile, profile_std : ndarray, shape (site 3, fiber, channel 3)
            R(r) and its standard deviation, mm⁻², sites in :data:`~facestats.core.conventions.SITES` order. NaN in
            both (null in the file) where a fibre has no reading: its spot clipped in every exposure of the bracket.
            The dipole fit leaves those fibres out.

        Raises
        ------
        FormatError
            The file is missing, unreadable or malformed; a value is ±inf, a standard deviation negative, or null in
            only one of the two fields; or a site and channel has fewer than 3 readings (the fit's 2 parameters).
        """

        name = self.manifest.get("sensor")
        if not isinstance(name, str) or not relative_inside(name):
            raise FormatError(
                f"{MANIFEST} needs the field 'sensor' naming the contact-sensor file inside the folder (a relative "
                f"path without '..'), got {name!r:.60}"
            )
        label = f"sensor file {name} of {self.path}"
        _, sensor, prof, std = read_sensor_file(self.inside(name, "sensor file"), label)
        count = np.isfinite(prof).sum(axis=1)  # (site, channel): the dipole fit's 2 parameters need 3 readings
        if np.any(count < 3):
            s, c = (int(i) for i in np.argwhere(count < 3)[0])
            raise FormatError(
                f"{label} has {count[s, c]} readings for site {SITES[s]} channel {CHANNELS[c]} (the other fibres "
                "have none: clipped in every exposure); the dipole fit needs at least 3: take that site's bracket "
                "again with shorter exposures"
            )
        return sensor, prof, std

    def fingerprint(self) -> str:
        """SHA-256 of the manifest file (identifies the capture an ingest was made from)."""
        return hashlib.sha256((self.path / MANIFEST).read_bytes()).hexdigest()


def read_sensor_file(path, label=None):
    """The contact-sensor file ``path`` (format ``SENSOR_FORMAT``, :func:`write_sensor_file`), read and checked.

    A fibre whose spot clipped in every exposure of the bracket has no reading: :func:`merge_bracket
    <facestats.acquire.devices.sensor.merge_bracket>` gives NaN for it and for its standard deviation, written as
    null. Such readings are kept as NaN; the dipole fit leaves them out (:func:`facestats.model.fitting.
    fit_translucency`). A measured profile may dip below 0 by noise (dark-frame subtraction); its standard deviation
    may not.

    Parameters
    ----------
    path : str or path-like
        The file (read without blocking: a FIFO there is refused).
    label : str, optional
        Names the file in messages (default ``"sensor file <path>"``).

    Returns
    -------
    document : dict
        The whole JSON document (a device session's ``frames``, ``subject`` and ``fiber_layout`` too).
    sensor : ContactSensor
    profile, profile_std : ndarray, shape (site 3, fiber, channel 3)
        R(r) and its standard deviation, mm⁻², sites in :data:`~facestats.core.conventions.SITES` order; NaN in both
        where a fibre has no reading.

    Raises
    ------
    FormatError
        The file cannot be read or is not JSON of this format; ``sensor``, ``profile`` or ``profile_std`` is missing
        or malformed; a value is ±inf, a standard deviation negative, or null in only one of the two fields.
    """
    # local import: keeps facestats.io (24 modules) out of this module's import
    from facestats.io.layout import read_regular_file

    label = f"sensor file {path}" if label is None else label
    try:
        doc = json.loads(read_regular_file(path))
    except (OSError, ValueError, RecursionError) as exc:
        raise FormatError(f"{label} cannot be read: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != SENSOR_FORMAT:
        raise FormatError(f"{label} field 'format' must be {SENSOR_FORMAT!r}")
    try:
        sensor = ContactSensor.from_attrs(doc["sensor"])
        prof = np.asarray(doc["profile"], np.float64)
        std = np.asarray(doc["profile_std"], np.float64)
    except (KeyError, TypeError, ValueError, FormatError) as exc:  # FormatError: the sensor's, named here
        raise FormatError(f"{label} has a missing or malformed field: {exc}") from None
    if prof.shape != (len(SITES), sensor.n_fibers, 3) or std.shape != prof.shape:
        raise FormatError(
            f"{label} fields 'profile' and 'profile_std' must be (site {len(SITES)}, fiber {sensor.n_fibers}, "
            f"channel 3), got {prof.shape} and {std.shape}"
        )
    missing = np.isnan(prof)
    if not np.array_equal(missing, np.isnan(std)):
        at = tuple(int(i) for i in np.argwhere(missing != np.isnan(std))[0])
        raise FormatError(
            f"{label} fields 'profile' and 'profile_std' must both be null where a fibre has no reading, got "
            f"{prof[at]} and {std[at]} at (site, fiber, channel) {at}"
        )
    for field, a, low in (("profile", prof, -np.inf), ("profile_std", std, 0.0)):
        bad = (~np.isfinite(a) & ~missing) | (a < low)
        if bad.any():
            at = tuple(int(i) for i in np.argwhere(bad)[0])
            rule = "finite" if low == -np.inf else "finite and >= 0"
            raise FormatError(
                f"{label} field {field!r} must be {rule} (or null where a fibre has no reading), got {a[at]} at "
                f"(site, fiber, channel) {at}"
            )
    return doc, sensor, prof, std


def check_response(folder: "CaptureFolder", dome, calibration: str = "the calibration") -> None:
    """Raise unless ``dome`` has camera responses with one level per code of the folder's ``bits``.

    Parameters
    ----------
    folder : CaptureFolder
        The opened capture folder (:func:`open_folder`).
    dome : Dome
        The calibration whose ``camera_log_response`` merges the folder's frames.
    calibration : str
        Names the calibration in messages (its file when known).

    Raises
    ------
    FormatError
        ``dome`` has no ``camera_log_response``, or its number of levels is not 2**``folder.bits``.
    """
    if dome.camera_log_response is None:
        raise FormatError(
            f"{calibration} has no field 'camera_log_response' (the cameras' Debevec-Malik response g); "
            "recover it from a bracket with facestats.acquire.hdr.recover_response"
        )
    levels = dome.camera_log_response.shape[1]
    if levels != 2**folder.bits:
        raise FormatError(
            f"field 'camera_log_response' of {calibration} has {levels} levels, {folder.path / MANIFEST} field "
            f"'bits' is {folder.bits} ({2**folder.bits} levels)"
        )


def check_exposures(folder: "CaptureFolder", dome, calibration: str = "the calibration") -> None:
    """Raise unless every frame's ``exposure_s`` is the calibration's exposure time of its exposure index.

    The frames of exposure e were taken with the rig's exposure setting e, whose time is
    ``dome.exposure_times[e]`` (``exposure_times_s`` of the calibration file); they must agree within
    :data:`EXPOSURE_TOLERANCE` (relative), the tolerance ``facestats capture`` allows between the device's
    settings and the calibration.  This catches times written in another unit (milliseconds: a factor 1000 in
    every merged radiance) in frames without EXIF, and frames of another rig set-up.

    Parameters
    ----------
    folder : CaptureFolder
        The opened capture folder (:func:`open_folder`).
    dome : Dome
        The calibration whose ``exposure_times`` (s) the frames must match.
    calibration : str
        Names the calibration in messages (its file when known).

    Raises
    ------
    FormatError
        Naming the manifest (a number of exposures other than the calibration's), or the first disagreeing frame
        with its ``exposure_s`` and the calibration's time.
    """
    want = np.asarray(dome.exposure_times, np.float64)
    manifest = folder.path / MANIFEST
    if folder.n_exposures != want.size:
        raise FormatError(
            f"{manifest} frames have {folder.n_exposures} exposures (0..{folder.n_exposures - 1}), {calibration} "
            f"field 'exposure_times_s' has {want.size}: {[round(float(t), 6) for t in want]} s"
        )
    with np.errstate(invalid="ignore"):  # NaN: cameras without frames
        bad = np.abs(folder.exposure_s / want - 1) > EXPOSURE_TOLERANCE
    if np.any(bad):
        p, c, l, e = np.argwhere(bad)[0]
        raise FormatError(
            f"frame {folder.files[p, c, l, e]}: field 'exposure_s' {folder.exposure_s[p, c, l, e]:.6g} s of {MANIFEST} "
            f"differs by more than {EXPOSURE_TOLERANCE * 100:g} % from exposure {e} of {calibration} (field "
            f"'exposure_times_s': {want[e]:.6g} s); times must be in seconds, taken with the calibrated settings"
        )


def relative_inside(name: str) -> bool:
    """A relative path without ``..``: it names a file inside the folder, never one elsewhere.

    Parameters
    ----------
    name : str
        A file name from a manifest, read as a POSIX path.

    Returns
    -------
    bool
        False for an empty name, an absolute path, a name starting with ``~``, or one with a ``..`` component.
    """
    p = pathlib.PurePosixPath(name)
    return bool(name) and not p.is_absolute() and not name.startswith("~") and ".." not in p.parts


def _parse_frames(frames, n_cameras, n_leds):
    """Columns of the frame list (vectorised checks follow in :func:`_frame_table`)."""
    if not isinstance(frames, list) or not frames:
        raise FormatError(f"{MANIFEST} field 'frames' must be a non-empty list")
    cols = {k: [] for k in _FRAME_FIELDS + ("pose",)}
    for i, f in enumerate(frames):  # loop over manifest entries (metadata, not pixels)
        where = f"{MANIFEST} frames[{i}]"
        if not isinstance(f, dict):
            raise FormatError(f"{where} must be an object, got {f!r:.60}")
        cols["camera"].append(_field(f, "camera", int, where, lambda v: 0 <= v < n_cameras))
        cols["led"].append(_field(f, "led", int, where, lambda v: 0 <= v < n_leds))
        cols["exposure"].append(_field(f, "exposure", int, where, lambda v: v >= 0))
        cols["exposure_s"].append(_field(f, "exposure_s", (int, float), where, _positive_finite))
        name = _field(f, "file", str, where, relative_inside)
        cols["file"].append(name)
        cols["sha256"].append(_field(f, "sha256", str, where, lambda v: len(v) == 64))
        cols["pose"].append(_field(f, "pose", int, where, lambda v: v >= 0) if "pose" in f else 0)
    return {k: np.asarray(v, dtype=object if k in ("file", "sha256") else None) for k, v in cols.items()}


def _frame_table(path, cols, n_cameras, n_leds, cameras):
    """The (pose, camera, led, exposure) tables, checking completeness, duplicates and monotonic times."""
    n_poses = int(cols["pose"].max()) + 1
    n_exp = int(cols["exposure"].max()) + 1
    # Python ints (no overflow), before any table exists: an index far beyond the frames would allocate terabytes.
    # Up to twice the frames, the tables below name the first missing frame instead.
    needed = n_poses * len(cameras) * n_leds * n_exp
    if needed > 2 * len(cols["file"]):
        raise FormatError(
            f"{MANIFEST} lists {len(cols['file'])} frames, fewer than the {needed} that its fields ask for "
            f"({n_poses} pose(s) × {len(cameras)} camera(s) × {n_leds} LED(s) × {n_exp} exposure(s): "
            "check 'n_leds', 'cameras' and the frames' 'pose' and 'exposure' indices)"
        )
    shape = (n_poses, n_cameras, n_leds, n_exp)
    flat = np.ravel_multi_index((cols["pose"], cols["camera"], cols["led"], cols["exposure"]), shape)
    uniq, first, counts = np.unique(flat, return_index=True, return_counts=True)
    if np.any(counts > 1):
        dup = cols["file"][first[np.argmax(counts > 1)]]
        raise FormatError(f"{MANIFEST} lists the frame of {dup} twice (same pose, camera, LED and exposure)")
    expected = np.zeros(shape, bool)
    expected[:, cameras] = True
    if np.any(~np.isin(cols["camera"], cameras)):
        bad = cols["file"][np.argmax(~np.isin(cols["camera"], cameras))]
        raise FormatError(f"frame {bad} is of a camera not in {MANIFEST} field 'cameras' {cameras}")
    if uniq.size != expected.sum():
        missing = np.setdiff1d(np.flatnonzero(expected), uniq)[0]
        p, c, l, e = np.unravel_index(missing, shape)
        raise FormatError(
            f"{MANIFEST} lists no frame for pose {p}, camera {c}, LED {l}, exposure {e} "
            f"(every camera and LED needs exposures 0..{n_exp - 1})"
        )
    files = np.empty(shape, object)
    sha = np.empty(shape, object)
    times = np.empty(shape)
    idx = np.unravel_index(flat, shape)
    files[idx], sha[idx], times[idx] = cols["file"], cols["sha256"], cols["exposure_s"]
    if n_exp < 2:
        raise FormatError(f"{MANIFEST} frames have a single exposure: an HDR merge needs at least two")
    times[~expected] = np.nan
    with np.errstate(invalid="ignore"):
        bad = np.diff(times, axis=-1) <= 0
    if np.any(bad):
        p, c, l, e = np.argwhere(bad)[0]
        raise FormatError(
            f"frame {files[p, c, l, e + 1]}: field 'exposure_s' {times[p, c, l, e + 1]:.6g} s is not longer than "
            f"exposure {e}'s {times[p, c, l, e]:.6g} s (exposure times must increase with the exposure index)"
        )
    absent = [f for f in files[expected] if not (path / f).is_file()]
    if absent:
        more = f" ({len(absent)} frames missing)" if len(absent) > 1 else ""
        what = "is not a regular file in" if os.path.lexists(path / absent[0]) else "is missing from"
        raise FormatError(f"frame {absent[0]} listed in {MANIFEST} {what} {path}{more}")
    return n_poses, n_exp, files, sha, times


def open_folder(path) -> CaptureFolder:
    """Open and check a capture folder (module docstring); raises :class:`FormatError` on any violation.

    Parameters
    ----------
    path : str or path-like
        The folder holding ``manifest.json`` and the frames it lists.

    Returns
    -------
    CaptureFolder
        The manifest and its frame tables; no frame is decoded or hashed here.

    Raises
    ------
    FormatError
        No readable ``manifest.json``, invalid JSON, or any rule of the module docstring broken (the message
        names the file, the field and the value).
    """
    # local import: keeps facestats.io (24 modules) out of this module's import
    from facestats.io.layout import read_regular_file

    p = pathlib.Path(os.fspath(path))
    try:
        doc = json.loads(read_regular_file(p / MANIFEST))  # a FIFO is refused, never read
    except OSError as exc:
        raise FormatError(f"capture folder {p} has no readable {MANIFEST}: {exc.strerror}") from None
    except (ValueError, RecursionError) as exc:  # bad JSON or UTF-8, an int of > 4300 digits, nesting too deep
        raise FormatError(f"{p / MANIFEST} is not valid JSON: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        got = doc.get("format") if isinstance(doc, dict) else doc
        raise FormatError(f"{MANIFEST} field 'format' must be {FORMAT!r}, got {got!r:.60}")
    bits = _field(doc, "bits", int, MANIFEST, lambda v: 8 <= v <= 16)
    n_cam = _field(doc, "n_cameras", int, MANIFEST, lambda v: v >= 1)
    if n_cam > MAX_CAMERAS:  # the frame tables hold every camera: a few bytes of JSON must not ask for gigabytes
        raise FormatError(f"{MANIFEST} field 'n_cameras' must be at most {MAX_CAMERAS}, got {n_cam}")
    n_led = _field(doc, "n_leds", int, MANIFEST, lambda v: v >= 1)
    cameras = _cameras(doc, n_cam)
    cols = _parse_frames(doc.get("frames"), n_cam, n_led)
    n_poses, n_exp, files, sha, times = _frame_table(p, cols, n_cam, n_led, cameras)
    if n_poses > 1 and doc.get("kind", "face") != "target":  # an ingest reads pose 0: the rest would be ignored
        raise FormatError(
            f"{MANIFEST} frames of a face capture must all be pose 0 (poses are for LED calibration targets, "
            f"'kind': 'target'), got poses 0..{n_poses - 1}"
        )
    return CaptureFolder(p, doc, bits, n_cam, n_led, n_poses, n_exp, cameras, files, sha, times)


def _cameras(doc, n_cam) -> list:
    """The manifest's field ``cameras``, sorted: distinct indices in [0, n_cam), every camera unless a target."""
    cameras = doc.get("cameras", list(range(n_cam)))
    if (
        not isinstance(cameras, list)
        or not cameras
        or any(isinstance(c, bool) or not isinstance(c, int) or not 0 <= c < n_cam for c in cameras)
    ):
        raise FormatError(f"{MANIFEST} field 'cameras' must list camera indices in [0, {n_cam}), got {cameras!r:.60}")
    seen = set()
    twice = [c for c in cameras if c in seen or seen.add(c)]
    if twice:
        raise FormatError(f"{MANIFEST} field 'cameras' must list each camera once, got camera {twice[0]} twice")
    if len(seen) < n_cam and doc.get("kind", "face") != "target":
        absent = sorted(set(range(n_cam)) - seen)
        raise FormatError(
            f"{MANIFEST} field 'cameras' must list every camera 0..{n_cam - 1} (a subset for targets only), "
            f"got {len(seen)} without {absent[:5]}"
        )
    return sorted(seen)


def prefetch(fn, items, workers: int):
    """``fn(item)`` for each item in order on ``workers`` threads, at most ``workers + 1`` ahead (bounded memory).

    Frames are decoded and hashed this way: both release the GIL.

    Parameters
    ----------
    fn : callable
        Called once per item.
    items : iterable
        The items (read into a list first when ``workers`` > 1).
    workers : int
        Threads; 1 or fewer calls ``fn`` in the caller's thread, lazily.

    Yields
    ------
    object
        ``fn(item)`` in the order of ``items``; an exception of ``fn`` is raised when its result is reached.
    """
    if workers <= 1:
        yield from map(fn, items)
        return
    items = list(items)
    with ThreadPoolExecutor(workers) as ex:
        pending = [ex.submit(fn, it) for it in items[: workers + 1]]
        for k in range(len(items)):
            result = pending[k].result()
            pending[k] = None
            if k + workers + 1 < len(items):
                pending.append(ex.submit(fn, items[k + workers + 1]))
            yield result


# -- HDR samples at sub-pixel positions ----------------------------------------------------------------
def bilinear_taps(pixels, size):
    """Four neighbouring pixels and bilinear weights of sub-pixel positions (pixel centres at integers).

    Parameters
    ----------
    pixels : ndarray, shape (N, 2)
        (u, v) positions inside the image.
    size : (int, int)
        Image width and height.

    Returns
    -------
    index : ndarray of int64, shape (N, 4)
        Flat pixel indices (row-major), clamped to the image: within half a pixel of an edge (the image spans
        [−1/2, W − 1/2)) both taps across it are the edge pixel, so the value is the edge pixel's (clamp to edge).
    weight : ndarray of float32, shape (N, 4)
        Bilinear weights, summing to 1.
    """
    w, h = int(size[0]), int(size[1])
    u, v = np.asarray(pixels, np.float64)[:, 0], np.asarray(pixels, np.float64)[:, 1]
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = u - u0, v - v0
    # Each tap clamped on its own: x1 from u0 + 1, not from the clamped x0 (for u in [−1/2, 0) that read pixel 1).
    x0 = np.clip(u0.astype(np.int64), 0, w - 1)
    x1 = np.clip(u0.astype(np.int64) + 1, 0, w - 1)
    y0 = np.clip(v0.astype(np.int64), 0, h - 1)
    y1 = np.clip(v0.astype(np.int64) + 1, 0, h - 1)
    index = np.stack([y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1], -1)
    weight = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], -1).astype(np.float32)
    return index, weight


def _gather(stack, index):
    """Codes of each exposure at flat pixel ``index`` (N, 4): list of (N, 4, 3) arrays."""
    return [img.reshape(-1, img.shape[-1])[index] for img in stack]


def merge_at(
    stack,
    times,
    response,
    index,
    weight,
    weighting: str = "hat_time",
    black_level: int = 0,
    white_level: int | None = None,
    measured_only: bool = False,
) -> np.ndarray:
    """HDR radiance (N, 3) of a frame at the taps of :func:`bilinear_taps` (NaN if a tap is saturated).

    Debevec & Malik 1997 eq. 6 at each of the four pixels
    (:func:`facestats.acquire.response.merge_photographs`, by default with the
    shot-noise weights w(z)·Δt, zero at and below ``black_level`` and at and above ``white_level``, both in DN:
    Z_min and Z_max of eq. 4; ``white_level`` None is the top code), then bilinear interpolation.  A tap dark in
    every exposure takes the longest exposure's floor, an upper bound of its radiance; ``measured_only`` makes it
    NaN too (for a fit, where such bounds taken as data bias the result upwards).

    Parameters
    ----------
    stack : sequence of ndarray of int, each (H, W, 3)
        The frame's codes per exposure.
    times : array_like, shape (P,)
        Exposure times in seconds.
    response : ndarray, shape (levels, 3)
        g = ln f⁻¹ per channel.
    index, weight : ndarray, shape (N, 4)
        Flat pixel indices and bilinear weights from :func:`bilinear_taps`.
    weighting : {"hat_time", "hat"}
        As :func:`facestats.acquire.response.merge_photographs`.
    black_level : int
        Pedestal in DN (Z_min).
    white_level : int, optional
        Clipping code in DN (Z_max); None: the top code.
    measured_only : bool
        NaN instead of the floor where a tap is dark in every exposure.

    Returns
    -------
    ndarray, shape (N, 3)
        Radiance in the units of exp(g)/s (float32 with :func:`bilinear_taps`'s weights).
    """
    taps = _gather(stack, index)
    e, den = merge_photographs(
        taps, times, response, weighting=weighting, return_weight=True, black_level=black_level,
        white_level=white_level,
    )  # fmt: skip  # (N, 4, 3)
    if measured_only:
        e[den == 0] = np.nan
    return np.einsum("nk,nkc->nc", weight, e)


def exposure_consistency(
    stack,
    times,
    response,
    box,
    *,
    min_weight: float = 0.2,
    jump: float = 0.5,
    black_level: int = 0,
    white_level: int | None = None,
    clip_radius: int = 4,
):
    """How often a frame's shortest and longest exposures disagree inside ``box``: the head-motion statistic.

    For each pixel and channel of ``box`` well exposed (hat weight ≥ ``min_weight``
    of its peak) in both exposures, d = (g(Z_long) − ln Δt_long) − (g(Z_short) −
    ln Δt_short) is the log ratio of the two radiance estimates (Debevec & Malik
    1997 eq. 2 per exposure).  Noise keeps |d| at a few hundredths; a head that
    moved between the two passes (Weyrich et al. 2006 §5: the exposures are two
    passes through the light sequence) puts shadow, highlight and texture edges in
    different places, where |d| is of order one.  ``min_weight`` 0.2 keeps the
    darkest and brightest fifth of the codes out, where quantisation and JPEG
    ringing alone can reach |d| > ``jump``.

    Pixels within ``clip_radius`` pixels (a square window) of a pixel clipped in
    either exposure (a code at or above the white level in any channel) are not
    compared: around a clipped highlight a camera's own processing is not a function
    of the code — JPEG's 8 × 8 blocks ring, sharpening leaves halos, the sensor blooms
    — and the clipped area grows with the exposure, so the two exposures disagree
    there in a still scene.  On a real still bracket (colour-hdri's ``frobisher_001``,
    Canon JPEGs on a tripod, the 1 s and 8 s frames, whole frame) 0.48 % of the
    samples disagreed, along the edges of the clipped window, colour checker and a red
    strap, above the ingest's 0.1 % threshold; 0.14 % with a radius of 2 pixels,
    0.0016 % with 4 (``tests/acquire/test_motion.py``).

    Parameters
    ----------
    stack : sequence of ndarray of int, shape (H, W, 3)
        One frame's codes per exposure.
    times : ndarray, shape (P,)
        Exposure times of ``stack``, s (any order: the shortest and the longest are compared).
    response : ndarray, shape (levels, 3)
        g(Z) = ln exposure per code and channel (Debevec & Malik 1997 eq. 2).
    box : (x0, y0, x1, y1)
        Pixel bounds (end exclusive) of the face in the frame.
    min_weight : float
        Hat weight, relative to its peak, a code needs in both exposures to be compared.
    jump : float
        |d| counted as a disagreement, ln units (0.5: a factor e^0.5 ≈ 1.65).
    black_level : int
        The sensor's pedestal in DN: Z_min of the hat weights
        (:func:`facestats.acquire.response.hat_weights`).
    white_level : int, optional
        The code in DN at and above which the sensor clips: Z_max of the hat weights (Debevec & Malik
        1997 eq. 4); default None, the top code.
    clip_radius : int
        Pixels around a clipped pixel left out (≥ 0; 0 compares every well-exposed pixel).

    Returns
    -------
    score : float
        Fraction of the usable samples with |d| > ``jump`` (NaN without usable samples).
    n : int
        Number of usable samples.
    """
    if isinstance(clip_radius, bool) or not isinstance(clip_radius, (int, np.integer)) or clip_radius < 0:
        raise ValidationError(f"clip_radius must be a whole number of pixels >= 0, got {clip_radius!r}")
    g = np.asarray(response, np.float64)
    levels = g.shape[0]
    w = hat_weights(levels, black_level, white_level)
    w = w / w.max()
    order = np.argsort(times)
    x0, y0, x1, y1 = (int(v) for v in box)
    zs, zl = (stack[k][y0:y1, x0:x1] for k in (order[0], order[-1]))
    ok = (w[zs] >= min_weight) & (w[zl] >= min_weight)
    if clip_radius > 0 and ok.any():  # clipped pixels up to clip_radius outside the box count too
        top = levels - 1 if white_level is None else int(white_level)
        r = int(clip_radius)
        bx0, by0 = max(x0 - r, 0), max(y0 - r, 0)
        near = [np.any(stack[k][by0 : y1 + r, bx0 : x1 + r] >= top, axis=-1) for k in (order[0], order[-1])]
        near = ndimage.maximum_filter(near[0] | near[1], size=2 * r + 1, mode="constant", cval=False)
        ok &= ~near[y0 - by0 : y0 - by0 + ok.shape[0], x0 - bx0 : x0 - bx0 + ok.shape[1], None]
    ch = np.arange(zs.shape[-1])
    d = np.abs((g[zl, ch] - np.log(times[order[-1]])) - (g[zs, ch] - np.log(times[order[0]])))[ok]
    return (float(np.mean(d > jump)) if d.size else float("nan")), int(d.size)
