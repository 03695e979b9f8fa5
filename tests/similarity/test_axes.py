"""Search, uniqueness, coverage and novelty on chosen axes (the interaction axis of SPEC 7)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.scores.coverage import corpus_reference, coverage, vocabulary_reference
from tap_bench.bench.scores.novelty import novelty
from tap_bench.errors import LabelTableError, UnknownNameError
from tap_bench.sdl import check_axes
from tap_bench.similarity import search, unique_labels
from tap_bench.similarity.sdl_distance import label_set, sdl_levenshtein
from tap_bench.similarity.unique import label_counts


def table() -> pd.DataFrame:
    """Four egos doing the same manoeuvre, two of them cut in on; a non-ego (no
    interaction label)."""
    rows = [("s1", "ego", "Straight", "Maintain Speed", "Following"),
            ("s2", "ego", "Straight", "Maintain Speed", "Free Driving > Cut-in > Following"),
            ("s3", "ego", "Straight", "Maintain Speed", "Free Driving > Cut-in > Following"),
            ("s4", "ego", "Straight", "Maintain Speed", "Free Driving"),
            ("s4", "7", "Straight", "Decelerate", None)]
    out = pd.DataFrame(rows, columns=["scenario_id", "track_id", "lateral", "longitudinal",
                                      "interaction"])
    out["sdl"] = out["lateral"] + " | " + out["longitudinal"]
    out["level"] = "maneuver"
    return out


def test_axes_are_checked_and_ordered():
    assert check_axes("interaction,lateral") == ("lateral", "interaction")
    assert check_axes(None) == ("lateral", "longitudinal")
    with pytest.raises(UnknownNameError, match="interaction"):
        check_axes("interactions")
    with pytest.raises(LabelTableError, match="distinct"):
        check_axes(["lateral", "lateral"])


def test_search_on_the_interaction_axis():
    labels = table()
    # on TAP's axes the four egos are alike
    assert len(search(labels, "Straight | Maintain Speed")) == 4
    found = search(labels, "Free Driving > Cut-in > Following", axes="interaction")
    assert list(found["scenario_id"]) == ["s2", "s3"]
    assert (found["label"] == "Free Driving > Cut-in > Following").all()
    near = search(labels, "Straight | Maintain Speed | Free Driving > Following",
                  axes=("lateral", "longitudinal", "interaction"), metric="levenshtein",
                  d_sim=1)
    # Following (1 deletion), Free Driving (1 deletion); the cut-ins are 1 deletion away too
    assert set(near["scenario_id"]) == {"s1", "s2", "s3", "s4"}
    assert sdl_levenshtein("Following", "Free Driving > Cut-in > Following",
                           axes="interaction") == 2


def test_rows_without_an_interaction_label_are_left_out_and_a_table_without_them_fails():
    ls = label_set(table(), axes="interaction")
    assert len(ls) == 4 and ls.axes == ("interaction",)
    with pytest.raises(LabelTableError, match="--interactions"):
        label_set(table().drop(columns="interaction"), axes="interaction")
    with pytest.raises(LabelTableError, match="Cut in"):
        search(table(), "Cut in", axes="interaction")


def test_unique_and_counts_on_the_interaction_axis():
    labels = table()
    # on TAP's axes nobody is unique but track 7; with the interaction axis s1 and s4 are
    assert list(unique_labels(labels)["scenario_id"]) == ["s4"]
    uniq = unique_labels(labels, axes=("lateral", "longitudinal", "interaction"))
    assert sorted(uniq["scenario_id"]) == ["s1", "s4"]
    assert "n_interaction" in uniq.columns
    counts = label_counts(labels, axes="interaction")
    assert counts.iloc[0]["interaction"] == "Free Driving > Cut-in > Following"
    assert counts.iloc[0]["count"] == 2 and counts.iloc[0]["n_actions"] == 3


def test_coverage_and_novelty_on_the_interaction_axis():
    labels = table()
    axes = ("lateral", "longitudinal", "interaction")
    ref = corpus_reference(labels, "maneuver", tracks="all", axes=axes)
    assert len(ref) == 3  # the non-ego has no interaction label
    agent = pd.DataFrame({"lateral": ["Straight"] * 3, "longitudinal": ["Maintain Speed"] * 3,
                          "interaction": ["Following", "Following > Cut-out", "Free Driving"],
                          "sdl": "Straight | Maintain Speed", "env": "e",
                          "scenario_id": ["a", "b", "c"]})
    from tap_bench.labels import label_text
    from tap_bench.stats.bootstrap import BootstrapConfig

    cv = coverage(label_text(agent, axes), ref,
                  rng=BootstrapConfig().rng("coverage", ref.description))
    assert cv.coverage == pytest.approx(2 / 3)
    nv = novelty(agent, ref, axes=axes)
    assert nv.n_novel == 1 and list(nv.labels["label"]) == [
        "Straight | Maintain Speed | Following > Cut-out"]
    vocab = vocabulary_reference("maneuver", axes=axes)
    assert "Cut-in" in set(vocab.items) and "Straight" in set(vocab.items)
    assert np.isclose(vocab.weights.sum(), 1)
