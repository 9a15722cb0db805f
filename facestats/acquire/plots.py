"""Figures of the acquisition stage: camera responses, HDR frames, LED calibrations, head-motion scores.

Each function takes results (arrays or result objects) and returns a
:class:`matplotlib.figure.Figure`; matplotlib is imported inside.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plot_response", "plot_hdr_frame", "plot_led_calibration"]


def plot_response(response, truth=None, *, labels=("R", "G", "B")):
    """Debevec-Malik g(z) per channel (ln exposure against code), with a true curve if given.

    Parameters
    ----------
    response : array_like, shape (levels, C), C ≤ 3
        The recovered g per code and channel (drawn red, green, blue).
    truth : array_like, shape (levels,), optional
        A true g, drawn dashed.
    labels : sequence of str
        Channel names for the legend.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    g = np.asarray(response)
    fig, ax = plt.subplots(figsize=(5, 3.5))
    z = np.arange(g.shape[0])
    for c, colour in zip(range(g.shape[1]), ("tab:red", "tab:green", "tab:blue")):
        ax.plot(z, g[:, c], color=colour, lw=1, label=f"recovered {labels[c]}")
    if truth is not None:
        ax.plot(z, np.asarray(truth), "k--", lw=1, label="true")
    ax.set_xlabel("code z")
    ax.set_ylabel("g(z) = ln exposure")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def plot_hdr_frame(radiance, *, title="HDR frame"):
    """A merged frame (H, W, 3 linear radiance) shown with a log tone map, NaN (saturated) in magenta.

    Parameters
    ----------
    radiance : array_like, shape (H, W, 3)
        Linear radiance; the tone map spans its 1st to 99.9th percentile of positive values, and a pixel with
        any non-finite channel is magenta.
    title : str
        Axes title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    e = np.asarray(radiance, np.float64)
    pos = e[np.isfinite(e) & (e > 0)]
    lo, hi = np.percentile(pos, [1, 99.9]) if pos.size else (1.0, 10.0)
    img = np.clip((np.log(np.maximum(e, lo)) - np.log(lo)) / max(np.log(hi / lo), 1e-9), 0, 1)
    img[~np.isfinite(e).all(-1)] = [1, 0, 1]
    fig, ax = plt.subplots(figsize=(4, 4))
    ax.imshow(img)
    ax.set_title(title)
    ax.axis("off")
    fig.tight_layout()
    return fig


def plot_led_calibration(result, truth=None):
    """Fitted LED intensities (and their ratio to ``truth`` (L, 3) if given) and RMS residuals per LED.

    Parameters
    ----------
    result : LedCalibration
        :func:`facestats.acquire.calibration.fit_leds`'s result.
    truth : ndarray, shape (L, 3), optional
        True intensities I₀; given, the left panel shows the relative error in per cent instead of I₀.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.2))
    leds = np.arange(len(result.intensity))
    if truth is None:
        for c, colour in zip(range(3), ("tab:red", "tab:green", "tab:blue")):
            a.plot(leds, result.intensity[:, c], ".", color=colour)
        a.set_ylabel("I₀ (dome units · mm²)")
    else:
        for c, colour in zip(range(3), ("tab:red", "tab:green", "tab:blue")):
            a.plot(leds, 100 * (result.intensity[:, c] / truth[:, c] - 1), ".", color=colour)
        a.axhline(0, color="k", lw=0.5)
        a.set_ylabel("I₀ error (%)")
    a.set_xlabel("LED")
    b.bar(leds, 100 * result.rms_residual, color="0.5")
    b.set_xlabel("LED")
    b.set_ylabel("RMS relative residual (%)")
    fig.tight_layout()
    return fig
