"""Shared helpers of the tools/bench_*.py scripts: the harness of :mod:`clnlos.bench`."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from clnlos.bench.harness import device_meta, print_table, timeit, write_rows  # noqa: E402,F401
