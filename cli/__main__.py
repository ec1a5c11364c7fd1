"""``python -m cli``: the ``zcut`` console script."""

import sys

from cli.entry import run

sys.exit(run())
