"""`python -m abyss.cli`: how `abyss up` starts its stations (with -P, so that the current
directory never shadows abyss's own modules)."""

import sys

from abyss.cli import main

sys.exit(main())
