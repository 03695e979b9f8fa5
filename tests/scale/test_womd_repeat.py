"""benchmarks/womd_repeat.py: the real scenes repeated under new scenario ids, each copy
the same scene as its source but for its id."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(PROJECT_ROOT / "benchmarks"))

import womd_repeat  # noqa: E402


def test_a_scenario_record_keeps_every_byte_but_its_id():
    from tap_bench.womd.proto import ScenarioView

    record = b"\x09" + bytes(8) + b"\x2a\x03abc" + b"\x30\x07"  # field 1, id 'abc', field 6
    out = womd_repeat.with_scenario_id(record, "abc-r12")
    assert out == b"\x09" + bytes(8) + b"\x2a\x07abc-r12" + b"\x30\x07"
    assert ScenarioView.FromString(out).scenario_id == "abc-r12"
    assert womd_repeat.with_scenario_id(b"\x30\x07", "x") == b"\x2a\x01x\x30\x07"


def test_the_real_scenes_repeated_under_new_ids(womd_dir, tmp_path):
    from tap_bench.sim.womd_scene import load_scene, scene_catalog

    sources = womd_repeat.DEFAULT_SOURCES
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        n_src = len(scene_catalog(sources))
        files = womd_repeat.write_repeated(n_src + 3, tmp_path / "rep", per_file=4,
                                           sources=sources)
        refs = scene_catalog([str(tmp_path / "rep")])
        source_refs = scene_catalog(sources)
    assert len(refs) == n_src + 3 and len(files) > 1  # none dropped as a duplicate id
    by_id = {}
    for ref in refs:
        scene = load_scene(ref)
        assert scene.scenario_id not in by_id
        by_id[scene.scenario_id] = scene
    for k, ref in enumerate(source_refs[:3]):  # copy 1 of the first sources
        source = load_scene(ref)
        copy = by_id[f"{source.scenario_id}-r1"]
        np.testing.assert_array_equal(copy.x, source.x)
        np.testing.assert_array_equal(copy.valid, source.valid)
        assert copy.road.lanes.keys() == source.road.lanes.keys()
        assert f"{source.scenario_id}-r0" in by_id, k


def test_it_refuses_to_write_into_the_project(womd_dir):
    with pytest.raises(SystemExit, match="inside the project"):
        womd_repeat.main(["3", "-o", str(PROJECT_ROOT / "womd-copies")])
    assert not (PROJECT_ROOT / "womd-copies").exists()
