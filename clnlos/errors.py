"""Typed exceptions of clnlos.

Every error a user can cause derives from :class:`ClnlosError`; the command line turns
these into one line on stderr and exit status 2 (see :mod:`clnlos.cli`).
"""

from __future__ import annotations


class ClnlosError(Exception):
    """Base class for errors a user can cause (bad input, bad parameter, device problem)."""


class ParameterError(ClnlosError, ValueError):
    """A parameter is invalid; the message names it, its value and the allowed range."""

    def __init__(self, name: str, value, allowed: str):
        self.name, self.value, self.allowed = name, value, allowed
        super().__init__(f"invalid {name} = {value!r}: allowed {allowed}")


class ShapeError(ClnlosError, ValueError):
    """An array has the wrong shape or dtype for the operator it is given to."""


class InputFileError(ClnlosError):
    """A capture, config or data file cannot be read or does not hold what it must."""


class OutputFileError(ClnlosError):
    """An output path cannot be used (a directory, an input, unwritable) or writing failed."""


class MissingDependencyError(ClnlosError):
    """An optional dependency a command needs is not installed; the message names the extra."""


class DeviceError(ClnlosError, RuntimeError):
    """No device matches the request, or a device cannot be used."""


class DeviceCapabilityError(DeviceError):
    """The device lacks a capability the request needs (fp64, images, memory)."""


class KernelBuildError(DeviceError):
    """An OpenCL program failed to build; the message carries file, options, device and log."""
