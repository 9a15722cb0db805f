"""A camera's response from a bracket of photographs on disk: read, recover, check, save.

The lab's first calibration step (Weyrich et al. 2006 §5 calibrate the cameras
before the lights): photograph a static scene with a wide range of brightness at
several exposure times (a tripod, fixed aperture, focus and white balance), then

    facestats calibrate response IMG_1.jpg IMG_2.jpg IMG_3.jpg --output response.json
    facestats calibrate merge IMG_1.jpg IMG_2.jpg IMG_3.jpg --response response.json --out scene.exr

:func:`read_bracket` reads the frames (8-bit JPEG/PNG, 16-bit PNG/TIFF through
:func:`facestats.io.images.read_integer_image`) and their exposure times (EXIF
``ExposureTime`` through :func:`facestats.io.exif.read_exposure_time`, or given);
:func:`calibrate_response` recovers Debevec & Malik's g
(:func:`facestats.acquire.response.recover_response`) and scores it with
:func:`facestats.acquire.response.exposure_agreement`; :class:`ResponseCalibration`
saves it as JSON (``facestats.camera-response/1``) and puts it into a dome
calibration (:meth:`ResponseCalibration.apply`, the ``camera_log_response`` of
:class:`facestats.acquire.dome.Dome`); :func:`merge_bracket` merges a bracket
into one radiance image with a saved response.

**Exposure ratios.** Debevec & Malik's g is determined only up to what the
bracket can tell apart: with two exposures, or with one constant ratio between
consecutive exposures, a perturbation of g that repeats with that ratio in
exposure cannot be seen (Grossberg & Nayar 2003, *Determining the camera response
from images: what is knowable?*, §3); the smoothness term then decides it. Use
three or more exposures, and unequal steps where the camera allows.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace

import numpy as np

from facestats.acquire.response import (
    check_rising,
    check_white_level,
    exposure_agreement,
    merge_photographs,
    recover_response,
)
from facestats.core.validate import check_integer
from facestats.errors import FormatError, ValidationError

__all__ = [
    "RESPONSE_FORMAT",
    "SATURATED_FILLS",
    "ResponseCalibration",
    "read_bracket",
    "calibrate_response",
    "read_response",
    "merge_bracket",
    "MergedBracket",
    "agreement_warnings",
]

RESPONSE_FORMAT = "facestats.camera-response/1"
#: Median disagreement of two consecutive exposures above which :meth:`ResponseCalibration.warnings` warns (noise
#: and compression leave 3-4 % for 8-bit JPEGs, ``docs/photographs.md``).
AGREEMENT_LIMIT = 0.10


def read_bracket(paths, exposure_times=None):
    """Frames and exposure times of a bracket of photographs.

    Parameters
    ----------
    paths : sequence of str or path-like
        At least two image files of one static scene, any order.
    exposure_times : sequence of float, optional
        Seconds, one per file; default each file's EXIF ``ExposureTime``.

    Returns
    -------
    images : list of ndarray of uint8 or uint16, each (H, W, 3)
    times : ndarray of float64, shape (P,)
    bits : int
        8 for 8-bit files, 16 for 16-bit ones (pass ``bits`` to :func:`calibrate_response`
        for 12-bit codes in 16-bit files).

    Raises
    ------
    FormatError
        A file without EXIF exposure time when none is given (named), frames whose EXIF
        records another aperture, ISO or camera when no times are given (the exposure would not
        be the time alone), frames of different sizes or bit depths, or not RGB.
    ValidationError
        Fewer than two files, or a count of ``exposure_times`` different from the files.
    """
    from facestats.io.exif import read_exif
    from facestats.io.images import read_integer_image

    files = [os.fspath(p) for p in paths]
    if len(files) < 2:
        raise ValidationError(f"a bracket needs at least two photographs, got {len(files)}")
    for f in files:  # stat only: a FIFO or a device is refused without blocking on a read
        if not os.path.isfile(f):
            raise FormatError(f"{f!r} is not a photograph: no such regular file")
    if exposure_times is not None:
        times = np.asarray(exposure_times, np.float64).reshape(-1)
        if times.size != len(files):
            raise ValidationError(
                f"exposure_times must hold one time per photograph ({len(files)}), got {times.size}: {times.tolist()}"
            )
    else:
        tags = [read_exif(f) for f in files]
        missing = [f for f, t in zip(files, tags) if t.get("ExposureTime") is None]
        if missing:
            raise FormatError(
                f"no EXIF ExposureTime in {', '.join(missing)}: give the exposure times (seconds) of every file"
            )
        _check_only_time_varies(files, tags)
        times = np.asarray([float(t["ExposureTime"]) for t in tags], np.float64)
    images, depths = [], []
    for f in files:  # loop over a handful of files
        img, bits = read_integer_image(f)
        if img.ndim != 3 or img.shape[-1] < 3:
            raise FormatError(f"{f} must be an RGB photograph, got shape {img.shape}")
        images.append(np.ascontiguousarray(img[..., :3]))
        depths.append(bits)
    shapes = {i.shape for i in images}
    if len(shapes) != 1 or len(set(depths)) != 1:
        table = ", ".join(f"{f}: {i.shape[1]}×{i.shape[0]}, {b}-bit" for f, i, b in zip(files, images, depths))
        raise FormatError(f"the photographs of a bracket must share size and bit depth, got {table}")
    return images, times, 8 if depths[0] == 8 else 16


#: EXIF tags a bracket must hold constant: the exposure is then the time alone (Debevec & Malik 1997 §2.1).
_FIXED_TAGS = {"FNumber": "aperture (FNumber)", "ISOSpeedRatings": "ISO (ISOSpeedRatings)", "Make": "camera (Make)",
               "Model": "camera (Model)"}  # fmt: skip


def _check_only_time_varies(files, tags) -> None:
    """Refuse a bracket whose EXIF records another aperture, ISO or camera in some frames (times from EXIF).

    Exposure is t·ISO/N²: a bracket that varies ISO with the time read as if only the time changed gives a g
    scaled by the wrong ratios (ISO doubled with each doubled time: g half the truth, with a perfect exposure
    agreement).  Tags a file does not record are not compared.
    """
    for tag, what in _FIXED_TAGS.items():
        seen = {f: t[tag] for f, t in zip(files, tags) if t.get(tag) not in (None, "")}
        if len({str(v) for v in seen.values()}) > 1:
            table = ", ".join(f"{os.path.basename(f)}: {v}" for f, v in seen.items())
            raise FormatError(
                f"a bracket must vary only the exposure time, got another {what} across the photographs ({table}): "
                "reshoot with it fixed, or give --times with each frame's relative exposure t·ISO/N² (exposure_times "
                "in Python), which are then not checked against EXIF"
            )


@dataclass
class ResponseCalibration:
    """Result of :func:`calibrate_response`.

    Attributes
    ----------
    log_response : ndarray, shape (2**bits, 3)
        g(z) in natural-log exposure, g(2**bits / 2) = 0 (:func:`recover_response`).
    bits : int
    exposure_times : ndarray, shape (P,)
        Seconds, in the order of ``files``.
    agreement : ndarray, shape (P − 1, 2)
        Median and 90th percentile of the consecutive exposures' disagreement
        (:func:`exposure_agreement`), in order of exposure time.
    files : list of str
    settings : dict
        ``smoothness`` and ``samples`` as passed (None: the defaults).
    black_level : int
        The sensor's pedestal in DN g was recovered with (:mod:`facestats.acquire.response`); merges of
        photographs with this g use the same (:meth:`apply` records it in a dome calibration).
    white_level : int or None
        The code in DN at and above which the sensor clips, the Z_max of Debevec & Malik 1997 eq. 4 that g was
        recovered with (None: the top code 2**bits − 1); merges use the same (:meth:`apply` records it).
    """

    log_response: np.ndarray
    bits: int
    exposure_times: np.ndarray
    agreement: np.ndarray
    files: list = field(default_factory=list)
    settings: dict = field(default_factory=dict)
    black_level: int = 0
    white_level: int | None = None

    def to_dict(self) -> dict:
        """JSON-ready: format, bits, black and white levels (null: the top code), files with their times, agreement,
        settings and g per channel."""
        g = np.asarray(self.log_response, np.float64)
        return {
            "format": RESPONSE_FORMAT,
            "bits": int(self.bits),
            "black_level": int(self.black_level),
            "white_level": None if self.white_level is None else int(self.white_level),
            "frames": [{"file": f, "exposure_time_s": float(t)} for f, t in zip(self.files, self.exposure_times)],
            "exposure_agreement": [
                {"median": _num(m), "p90": _num(p)} for m, p in np.asarray(self.agreement, np.float64)
            ],
            "settings": dict(self.settings),
            # code 0 has no weight and g(0) may be -inf: stored as null
            "log_response": [[_num(v) for v in g[:, c]] for c in range(g.shape[1])],
        }

    def save(self, path) -> None:
        """Write :meth:`to_dict` as JSON (``facestats.camera-response/1``).

        Parameters
        ----------
        path : str or path-like
            The file to write (replaced if it exists); :func:`read_response` and :func:`merge_bracket` read it.
        """
        with open(path, "w", encoding="utf-8") as f:
            json.dump(self.to_dict(), f, indent=1, allow_nan=False)
            f.write("\n")

    def warnings(self) -> list:
        """What makes this response doubtful, one sentence each (:func:`agreement_warnings`)."""
        return agreement_warnings(self.agreement, self.exposure_times)

    def to_text(self) -> str:
        """The frames, the consecutive exposures' agreement and g at a few codes."""
        order = np.argsort(self.exposure_times, kind="stable")
        pedestal = f", black level {self.black_level}" if self.black_level else ""
        clip = f", white level {self.white_level}" if self.white_level is not None else ""
        lines = [f"{len(self.files)} photographs, {self.bits}-bit codes{pedestal}{clip}:"]
        lines += [f"  {self.files[k]}  {_seconds(self.exposure_times[k])}" for k in order]
        lines.append("exposure agreement (|E_j/E_k - 1| over samples well exposed in both): median, 90th percentile")
        for (m, p), a, b in zip(self.agreement, order[:-1], order[1:]):
            pair = f"{_seconds(self.exposure_times[a])} -> {_seconds(self.exposure_times[b])}"
            lines.append(f"  {pair}: " + ("no common well-exposed samples" if np.isnan(m) else f"{m:.2%}, {p:.2%}"))
        levels = self.log_response.shape[0]
        codes = [levels // 16, levels // 4, levels // 2, 3 * levels // 4, levels - 1 - levels // 16]
        lines.append(
            "g(z) = ln exposure (R G B): "
            + "; ".join(f"z={z}: " + " ".join(f"{v:+.3f}" for v in self.log_response[z]) for z in codes)
        )
        return "\n".join(lines)

    def apply(self, dome, cameras=None):
        """``dome`` with this response as the ``camera_log_response`` of ``cameras`` (default every camera).

        A dome without responses takes this one for every camera; then ``cameras``
        must be every camera (the others would have none).  The dome takes :attr:`black_level`
        as its ``camera_black_level`` and :attr:`white_level` as its ``camera_white_level`` (one
        each for all cameras: applying to some cameras of a dome whose black or white level differs
        is refused; a white level of None and one at the top code are the same), which the ingest
        and the LED calibration then merge with.

        Parameters
        ----------
        dome : Dome
            The calibration to update (:class:`facestats.acquire.dome.Dome`); it is not modified.
        cameras : sequence of int, optional
            Indices of the cameras that take this response, in [0, ``dome.n_cameras``); default every camera.

        Returns
        -------
        Dome
            A copy of ``dome`` with ``camera_log_response`` (C, 2**bits, 3), ``camera_black_level`` and
            ``camera_white_level`` set; g's non-finite values (code 0, −inf) are replaced by g(1).

        Raises
        ------
        ValidationError
            A camera index out of range; some cameras only when the dome has no responses yet; a response of
            another number of levels than the dome's; some cameras only with a black or white level other than
            the dome's.
        """
        g = np.where(np.isfinite(self.log_response), self.log_response, self.log_response[1])  # code 0: weight 0
        n_cam = dome.n_cameras
        sel = list(range(n_cam)) if cameras is None else [int(c) for c in cameras]
        bad = [c for c in sel if not 0 <= c < n_cam]
        if bad:
            raise ValidationError(f"cameras must be in [0, {n_cam}), got {bad}")
        current = dome.camera_log_response
        if current is None:
            if sorted(set(sel)) != list(range(n_cam)):
                raise ValidationError(
                    f"the calibration has no camera responses yet: give every camera (0-{n_cam - 1}), got {sel}"
                )
            out = np.repeat(g[None], n_cam, axis=0)
        else:
            if current.shape[1] != g.shape[0]:
                raise ValidationError(
                    f"the calibration's responses have {current.shape[1]} levels, this one {g.shape[0]} "
                    f"({self.bits}-bit): pass bits to match the cameras"
                )
            if sorted(set(sel)) != list(range(n_cam)) and dome.camera_black_level != self.black_level:
                raise ValidationError(
                    f"black_level must be the calibration's camera_black_level ({dome.camera_black_level}) when only "
                    f"cameras {sel} take this response (the cameras share one), got {self.black_level}"
                )
            levels = g.shape[0]
            mine = check_white_level(self.white_level, levels, self.black_level)
            theirs = check_white_level(dome.camera_white_level, levels, dome.camera_black_level)
            if sorted(set(sel)) != list(range(n_cam)) and theirs != mine:
                have, got = _white(dome.camera_white_level, levels), _white(self.white_level, levels)
                raise ValidationError(
                    f"white_level must be the calibration's camera_white_level ({have}) when only cameras {sel} take "
                    f"this response (the cameras share one), got {got}"
                )
            out = np.array(current, np.float64)
            out[sel] = g
        white = None if self.white_level is None else int(self.white_level)
        return replace(
            dome, camera_log_response=out, camera_black_level=int(self.black_level), camera_white_level=white
        )


def _white(white_level, levels: int) -> str:
    """A white level (DN) for messages: None is the top code."""
    return f"None: the top code {levels - 1}" if white_level is None else str(int(white_level))


def _num(x):
    x = float(x)
    return x if np.isfinite(x) else None


def _samples_setting(samples):
    """``samples`` as recorded in the file: None, a choice, a count, or "indices" for an explicit array."""
    if samples is None or isinstance(samples, (str, int, np.integer)):
        return samples if not isinstance(samples, np.integer) else int(samples)
    return "indices"


def _seconds(t: float) -> str:
    return f"1/{1 / t:.4g} s" if t < 1 else f"{t:.4g} s"


def calibrate_response(
    paths, exposure_times=None, *, bits=None, smoothness=None, samples=None, black_level=0, white_level=None
):
    """Debevec & Malik's response g from a bracket of photographs on disk (module docstring).

    Parameters
    ----------
    paths, exposure_times
        As :func:`read_bracket`.
    bits : int, optional
        Bit depth of the codes (default 8 or 16 from the files; 12 for 12-bit codes in 16-bit files).
    smoothness, samples, black_level, white_level
        As :func:`facestats.acquire.response.recover_response` (``black_level`` and ``white_level``, in DN, the
        Z_min and Z_max of Debevec & Malik 1997 eq. 4, also score the agreement; ``white_level`` None: the top
        code).

    Returns
    -------
    ResponseCalibration
    """
    images, times, file_bits = read_bracket(paths, exposure_times)
    if bits is not None and check_integer(bits, "bits", 1) > file_bits:
        raise ValidationError(f"bits must be at most {file_bits} for these {file_bits}-bit files, got {bits}")
    bits = file_bits if bits is None else bits
    g = recover_response(
        images,
        times,
        smoothness=smoothness,
        samples=samples,
        bits=bits,
        black_level=black_level,
        white_level=white_level,
    )
    return ResponseCalibration(
        log_response=g,
        bits=int(bits),
        exposure_times=times,
        agreement=exposure_agreement(images, times, g, black_level=black_level, white_level=white_level),
        files=[os.fspath(p) for p in paths],
        settings={"smoothness": smoothness, "samples": _samples_setting(samples)},
        black_level=int(black_level),
        white_level=None if white_level is None else int(white_level),
    )


def read_response(path) -> np.ndarray:
    """g (levels, 3) of a ``facestats.camera-response/1`` file (code 0, stored as null, is −inf).

    Parameters
    ----------
    path : str or path-like
        A response file as :meth:`ResponseCalibration.save` writes it.

    Returns
    -------
    ndarray of float64, shape (levels, 3)
        g = ln f⁻¹ per code and channel; levels is a power of 2, code 0 may be −inf.

    Raises
    ------
    FormatError
        The file cannot be read or is not JSON, its ``format`` is not ``facestats.camera-response/1``, its
        ``log_response`` is missing, not 3 channels of 2**bits values or not finite above code 0, or its
        ``bits`` disagrees with the number of levels.
    """
    return _response_file(path)[0]


def _response_file(path):
    """(g, the file's JSON document) of a response file (:func:`read_response`), read once."""
    from facestats.io.layout import read_regular_file

    p = os.fspath(path)
    try:
        d = json.loads(read_regular_file(p))  # a FIFO or a device is refused, never read
    except (OSError, ValueError, RecursionError) as exc:  # (RecursionError: nesting deeper than Python's limit)
        raise FormatError(f"cannot read the response file {p}: {exc}") from None
    if not isinstance(d, dict) or d.get("format") != RESPONSE_FORMAT:
        got = d.get("format") if isinstance(d, dict) else type(d).__name__
        raise FormatError(f"{p} field 'format' must be {RESPONSE_FORMAT!r}, got {got!r}")
    try:
        g = np.array([[np.nan if v is None else float(v) for v in ch] for ch in d["log_response"]], np.float64).T
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"{p} field 'log_response' is missing or malformed ({exc!r})") from None
    levels = g.shape[0]
    if g.ndim != 2 or g.shape[1] != 3 or levels < 2 or levels & (levels - 1) or not np.all(np.isfinite(g[1:])):
        raise FormatError(f"{p} field 'log_response' must be 3 channels of 2**bits finite values, got shape {g.shape}")
    g[0] = np.where(np.isfinite(g[0]), g[0], -np.inf)  # code 0 (weight 0) may be stored as null
    bits = d.get("bits")
    if bits is not None and (isinstance(bits, bool) or not isinstance(bits, int) or not 1 <= bits <= 16
                             or 1 << bits != levels):  # fmt: skip
        raise FormatError(
            f"{p} field 'bits' is {bits!r}, but its 'log_response' has {levels} levels ({levels.bit_length() - 1} bits)"
        )
    return g, d


