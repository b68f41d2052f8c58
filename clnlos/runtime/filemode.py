"""The mode of a new file under the process's umask: what every file clnlos writes gets
(outputs, :mod:`clnlos.io.outputs`; cache entries, :mod:`clnlos.runtime.spectrum_cache`),
stated once here below both."""

from __future__ import annotations

import os


def umask() -> int:
    """The process's umask (read by setting it and putting it back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def file_mode() -> int:
    """Mode of a new regular file under the current umask (0o644 under umask 022)."""
    return 0o666 & ~umask()
