"""``python -m citylod.cli``: the same as the ``citylod`` command."""

import sys

from citylod.cli import main

sys.exit(main())
