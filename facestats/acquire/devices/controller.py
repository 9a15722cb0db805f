"""What every device driver shares: the link, the identity handshake, status, and a clean shutdown.

A driver opens a :class:`~facestats.acquire.devices.serial_link.SerialLink`, asks
the device ``ver`` and refuses a device of another kind (a dome driver on the
sensor's port, a modem, a device of another protocol) before it sends anything
else.  As a context manager it switches every light off when it leaves — also
after an error or Ctrl-C — and then closes the port; if the device cannot be
reached any more, the failure is logged and the port closed anyway.

Drivers remember the state they have set on the device (:meth:`Controller.remember`)
and send only what differs (:meth:`Controller.changed`); a reboot of the device
(:attr:`Controller.epoch` changes) forgets it, so the next step sets everything again.
"""

from __future__ import annotations

from facestats.acquire.devices.serial_link import SerialLink
from facestats.errors import DeviceError

__all__ = ["Controller", "status_field_error"]


def status_field_error(kind: str, port, exc: BaseException, fields: dict) -> DeviceError:
    """The error for a status reply of the ``kind`` device on ``port`` whose ``fields`` lack or garble one.

    Parameters
    ----------
    kind : str
        "dome" or "sensor".
    port : str
        The device's port, for the message.
    exc : BaseException
        The ``KeyError`` (missing field) or ``ValueError`` (malformed value) the parse raised.
    fields : dict
        The reply's fields (shown, cut to 120 characters).

    Returns
    -------
    DeviceError
        To be raised by the caller (``from None``).
    """
    return DeviceError(f"the {kind} on {port} sent a status without a valid field {exc}: {fields!r:.120}")


class Controller:
    """Base of :class:`DomeController` and :class:`SensorController` (module docstring).

    Parameters
    ----------
    port : str
        Device path or pyserial URL (``loop://``, ``socket://host:port``, ``rfc2217://host:port``).
    link : SerialLink, optional
        An open link to use instead of opening ``port``.
    log : callable, optional
        Receives one line per irregular event.

    Other Parameters
    ----------------
    **link_options
        Keyword arguments of :class:`SerialLink` (baudrate, parity, timeout, retries, …).

    Raises
    ------
    DeviceError
        The device does not identify itself as a facestats controller of this ``kind`` (or cannot be reached).
    """

    #: "dome" or "sensor": the device's identity must start with ``facestats-<kind>``.
    kind = ""

    def __init__(self, port: str | None = None, *, link: SerialLink | None = None, log=None, **link_options):
        self.link = link if link is not None else SerialLink(port, log=log, **link_options)
        self._state: dict = {}
        self._state_epoch = self.link.epoch
        try:
            self.identity = self.link.request("ver").payload
        except BaseException:
            self.link.close()
            raise
        if not self.identity.startswith(f"facestats-{self.kind}"):
            self.link.close()
            raise DeviceError(
                f"the device on {self.link.port} identifies itself as {self.identity!r}, not as a facestats "
                f"{self.kind} controller: check --port"
            )

    @property
    def port(self) -> str:
        return self.link.port

    @property
    def epoch(self) -> int:
        """Reboots of the device seen so far (its state is lost at each)."""
        return self.link.epoch

    def status(self) -> dict:
        """The device's ``st`` reply as a dict of strings."""
        return self.link.request("st").fields()

    def all_off(self):
        """Switch every light off (``x``)."""
        self.link.request("x")
        self._state.clear()

    # -- remembered device state -------------------------------------------------------------------
    def changed(self, key, value) -> bool:
        """True unless the device is known to hold ``value`` for ``key`` since its last reboot.

        Parameters
        ----------
        key : str
            The state's name (``"led"``, ``"exposure"``, ``"lamp"``, …).
        value
            The value to compare with the one remembered (:meth:`remember`).

        Returns
        -------
        bool
            True also when nothing is remembered for ``key``, or the device rebooted since (then every
            remembered value is forgotten).
        """
        if self._state_epoch != self.link.epoch:
            self._state.clear()
            self._state_epoch = self.link.epoch
        return self._state.get(key) != value

    def remember(self, key, value):
        """Record that the device now holds ``value`` for ``key`` (what :meth:`ensure` need not set again).

        Parameters
        ----------
        key : str
            The state's name.
        value
            The value the device now holds.
        """
        self._state[key] = value

    def forget(self):
        """Forget the remembered state: the next :meth:`ensure` sets everything (the device changed on its own)."""
        self._state.clear()

    # -- shutdown ------------------------------------------------------------------------------------
    def close(self):
        """Switch every light off (a few quick attempts), then close the port."""
        if not self.link.is_open:
            return
        retries, timeout = self.link.retries, self.link.timeout
        self.link.retries, self.link.timeout = min(retries, 2), min(timeout, 0.5)
        self.link.reconnect_timeout = min(self.link.reconnect_timeout, 1.0)
        try:
            self.all_off()
        except DeviceError as exc:
            self.link.log(f"could not switch the lights off on closing: {exc}")
        finally:
            self.link.retries, self.link.timeout = retries, timeout
            self.link.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
