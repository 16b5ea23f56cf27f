"""``python -m pipeline``: the ``monoflow-preprocess`` command line (stage one)."""

import sys

from pipeline.cli import main

sys.exit(main())