def agreement_warnings(agreement, exposure_times) -> list:
    """One sentence per pair of consecutive exposures whose median disagreement exceeds :data:`AGREEMENT_LIMIT`:
    their times do not match the frames, or the scene changed between them.

    Parameters
    ----------
    agreement : array_like, shape (P − 1, 2)
        Median and 90th percentile per consecutive pair in order of time, as
        :func:`facestats.acquire.response.exposure_agreement` gives it; NaN medians are skipped.
    exposure_times : array_like, shape (P,)
        The bracket's exposure times in seconds, any order (sorted here to name each pair).

    Returns
    -------
    list of str
        One warning per disagreeing pair; empty when all agree.
    """
    times = np.asarray(exposure_times, np.float64)
    order = np.argsort(times, kind="stable")
    out = []
    for (m, _), a, b in zip(np.asarray(agreement, np.float64), order[:-1], order[1:]):
        if np.isfinite(m) and m > AGREEMENT_LIMIT:
            out.append(
                f"exposures {_seconds(times[a])} -> {_seconds(times[b])} disagree by a median {m:.1%} (over "
                f"{AGREEMENT_LIMIT:.0%}; noise and compression leave a few per cent): their times do not match the "
                "frames, or the scene, its light or the camera changed between them"
            )
    return out


