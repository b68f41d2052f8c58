"""``python -m clnlos.bench ...``: exactly ``clnlos bench ...`` (the CLI's checks, flags and
one-line errors)."""

import sys

from clnlos.app.cli import main

sys.exit(main(["bench", *sys.argv[1:]]))
