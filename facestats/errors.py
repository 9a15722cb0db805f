"""The exception hierarchy of facestats.

Every error facestats raises on purpose derives from :class:`FacestatsError`, so
callers can catch one class.  Messages name the argument, the offending value
and what was expected.
"""

from __future__ import annotations

__all__ = [
    "FacestatsError",
    "ValidationError",
    "StoreError",
    "SchemaError",
    "InsufficientDataError",
    "FitError",
    "FormatError",
    "DependencyError",
    "DeviceError",
    "DeviceTimeout",
    "DeviceReplyError",
    "SessionError",
    "ConvergenceWarning",
    "FacestatsWarning",
    "QuantisationWarning",
]


class FacestatsError(Exception):
    """Root of every error raised by facestats."""


class ValidationError(FacestatsError, ValueError):
    """An argument has the wrong shape, type, domain or value."""


class InsufficientDataError(ValidationError):
    """The data selected cannot support an analysis (too few subjects, no condition series, no sensor data)."""


class StoreError(FacestatsError):
    """A parameter store is missing, corrupt, locked or read-only."""


class SchemaError(StoreError):
    """Stored data does not follow the facestats schema (or a version it cannot migrate)."""


class FitError(FacestatsError):
    """A fit could not be carried out at all (as opposed to a flagged texel)."""


class FormatError(FacestatsError):
    """A file in an external format (mesh, MATLAB, capture) cannot be read."""


class DependencyError(FacestatsError, ImportError):
    """An optional dependency a feature needs is not installed (the message says how to install it)."""


class DeviceError(FacestatsError):
    """A serial device cannot be opened, does not speak the facestats protocol, or was wired differently."""


class DeviceTimeout(DeviceError):
    """A device did not answer a command within its retries (silent, disconnected or too noisy a line)."""


class DeviceReplyError(DeviceError):
    """A device answered a command with a numbered error (``code``: the protocol's error number)."""

    def __init__(self, message: str, code: int = 0):
        super().__init__(message)
        self.code = int(code)


class SessionError(FacestatsError):
    """A capture session cannot start or resume: its directory, plan or journal does not fit the request."""


class ConvergenceWarning(UserWarning):
    """A sampler or solver finished without meeting its convergence criterion."""


class FacestatsWarning(UserWarning):
    """Root of the warnings facestats issues about results it still returns."""


class QuantisationWarning(FacestatsWarning):
    """A quantised-distance system (Suzuki et al. eq. 33) had unsupported levels or lacked rank, or its light barely
    varies where the camera sees (:mod:`facestats.model.fitting.even_light`).

    The result records what was done (levels merged, numerical rank, condition number).
    """
