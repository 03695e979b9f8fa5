"""SDL similarity search: within d_sim of a label or of a trajectory, and all against all."""

from __future__ import annotations

import numpy as np
import pytest
from similarity_helpers import CRUISE, GRADUAL_LEFT, LEFT_MERGE, label_rows

from tap_bench import sdl
from tap_bench.errors import LabelTableError, UnknownNameError
from tap_bench.similarity import (
    exact_matches,
    label_set,
    levenshtein_nearest,
    sdl_levenshtein,
    search,
    search_like,
)


def test_exact_search_returns_every_row_with_the_label(small_labels):
    found = search(small_labels, CRUISE)
    assert found["track_id"].tolist() == ["1", "3", "3"]
    assert found["scenario_id"].tolist() == ["s1", "s1", "s2"]
    assert (found["distance"] == 0).all()
    assert search(small_labels, GRADUAL_LEFT).empty


def test_exact_search_with_d_sim_one_returns_everything(small_labels):
    # g_SDL is 0 or 1: within 1 is the whole table, nearest (the exact label) first
    found = search(small_labels, CRUISE, d_sim=1)
    assert len(found) == 6
    assert found["distance"].tolist() == [0, 0, 0, 1, 1, 1]


def test_levenshtein_search_within_d_sim(small_labels):
    found = search(small_labels, GRADUAL_LEFT, metric="levenshtein", d_sim=1)
    # Left Merge is one substitution away; cruise two insertions; stop-and-go further
    assert found["sdl"].tolist() == [LEFT_MERGE, LEFT_MERGE]
    assert found["distance"].tolist() == [1, 1]
    found = search(small_labels, GRADUAL_LEFT, metric="levenshtein", d_sim=2)
    assert found["sdl"].tolist() == [LEFT_MERGE, LEFT_MERGE, CRUISE, CRUISE, CRUISE]


def test_search_like_leaves_the_reference_out(small_labels):
    found = search_like(small_labels, "s1", "3")
    assert list(zip(found["scenario_id"], found["track_id"], strict=True)) == [
        ("s1", "1"), ("s2", "3")]
    assert search_like(small_labels, "s2", "2").empty  # the unique stop-and-go


def test_search_errors(small_labels):
    with pytest.raises(UnknownNameError, match="Did you mean 'levenshtein'"):
        search(small_labels, CRUISE, metric="levenstein")
    with pytest.raises(LabelTableError, match="d_sim"):
        search(small_labels, CRUISE, d_sim=-1)
    with pytest.raises(LabelTableError, match="scenario 's1' has no labelled track '9'"):
        search_like(small_labels, "s1", "9")
    with pytest.raises(LabelTableError, match="Did you mean 's1'"):
        search_like(small_labels, "s11", "1")
    two = small_labels.copy()
    two.loc[len(two)] = two.loc[0]
    two.loc[len(two) - 1, "segment"] = 1
    with pytest.raises(LabelTableError, match="2 labelled segments"):
        search_like(two, "s1", "1")
    assert len(search_like(two, "s1", "1", 1)) == 3


def _random_labels(n: int, seed: int):
    rng = np.random.default_rng(seed)
    lat_v = sdl.vocabulary("action", "lateral")
    lon_v = sdl.vocabulary("action", "longitudinal")
    rows = []
    for i in range(n):
        lat = " > ".join(rng.choice(lat_v[:4], rng.integers(1, 4)))
        lon = " > ".join(rng.choice(lon_v[:4], rng.integers(1, 3)))
        rows.append((f"s{i % 7}", str(i), f"{lat} | {lon}"))
    return label_rows(rows)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_matches_for_all_equal_the_pairwise_answer(seed):
    labels = _random_labels(150, seed)
    em = exact_matches(labels)
    text = labels["sdl"].to_numpy()
    for i in range(len(labels)):
        expected = [j for j in range(len(labels)) if j != i and text[j] == text[i]]
        assert em.matches(i).tolist() == expected
        assert em.n_matches[i] == len(expected)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_levenshtein_nearest_equals_brute_force_with_lowest_index_ties(seed):
    labels = _random_labels(120, seed)
    nn = levenshtein_nearest(label_set(labels), chunk=7)
    text = labels["sdl"].tolist()
    for i in range(len(text)):
        d = [sdl_levenshtein(text[i], text[j]) if j != i else 10**9 for j in range(len(text))]
        best = min(d)
        assert nn.distance[i] == best
        assert nn.neighbour[i] == d.index(best)
        assert nn.n_at_distance[i] == d.count(best)


def test_levenshtein_nearest_of_a_single_row():
    nn = levenshtein_nearest(label_rows([("s", "1", CRUISE)]))
    assert nn.distance.tolist() == [-1] and nn.neighbour.tolist() == [-1]
