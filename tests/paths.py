"""Where the tests find the repository and the real data beside it (``../shared/data``, optional)."""

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# CITYLOD_SHARED_DATA points a worktree that is not beside ../shared at the data.
SHARED_DATA = Path(os.environ.get("CITYLOD_SHARED_DATA") or ROOT.parent / "shared" / "data")
DELFT = SHARED_DATA / "delft"
