"""Physical constants every stage shares (pure: imports nothing), stated once here;
``clnlos.C0`` is this one, re-exported at the package top."""

C0 = 299_792_458.0
"""Speed of light in vacuum, m/s."""
