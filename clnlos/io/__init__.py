"""Captures, volumes and reports on disk: the Capture contract, format readers, atomic
outputs, figures."""
