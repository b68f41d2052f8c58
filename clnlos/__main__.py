import sys

from clnlos.app.cli import main

sys.exit(main())
