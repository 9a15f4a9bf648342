"""``python -m head360cli`` runs the ``head360`` command line."""

import sys

from head360cli.cli import main

if __name__ == "__main__":  # not when a worker process re-imports this module
    sys.exit(main())
