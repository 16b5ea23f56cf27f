"""``python -m training.depth`` = ``monoflow-train-depth``."""

from training.depth.cli import main

raise SystemExit(main())
