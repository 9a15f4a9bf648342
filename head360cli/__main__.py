"""``python -m head360cli`` runs the ``head360`` command line."""

import sys

from head360cli.cli import main

sys.exit(main())
