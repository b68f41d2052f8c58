"""Checks of the environment and installation before any work (one line naming the variable)."""

from __future__ import annotations

from clnlos.runtime.fft import check_vkfft_importable
from clnlos.runtime.spectrum_cache import SpectrumCache
from clnlos.settings import Settings


def check_environment() -> Settings:
    """Read and validate the CLNLOS_* environment variables up front (before any work): a bad
    value is a one-line error naming the variable (:meth:`clnlos.settings.Settings.from_env`);
    CLNLOS_FFT=vkfft needs pyvkfft's OpenCL backend, CLNLOS_SPECTRUM_CACHE a writable folder.
    Returns the settings, for the command to pass down."""
    settings = Settings.from_env()
    if settings.fft == "vkfft":
        check_vkfft_importable()
    cache = SpectrumCache.from_settings(settings)
    if cache is not None:
        cache.check()
    return settings
