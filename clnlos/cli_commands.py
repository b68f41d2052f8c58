"""Sub-commands of the clnlos CLI beyond ``devices`` (each one thin over a pipeline)."""

from __future__ import annotations


def register(sub, add_device) -> None:
    """Add the pipeline sub-commands to the parser ``sub``."""
