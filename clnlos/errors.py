"""Typed exceptions of clnlos.

Every error a user can cause derives from :class:`ClnlosError`; the command line turns
these into one line on stderr and exit status 2 (see :mod:`clnlos.app.cli`).
"""

from __future__ import annotations


class ClnlosError(Exception):
    """Base class for errors a user can cause (bad input, bad parameter, device problem)."""


SHOWN_CHARS = 80  # a value (or a name) is cut to this many characters in a message


def shown(value, *, as_repr: bool = True) -> str:
    """``value`` for a one-line message (its repr, or str with ``as_repr=False``), cut to
    SHOWN_CHARS with its full length added: a 10 MB string is not echoed back."""
    text = repr(value) if as_repr else str(value)
    if len(text) <= SHOWN_CHARS:
        return text
    size = len(value) if isinstance(value, str | list | dict | tuple) else len(text)
    unit = "characters" if isinstance(value, str) else "items" if size != len(text) else \
        "characters as text"
    return f"{text[:SHOWN_CHARS - 3]}... ({size} {unit})"


class ParameterError(ClnlosError, ValueError):
    """A parameter is invalid; the message names it, its value and the allowed range."""

    def __init__(self, name: str, value, allowed: str):
        self.name, self.value, self.allowed = name, value, allowed
        super().__init__(f"invalid {shown(name, as_repr=False)} = {shown(value)}: "
                         f"allowed {allowed}")


class MissingParameterError(ParameterError):
    """A parameter the input does not give and the user did not set; the message names it
    and says how to give it."""

    def __init__(self, name: str, why: str):
        self.name, self.value, self.allowed = name, None, why
        ValueError.__init__(self, f"{name} is needed: {why}")


class ImplausibleValueError(ParameterError):
    """A value no NLOS capture can have (most likely a unit slip); the message names it, why
    it cannot be, the likely slip and the option that accepts it anyway."""

    def __init__(self, name: str, value, why: str, accept: str):
        self.name, self.value, self.allowed = name, value, why
        ValueError.__init__(self, f"{why}; {accept} accepts it")


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


class MemoryLimitError(ClnlosError):
    """A size declared by a file or a parameter needs more memory than the host has or a
    device allows; the message names the size, the limit and which memory
    (:func:`clnlos.runtime.limits.check_memory`)."""


class DeviceMemoryError(MemoryLimitError, DeviceCapabilityError):
    """:class:`MemoryLimitError` of a device's memory (global or largest allocation)."""
