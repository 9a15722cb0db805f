"""Figures of capture sessions: a camera's contact sheet, the sensor's bracket and profiles, the link's events.

Each function takes result objects and returns a :class:`matplotlib.figure.Figure`;
matplotlib is imported inside.
"""

from __future__ import annotations

import numpy as np

__all__ = ["plot_contact_sheet", "plot_sensor_bracket", "plot_link_events"]


def plot_contact_sheet(folder, camera: int = 0, exposure: int = -1, leds=None, *, columns: int = 10, g=None):
    """Thumbnails of one camera's frames under each LED, the operator's check of a dome session.

    Parameters
    ----------
    folder : CaptureFolder
        An opened capture folder (:func:`facestats.acquire.photographs.open_folder`).
    camera, exposure : int
        Which camera and exposure (default the longest).
    leds : sequence of int, optional
        LEDs to show (default all, at most 60 evenly spread).
    columns : int
        Thumbnails per row.
    g : ndarray, shape (levels, 3), optional
        The cameras' response (ln exposure per code); shown linear in exposure when given, else as codes.

    Returns
    -------
    matplotlib.figure.Figure
        The contact sheet.
    """
    import matplotlib.pyplot as plt

    n = folder.n_leds
    leds = np.unique(np.linspace(0, n - 1, min(n, 60)).round().astype(int)) if leds is None else np.asarray(leds)
    e = exposure % folder.n_exposures
    rows = int(np.ceil(len(leds) / columns))
    fig, axes = plt.subplots(rows, columns, figsize=(1.2 * columns, 1.25 * rows), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    images = []
    for led in leds:
        codes = folder.read_codes(camera, int(led), e)
        images.append(
            np.exp(np.take_along_axis(g, codes.reshape(-1, 3), 0)).reshape(codes.shape) if g is not None else codes
        )
    top = max(float(np.percentile(img, 99.5)) for img in images) or 1.0  # one scale: dark frames look dark
    for ax, led, img in zip(axes.ravel(), leds, images):
        ax.imshow(np.clip(img / top, 0, 1) ** (1 / 2.2))
        ax.set_title(f"LED {led}", fontsize=7)
    fig.suptitle(f"camera {camera}, exposure {e} ({folder.times(camera, 0)[e] * 1e3:.3g} ms)", fontsize=9)
    fig.tight_layout()
    return fig


def plot_sensor_bracket(bracket, site: int = 0):
    """The raw bracket of one site (fibre readings per exposure, saturation marked) and the merged profiles.

    Parameters
    ----------
    bracket : SensorBracket
        :func:`facestats.acquire.devices.sensor.read_bracket`'s result.
    site : int
        Index into ``bracket.sites`` of the site whose raw bracket (green channel, DN) is drawn; the profiles of
        every site are drawn beside it.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    r = bracket.fiber_distance
    colours = plt.cm.viridis(np.linspace(0, 1, len(bracket.exposure_s)))
    for j, t in enumerate(bracket.exposure_s):
        a.plot(
            r,
            bracket.readings[site, j, :, 1],
            color=colours[j],
            lw=1,
            label=f"{t * 1e3:.3g} ms" if j % 5 == 0 else None,
        )
    a.axhline(bracket.max_dn, color="k", ls=":", lw=1, label="saturation")
    a.set_yscale("log")
    a.set_xlabel("fibre distance r (mm)")
    a.set_ylabel("mean code of the spot, green (DN)")
    a.set_title(f"{bracket.sites[site]}: the {len(bracket.exposure_s)}-image bracket")
    a.legend(fontsize=7)
    for k, name in enumerate(bracket.sites):
        for c, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
            p, s = bracket.profile[k, :, c], bracket.profile_std[k, :, c]
            ok = p > 3 * s
            b.errorbar(r[ok], p[ok], yerr=s[ok], color=colour, fmt=("o", "s", "^")[k], ms=3, lw=0.8, alpha=0.8,
                       label=f"{name}" if c == 1 else None)  # fmt: skip
    b.set_yscale("log")
    b.set_xlabel("fibre distance r (mm)")
    b.set_ylabel("R(r) (mm⁻²), HDR merged")
    b.set_title("profiles (points above 3σ), R G B")
    b.legend(fontsize=7)
    fig.tight_layout()
    return fig


def plot_link_events(report, injected=None):
    """What the link met during a session (:class:`SessionReport`), beside what an emulator injected.

    Parameters
    ----------
    report : SessionReport
        A session's report; its ``link`` counters are drawn.
    injected : dict, optional
        The emulator's fault counts (``PtyServer.injected``: ``drop``, ``garble``, ``truncate``, ``duplicate``,
        ``stall``, ``disconnect``, ``reboot``), drawn beside the link's counters they should cause.

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    keys = ["retries", "garbled", "truncated", "timeouts", "out_of_order", "duplicates", "reboots", "reconnects"]
    seen = [report.link.get(k, 0) for k in keys]
    fig, ax = plt.subplots(figsize=(7, 3))
    x = np.arange(len(keys))
    ax.bar(x - 0.2, seen, 0.4, label="detected by the link")
    if injected:
        names = {"garbled": "garble", "truncated": "truncate", "timeouts": "drop", "duplicates": "duplicate",
                 "reboots": "reboot", "reconnects": "disconnect", "out_of_order": "stall"}  # fmt: skip
        ax.bar(x + 0.2, [injected.get(names.get(k, ""), 0) for k in keys], 0.4, label="injected by the emulator")
    ax.set_xticks(x, keys, rotation=30, fontsize=8)
    ax.set_ylabel("count")
    ax.set_title(f"{report.kind} session of {report.subject_id}: {report.link.get('requests', 0)} requests")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig
