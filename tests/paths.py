"""Where the tests find the repository and the real data beside it (``../shared/data``, optional)."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = ROOT.parent / "shared" / "data"
DELFT = SHARED_DATA / "delft"
