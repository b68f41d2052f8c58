"""The clnlos version, stated once (pyproject.toml reads it; ``clnlos.__version__`` is this
one, re-exported at the package top); modules inside the package import it from here, never
from the package's face."""

__version__ = "0.4.2"
