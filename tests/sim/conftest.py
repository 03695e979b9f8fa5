"""Fixtures of the simulation tests: tiny scenario files and short episodes."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest

import tap_bench  # noqa: F401  (registers the tap_bench/... ids)


@pytest.fixture(autouse=True)
def _quiet_gymnasium_checker():
    # The passive checker warns that highway-env's AttributesObservation space is generic.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*within the observation space.*")
        warnings.filterwarnings("ignore", message=".*is not within the observation space.*")
        yield


@pytest.fixture
def write_scenario(tmp_path: Path):
    """Write a scenario file (a dict, with overrides of a valid highway scenario) and return
    its path."""

    def write(name: str = "tiny", **fields) -> Path:
        doc = {"name": name, "version": 0, "highway_env_id": "highway-v0",
               "description": "test scenario", "duration": 2, "default_seeds": "0-2",
               "lane_change": "realistic",
               "config": {"lanes_count": 2, "vehicles_count": 3, "policy_frequency": 1}}
        doc.update(fields)
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(doc))
        return path

    return write
