"""g_SDL and the Levenshtein distance over SDL tokens, and the label-table encoding."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from similarity_helpers import CRUISE, GRADUAL_LEFT, LEFT_MERGE, STOP_AND_GO, label_rows

from tap_bench import sdl
from tap_bench.errors import LabelTableError, UnknownNameError
from tap_bench.similarity import g_sdl, label_set, parse_sdl, sdl_levenshtein
from tap_bench.similarity.sdl_distance import levenshtein_matrix


def test_g_sdl_is_zero_only_for_the_same_label():
    assert g_sdl(CRUISE, CRUISE) == 0
    assert g_sdl(CRUISE, LEFT_MERGE) == 1


@pytest.mark.parametrize(("a", "b", "expected"), [
    (CRUISE, CRUISE, 0),
    # insert "Gradual Left Turn" and "Straight" on the lateral axis
    (CRUISE, GRADUAL_LEFT, 2),
    # substitute one lateral token
    (LEFT_MERGE, GRADUAL_LEFT, 1),
    # lateral: delete two tokens (1 + 2 = 3 lateral -> 1); longitudinal: substitute 1,
    # insert 2 (Maintain Medium -> Decelerate Slow > Stopped > Accelerate Slow): 2 + 3
    (LEFT_MERGE, STOP_AND_GO, 5),
    # the axes are separate: a longitudinal token never matches a lateral one
    ("Straight | Stopped", "Stopped | Straight", None),
])
def test_levenshtein_on_known_pairs(a, b, expected):
    if expected is None:
        with pytest.raises(LabelTableError):
            sdl_levenshtein(a, b)
        return
    assert sdl_levenshtein(a, b) == expected
    assert sdl_levenshtein(b, a) == expected


def _dp(a: list[str], b: list[str]) -> int:
    """Textbook Levenshtein dynamic programme over tokens, the reference."""
    d = list(range(len(b) + 1))
    for i, ta in enumerate(a, 1):
        prev, d[0] = d[0], i
        for j, tb in enumerate(b, 1):
            prev, d[j] = d[j], min(d[j] + 1, d[j - 1] + 1, prev + (ta != tb))
    return d[-1]


LAT = st.lists(st.sampled_from(sdl.vocabulary("action", "lateral")), min_size=1, max_size=7)
LON = st.lists(st.sampled_from(sdl.vocabulary("action", "longitudinal")), min_size=1,
               max_size=7)


@settings(max_examples=80, deadline=None)
@given(LAT, LON, LAT, LON)
def test_levenshtein_equals_the_token_dynamic_programme(lat_a, lon_a, lat_b, lon_b):
    a = " > ".join(lat_a) + " | " + " > ".join(lon_a)
    b = " > ".join(lat_b) + " | " + " > ".join(lon_b)
    assert sdl_levenshtein(a, b) == _dp(lat_a, lat_b) + _dp(lon_a, lon_b)
    labels = label_rows([("s", "0", a), ("s", "1", b)])
    ls = label_set(labels)
    m = levenshtein_matrix(ls)
    assert m[ls.code[0], ls.code[1]] == _dp(lat_a, lat_b) + _dp(lon_a, lon_b)


def test_parse_sdl_splits_axes_and_tolerates_loose_spacing():
    assert parse_sdl("Straight>Left Merge >Straight|Maintain Medium Speed") == (
        ("Straight", "Left Merge", "Straight"), ("Maintain Medium Speed",))


@pytest.mark.parametrize(("text", "message"), [
    ("Straight > Left Merge", "exactly one ' | '"),
    ("Straight | Maintain Medium Speed | Stopped", "exactly one ' | '"),
    ("Straight > Left Merj | Maintain Medium Speed", "Did you mean 'Left Merge'"),
    ("Straight >  | Stopped", "empty lateral label"),
])
def test_parse_sdl_errors_name_the_problem(text, message):
    with pytest.raises(LabelTableError, match=message):
        parse_sdl(text)


def test_level_vocabulary_is_enforced():
    with pytest.raises(LabelTableError, match="action-level lateral label 'Left Turn'"):
        parse_sdl("Left Turn | Maintain Medium Speed", level="action")
    assert parse_sdl("Left Turn | Maintain Speed", level="trend")


def test_label_set_encodes_distinct_labels_in_order_of_first_use(small_labels):
    ls = label_set(small_labels)
    assert ls.level == "action"
    assert list(ls.labels) == [CRUISE, LEFT_MERGE, STOP_AND_GO]
    assert ls.code.tolist() == [0, 1, 0, 1, 2, 0]
    assert ls.counts.tolist() == [3, 2, 1]
    assert ls.first_row.tolist() == [0, 1, 4]
    assert ls.n_lateral.tolist() == [1, 3, 1]
    assert ls.n_longitudinal.tolist() == [1, 1, 3]


def test_label_set_picks_the_level_or_asks_for_one(small_labels):
    two = small_labels.copy()
    two["level"] = "action"
    trend = label_rows([("s1", "1", "Straight | Maintain Speed")], level="trend")
    import pandas as pd

    both = pd.concat([two, trend], ignore_index=True)
    with pytest.raises(LabelTableError, match="2 levels"):
        label_set(both)
    assert len(label_set(both, "trend")) == 1
    with pytest.raises(LabelTableError, match="no labels at level 'maneuver'"):
        label_set(both, "maneuver")
    with pytest.raises(UnknownNameError, match="Did you mean 'action'"):
        label_set(both, "actoin")


def test_label_table_errors_name_row_and_fix(small_labels):
    bad = small_labels.copy()
    bad.loc[4, "sdl"] = CRUISE  # sdl no longer lateral | longitudinal
    with pytest.raises(LabelTableError, match=r"row 4 \(scenario_id='s2', track_id='2'.*"
                       r"tap-bench label"):
        label_set(bad)
    with pytest.raises(LabelTableError, match=r"missing column.*'sdl'"):
        label_set(small_labels.drop(columns=["sdl"]))
    bad = small_labels.copy()
    bad.loc[2, ["lateral", "sdl"]] = ["Straight > Left Turn", "Straight > Left Turn | "
                                      "Maintain Medium Speed"]
    with pytest.raises(LabelTableError, match=r"row 2 .*'sdl'.*action-level lateral label"):
        label_set(bad)
    bad = small_labels.copy()
    bad.loc[1, "lateral"] = np.nan
    with pytest.raises(LabelTableError, match="'lateral' is empty at row 1"):
        label_set(bad)
