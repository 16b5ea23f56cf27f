"""``python -m evaluation`` = ``monoflow-evaluate``."""

from evaluation.cli import main

raise SystemExit(main())
