"""``python -m training`` = ``monoflow-train``."""

from training.cli import main

raise SystemExit(main())
