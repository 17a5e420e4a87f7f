"""Entry point of ``python -m stereod_fakes.world``."""

from .cli import main

raise SystemExit(main())
