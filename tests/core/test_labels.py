"""The label-table contract (tap_bench.labels) and the SDL text functions (tap_bench.sdl)."""

from __future__ import annotations

import pandas as pd
import pytest

import tap_bench
from tap_bench import sdl
from tap_bench.errors import LabelTableError, UnknownNameError
from tap_bench.labels import LABEL_COLUMNS, select_level, validate_labels


def _table() -> pd.DataFrame:
    return pd.DataFrame({
        "scenario_id": ["s", "s", "s"], "track_id": ["1", "2", "1"], "segment": [0, 0, 0],
        "level": ["maneuver", "maneuver", "trend"],
        "lateral": ["Straight > Left Merge", "Straight", "Straight"],
        "longitudinal": ["Maintain Speed", "Stopped", "Accelerate"],
        "sdl": ["Straight > Left Merge | Maintain Speed", "Straight | Stopped",
                "Straight | Accelerate"]})


def test_format_and_parse_are_inverse():
    text = sdl.format_sdl(["Straight", "Gradual Left Turn"], ["Maintain Medium Speed"])
    assert text == "Straight > Gradual Left Turn | Maintain Medium Speed"
    assert sdl.parse_sdl(text, level="action") == (("Straight", "Gradual Left Turn"),
                                                   ("Maintain Medium Speed",))
    assert sdl.split(sdl.join(["A", "B"])) == ("A", "B")


def test_level_checks_name_the_choices():
    assert sdl.levels("all") == sdl.LEVELS and sdl.levels("trend") == ("trend",)
    with pytest.raises(UnknownNameError, match="maneuver"):
        sdl.check_level("manuever")
    with pytest.raises(UnknownNameError, match="all"):
        sdl.levels("al")


def test_validate_selects_one_level_and_keeps_input_rows():
    table, level, rows = validate_labels(_table(), "maneuver")
    assert level == "maneuver" and len(table) == 2 and list(rows) == [0, 1]
    with pytest.raises(LabelTableError, match="2 levels"):
        validate_labels(_table())
    with pytest.raises(LabelTableError, match="no labels at level 'action'"):
        select_level(_table(), "action")


def test_validate_names_the_row_and_the_fix():
    bad = _table()
    bad.loc[1, "sdl"] = "Straight | Maintain Speed"
    with pytest.raises(LabelTableError, match=r"row 1 \(scenario_id='s', track_id='2'.*"
                                              r"tap-bench label"):
        validate_labels(bad, "maneuver", source="x.parquet")
    with pytest.raises(LabelTableError, match=r"missing column.*'sdl'"):
        validate_labels(_table().drop(columns="sdl"), "maneuver")


def test_tap_output_meets_the_contract():
    table = tap_bench.sample_table()
    labels = tap_bench.label(table, level="all")
    assert tuple(labels.columns[:len(LABEL_COLUMNS)]) == LABEL_COLUMNS
    for level in sdl.LEVELS:
        rows, _, _ = validate_labels(labels, level)
        assert len(rows) == (labels["level"] == level).sum()
