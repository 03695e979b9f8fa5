"""The scale tests import their generated scenes (``scale_scenes``) and the closed-loop
tests' record helpers (``tests/sim/womd_records``)."""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # for scale_scenes
sys.path.insert(0, str(HERE.parent / "sim"))  # for womd_records
