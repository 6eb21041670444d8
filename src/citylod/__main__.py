"""``python -m citylod`` runs the command line, as the ``citylod`` script does."""

import sys

from citylod.cli import main

if __name__ == "__main__":
    sys.exit(main())
