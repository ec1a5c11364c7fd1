"""``python -m cli``: the ``zcut`` console script."""

import sys

from cli.main import main

sys.exit(main())
