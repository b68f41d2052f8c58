"""Process settings from the environment: the one place that reads ``CLNLOS_*`` variables.

=========================  ==================================================================
``CLNLOS_DEVICE``          device spec (:mod:`clnlos.runtime.device`); ``--device`` overrides
``CLNLOS_THREADS``         host threads of this process (host FFT, compression); default: the
                           cores available to it
``CLNLOS_FFT``             FFT backend: ``auto`` (default), ``vkfft`` or ``host`` (``numpy``
                           is an alias of ``host``) (:mod:`clnlos.runtime.fft`)
``CLNLOS_PLAN_CACHE_MB``   byte budget of the in-memory plan caches (MiB); default: a quarter
                           of the device's global memory (:mod:`clnlos.runtime.caches`)
``CLNLOS_SPECTRUM_CACHE``  folder of the optional on-disk spectrum cache (off when unset,
                           :mod:`clnlos.runtime.spectrum_cache`)
``CLNLOS_SPECTRUM_CACHE_MB``  that folder's budget (MiB), default DEFAULT_SPECTRUM_CACHE_MB
=========================  ==================================================================

:meth:`Settings.from_env` parses and validates them all (a bad value is one error naming the
variable); :func:`current` gives the settings of the environment as it is now, parsed once
per distinct environment. Code below the command line takes a ``Settings`` (or ``None`` for
:func:`current`) and reads no environment itself.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from clnlos.errors import DeviceError, ParameterError

ENV_DEVICE = "CLNLOS_DEVICE"
ENV_THREADS = "CLNLOS_THREADS"
ENV_FFT = "CLNLOS_FFT"
ENV_PLAN_CACHE_MB = "CLNLOS_PLAN_CACHE_MB"
ENV_SPECTRUM_CACHE = "CLNLOS_SPECTRUM_CACHE"
ENV_SPECTRUM_CACHE_MB = "CLNLOS_SPECTRUM_CACHE_MB"
ENV_NAMES = (ENV_DEVICE, ENV_THREADS, ENV_FFT, ENV_PLAN_CACHE_MB, ENV_SPECTRUM_CACHE,
             ENV_SPECTRUM_CACHE_MB)

FFT_CHOICES = ("auto", "vkfft", "host")
FFT_ALIASES = {"numpy": "host"}
DEFAULT_SPECTRUM_CACHE_MB = 4096.0
MIB = 2**20


def _threads(raw: str) -> int | None:
    raw = raw.strip()
    if not raw:
        return None
    try:
        n = int(raw)
    except ValueError:
        n = 0
    if n < 1:
        raise DeviceError(f"invalid {ENV_THREADS}={raw!r}: a positive integer")
    return n


def _fft(raw: str) -> tuple[str, str]:
    """(backend choice, the value as written: a reason names it)."""
    written = raw.strip().lower() or "auto"
    choice = FFT_ALIASES.get(written, written)
    if choice not in FFT_CHOICES:
        raise DeviceError(f"invalid {ENV_FFT}={written!r}: allowed {', '.join(FFT_CHOICES)}")
    return choice, written


def _mib(name: str, raw: str) -> int | None:
    raw = raw.strip()
    if not raw:
        return None
    try:
        mb = float(raw)
    except ValueError:
        raise ParameterError(name, raw, "a number of MiB >= 0") from None
    if not mb >= 0:
        raise ParameterError(name, raw, "a number of MiB >= 0")
    return int(mb * MIB)


@dataclass(frozen=True)
class Settings:
    """Validated process settings (see the module docstring). ``None``: the default."""

    device: str = ""
    threads: int | None = None
    fft: str = "auto"
    fft_written: str = "auto"            # CLNLOS_FFT as written (``numpy`` for the alias)
    plan_cache_bytes: int | None = None
    spectrum_cache_dir: Path | None = None
    spectrum_cache_bytes: int = int(DEFAULT_SPECTRUM_CACHE_MB * MIB)

    @classmethod
    def from_env(cls, environ=None) -> Settings:
        env = os.environ if environ is None else environ
        fft, written = _fft(env.get(ENV_FFT, ""))
        cache_dir = env.get(ENV_SPECTRUM_CACHE, "").strip()
        cache_mb = _mib(ENV_SPECTRUM_CACHE_MB, env.get(ENV_SPECTRUM_CACHE_MB, ""))
        return cls(device=env.get(ENV_DEVICE, "").strip(),
                   threads=_threads(env.get(ENV_THREADS, "")), fft=fft, fft_written=written,
                   plan_cache_bytes=_mib(ENV_PLAN_CACHE_MB, env.get(ENV_PLAN_CACHE_MB, "")),
                   spectrum_cache_dir=Path(cache_dir) if cache_dir else None,
                   spectrum_cache_bytes=(int(DEFAULT_SPECTRUM_CACHE_MB * MIB)
                                         if cache_mb is None else cache_mb))

    def host_threads(self) -> int:
        """Host threads this process may use: ``threads`` if set, else its available cores."""
        if self.threads is not None:
            return self.threads
        try:
            return len(os.sched_getaffinity(0)) or 1
        except AttributeError:  # not Linux
            return os.cpu_count() or 1


_parsed: dict[tuple, Settings] = {}


def current() -> Settings:
    """The settings of the environment as it is now (parsed once per distinct environment)."""
    key = tuple(os.environ.get(name) for name in ENV_NAMES)
    hit = _parsed.get(key)
    if hit is None:
        hit = _parsed[key] = Settings.from_env()
    return hit


def resolve(settings: Settings | None) -> Settings:
    """``settings``, or :func:`current` for None."""
    return current() if settings is None else settings
