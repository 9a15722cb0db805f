"""Device control: the dome's LED/trigger controller and the contact sensor over serial, emulated hardware, sessions.

One module per concept:

* :mod:`~facestats.acquire.devices.protocol` — the line protocol: requests, reply frames, CRC-16, error numbers;
* :mod:`~facestats.acquire.devices.serial_link` — request/reply over pyserial with timeouts, retries, reconnection;
* :mod:`~facestats.acquire.devices.controller` — what the drivers share (handshake, state, clean shutdown);
* :mod:`~facestats.acquire.devices.dome` — :class:`~facestats.acquire.devices.dome.DomeController`;
* :mod:`~facestats.acquire.devices.sensor` — :class:`~facestats.acquire.devices.sensor.SensorController`, the fibre
  image and bracket merge;
* :mod:`~facestats.acquire.devices.cameras` — camera backends: emulated, hot folder;
* :mod:`~facestats.acquire.devices.scene` — what emulated cameras see of a subject;
* :mod:`~facestats.acquire.devices.emulator` — emulated firmware on a pty, fault injection;
* :mod:`~facestats.acquire.devices.lab` — the emulated lab (``facestats emulate``);
* :mod:`~facestats.acquire.devices.plans` — the paper's sequences as plans;
* :mod:`~facestats.acquire.devices.session` — journal, resume, the capture folder;
* :mod:`~facestats.acquire.devices.capture` — calibration → plan → devices → session (``facestats capture``);
* :mod:`~facestats.acquire.devices.plots` — figures of sessions and brackets.
"""
