#!/usr/bin/env python3
"""What accuracy costs in time: thin wrapper of :mod:`clnlos.bench` (``clnlos bench``).

    python tools/bench_all.py [--quick | --tiny] [-o DIR] [--device SPEC] [--only SECTIONS]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from clnlos.bench import main  # noqa: E402

if __name__ == "__main__":
    main()
