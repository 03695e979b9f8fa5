"""Fixtures for the similarity tests: small label tables written by hand and the real WOMD
samples (skipped when absent). Helpers shared by the test modules are in
``similarity_helpers.py`` (importable: this folder is put on sys.path)."""

from __future__ import annotations

import sys
from pathlib import Path

import pandas as pd
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from similarity_helpers import CRUISE, LEFT_MERGE, STOP_AND_GO, label_rows


@pytest.fixture
def small_labels() -> pd.DataFrame:
    """Six trajectories: three cruising, two left merges, one stop-and-go (unique)."""
    return label_rows([
        ("s1", "1", CRUISE), ("s1", "2", LEFT_MERGE), ("s1", "3", CRUISE),
        ("s2", "1", LEFT_MERGE), ("s2", "2", STOP_AND_GO), ("s2", "3", CRUISE),
    ])
