"""``python -m stereod.cli``: the ``stereod`` command."""

import sys

from stereod.cli import main

sys.exit(main())
