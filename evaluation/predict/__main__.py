"""``python -m evaluation.predict`` = ``monoflow-predict``."""

import sys

from evaluation.predict.cli import main

sys.exit(main())
