"""Imported first by every bench: puts this checkout first on ``sys.path``, so a bench measures
the tree it belongs to even when an editable install points at another clone."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
