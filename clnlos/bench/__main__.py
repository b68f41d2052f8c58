"""``python -m clnlos.bench ...``: the bench's own entry point (:func:`clnlos.bench.main`,
the flags of ``clnlos bench``; a user error ends in one ``clnlos: error:`` line, exit 2).
``clnlos bench`` fronts the same function and adds the CLI's checks (the environment, no
output over an input); this entry imports nothing of the CLI."""

import sys

from clnlos.bench import main
from clnlos.errors import ClnlosError

try:
    main(sys.argv[1:])
except ClnlosError as e:
    print(f"clnlos: error: {e}", file=sys.stderr)
    sys.exit(2)
