"""``python -m stereod.cli``: the ``stereod`` command."""

import sys

from . import main

sys.exit(main())
