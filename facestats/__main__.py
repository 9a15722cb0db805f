"""``python -m facestats`` runs the command line."""

import sys

from facestats.cli import main

sys.exit(main())