#: How :func:`merge_bracket` fills a pixel saturated in every exposure (no radiance is measured there).
SATURATED_FILLS = ("clip", "zero")
#: Lost samples :func:`_fill_lost` bounds at once (about 60 bytes each).
FILL_CHUNK = 1 << 20


@dataclass
class _Lost:
    """The samples (pixel, channel) the merge could not measure, sorted out by :func:`_fill_lost`."""

    radiance: np.ndarray
    clipped_pixels: int
    gap_pixels: int
    gap_times: tuple  # (longest exposure that saw them dark, shortest that clipped them), s: the commonest pair


def _fill_lost(radiance, images, times, g, black, white, saturated):
    """Fill, in place, the samples ``merge_photographs`` left NaN: no exposure saw them with a usable code.

    Each exposure j saw such a sample dark (code ≤ black level B) or clipped (code ≥ white level W), where the
    weights of Debevec & Malik 1997 eq. 4 vanish.  Eq. 2 at those codes bounds its radiance: E ≥ exp(g(W))/Δt_j
    for an exposure that clipped it, E ≤ exp(g(B + 1))/Δt_j for one that saw it dark (units exp(g)/s).

    * Clipped in the shortest exposure (saturated in every exposure, in a consistent bracket): only the lower
      bound exp(g(W))/Δt_min is known.  It is at least every measured radiance of the channel (a measured code
      z < W in an exposure of Δt ≥ Δt_min gives exp(g(z))/Δt below it), so ``saturated="clip"`` gives the sample
      that bound: a clipped highlight stays the brightest; ``"zero"`` gives it 0.
    * Dark in the exposures up to one time and clipped from a longer one on (a gap in the bracket): the tightest
      bounds are the shortest clipping and the longest dark exposure's; the sample gets their geometric mean,
      which is within the square root of their ratio of the truth, whatever ``saturated`` says.
    """
    lost = ~np.isfinite(radiance)
    if not lost.any():
        return _Lost(radiance, 0, 0, ())
    flat_lost = np.flatnonzero(lost)
    channels = radiance.shape[-1]
    t = np.asarray(times, np.float64)
    order = np.argsort(t, kind="stable")  # shortest exposure first
    p = len(order)
    top = g.shape[0] - 1 if white is None else white
    out = radiance.reshape(-1)  # filled in place (merge_bracket's own array)
    flat_images = [images[j].reshape(-1) for j in order]
    per_pixel = np.zeros((2, lost[..., 0].size), bool)  # (clipped, gap) per pixel, any channel
    pair_counts = np.zeros(p * p, np.int64)  # (longest dark, shortest clipped) exposure of the gap samples
    for start in range(0, flat_lost.size, FILL_CHUNK):  # chunks of lost samples: bounded memory
        flat = flat_lost[start : start + FILL_CHUNK]
        channel = flat % channels
        g_top, g_dark = g[top, channel], g[black + 1, channel]
        ln_low = np.full(flat.size, -np.inf)  # the tightest lower bound, and upper bound, of ln E
        ln_high = np.full(flat.size, np.inf)
        dark_j = np.full(flat.size, -1, np.int64)
        clip_j = np.full(flat.size, p, np.int64)
        clipped = None
        for k in range(p):  # exposures, shortest first
            high = flat_images[k][flat] >= top
            if k == 0:
                clipped = high
            ln_t = np.log(t[order[k]])
            np.maximum(ln_low, np.where(high, g_top - ln_t, -np.inf), out=ln_low)
            np.minimum(ln_high, np.where(high, np.inf, g_dark - ln_t), out=ln_high)
            dark_j[~high] = k
            clip_j[high & (clip_j == p)] = k
        gap = ~clipped
        fill = np.where(clipped, np.exp(ln_low) if saturated == "clip" else 0.0, np.exp(0.5 * (ln_low + ln_high)))
        out[flat] = fill
        pixel = flat // channels
        per_pixel[0, pixel[clipped]] = True
        per_pixel[1, pixel[gap]] = True
        pair_counts += np.bincount(dark_j[gap] * p + clip_j[gap], minlength=p * p)
    pairs = ()
    if pair_counts.any():  # the commonest pair of exposures, to name the missing times
        k = int(np.argmax(pair_counts))
        pairs = (float(t[order[k // p]]), float(t[order[k % p]]))
    return _Lost(out.reshape(radiance.shape), int(per_pixel[0].sum()), int(per_pixel[1].sum()), pairs)


@dataclass
class MergedBracket:
    """What :func:`merge_bracket` gives: the radiance and how much to trust it.

    Attributes
    ----------
    radiance : ndarray of float32, shape (H, W, 3)
        Linear radiance in the response's units exp(g)/s, finite.
    saturated_pixels : int
        Pixels with a channel saturated in every exposure (filled as ``saturated`` says).
    exposure_times : ndarray of float64, shape (P,)
        Seconds, in the order of the files.
    agreement : ndarray, shape (P − 1, 2)
        Median and 90th percentile of consecutive exposures' disagreement (:func:`exposure_agreement`), in order
        of exposure time.
    gap_pixels : int
        Pixels with a channel dark in the shorter exposures and clipped in the longer ones: no exposure measured
        them (filled with the geometric mean of their bounds).  Default 0.
    gap_times : tuple of float
        The commonest gap: (longest exposure that saw such a channel dark, shortest that clipped it), s; () if none.
    """

    radiance: np.ndarray
    saturated_pixels: int
    exposure_times: np.ndarray
    agreement: np.ndarray
    gap_pixels: int = 0
    gap_times: tuple = ()

    def warnings(self) -> list:
        """Pixels in a gap of the bracket, then consecutive exposures that disagree (:func:`agreement_warnings`)."""
        out = []
        if self.gap_pixels:
            share = self.gap_pixels / (self.radiance.shape[0] * self.radiance.shape[1])
            dark, clipped = (_seconds(t) for t in self.gap_times)
            out.append(
                f"{self.gap_pixels} pixel(s) dark in the shorter exposures and clipped in the longer ones "
                f"({share:.2%}; most dark at {dark} and clipped at {clipped}): no exposure measured them, so they "
                "were given the geometric mean of their bounds; add exposures between these"
            )
        return out + agreement_warnings(self.agreement, self.exposure_times)


def merge_bracket(paths, response, exposure_times=None, *, saturated: str = "clip"):
    """One radiance image from a bracket of photographs and a saved response (Debevec & Malik 1997 eq. 6).

    Parameters
    ----------
    paths : sequence of str or path-like
        The bracket (:func:`read_bracket`: at least two files, any order).
    response : str or path-like
        A ``facestats.camera-response/1`` file (:meth:`ResponseCalibration.save`); its black and white levels
        are the merge's (:func:`facestats.acquire.response.merge_photographs`).
    exposure_times : sequence of float, optional
        Seconds, one per file; default each file's EXIF ``ExposureTime``.
    saturated : {"clip", "zero"}
        A pixel channel saturated in every exposure has no measured radiance (NaN from the merge): ``clip`` gives
        it the lower bound of its radiance, exp(g(W))/Δt_min with W the white level, which is at least every
        measured radiance of its channel (a clipped highlight stays the brightest); ``zero`` gives it 0.  A pixel
        channel dark in the shorter exposures and clipped in the longer ones (a gap in the bracket) gets the
        geometric mean of its two bounds either way (:attr:`MergedBracket.gap_pixels`).

    Returns
    -------
    MergedBracket
        The radiance, the saturated pixels, the times and the consecutive exposures' agreement with this
        response (:meth:`MergedBracket.warnings`).

    Raises
    ------
    FormatError
        An unreadable response file or frame (named).
    ValidationError
        Frames of another bit depth than the response's levels, an unknown ``saturated``.
    """
    from facestats.core.validate import check_choice

    check_choice(saturated, "saturated", SATURATED_FILLS)
    g, doc = _response_file(response)
    black = check_integer(doc.get("black_level") or 0, f"{os.fspath(response)} field 'black_level'", 0)
    white = doc.get("white_level")
    if white is not None:
        white = check_white_level(white, g.shape[0], black)
    check_rising(g, black, f"{os.fspath(response)} field 'log_response'")  # a hand-edited file is merged otherwise
    images, times, bits = read_bracket(paths, exposure_times)
    levels = g.shape[0]
    if (bits == 8) != (levels == 256):  # 8-bit codes read with a deeper response pass every code check
        raise ValidationError(
            f"the frames hold {bits}-bit codes, and the response {os.fspath(response)} has {levels} levels "
            f"({levels.bit_length() - 1} bits): recover a response from frames of this camera and bit depth"
        )
    radiance = merge_photographs(images, times, g, black_level=black, white_level=white)
    lost = _fill_lost(radiance, images, times, g, black, white, saturated)
    agreement = exposure_agreement(images, times, g, black_level=black, white_level=white)
    return MergedBracket(
        lost.radiance.astype(np.float32, copy=False),
        lost.clipped_pixels,
        times,
        agreement,
        lost.gap_pixels,
        lost.gap_times,
    )
