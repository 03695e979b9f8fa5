"""The measures inside interaction contexts are picked by their entries (issue 22): every
registered measure whose entry says ``in_context`` is taken inside each context by its own
function, and its occurrences reduced as the entry says; none is named by the contexts."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.measures import MEASURES, ego_measures, register_measure
from tap_bench.bench.scores.contexts import (
    CONTEXT_OWN_MEASURES,
    compare_contexts,
    context_measures,
    context_occurrences,
)
from tap_bench.errors import RegistrationError
from tap_bench.stats.bootstrap import BootstrapConfig

from .test_contexts import cut_in_scene

ROOT = Path(__file__).resolve().parents[2]


def test_the_contexts_take_the_entries_that_say_in_context():
    assert [m.name for m in context_measures()] == [
        "min_headway_s", "min_ttc_s", "rms_jerk", "peak_decel", "reaction_time_s", "braked"]
    assert {m.name: m.in_context for m in context_measures()} == {
        "min_headway_s": "min", "min_ttc_s": "min", "rms_jerk": "mean", "peak_decel": "max",
        "reaction_time_s": "first", "braked": "first"}
    assert MEASURES["min_ttc_s"].to_dict()["in_context"] == "min"
    assert MEASURES["crashed"].in_context == ""


@pytest.fixture
def closest_gap():
    """A user's measure taken inside contexts: the smallest bumper gap to the leader."""
    def smallest_gap(steps):
        gap = np.where(np.isnan(steps.gap), np.inf, steps.gap)
        out = np.minimum.reduceat(gap, steps.starts) if steps.n_episodes else np.zeros(0)
        return np.where(np.isfinite(out), out, np.nan)

    register_measure("min_gap_m", unit="m", higher_is_better=True, margin=1.0,
                     description="smallest gap to the leader", in_context="min")(smallest_gap)
    register_measure("gap_not_in_contexts", unit="m", higher_is_better=True, margin=1.0,
                     description="the same, not in contexts")(smallest_gap)
    yield smallest_gap
    MEASURES.unregister("min_gap_m")
    MEASURES.unregister("gap_not_in_contexts")


def test_a_user_measure_with_in_context_is_measured_and_compared_in_each_context(
        closest_gap):
    scenes = [cut_in_scene(s, brake_at=4.0 + 0.1 * s, policy=p) for p in ("a", "b")
              for s in range(6)]
    table = pd.concat(scenes, ignore_index=True)
    occ = context_occurrences(table)
    assert "min_gap_m" in occ.columns and "gap_not_in_contexts" not in occ.columns
    # an occurrence's value is the measure's own function over the ego's steps inside it:
    # the whole scene cut to the run's span gives the same number
    cut = occ[occ["context"] == "Cut-in"].iloc[0]
    scene = table[table["scenario_id"] == cut["scenario_id"]]
    inside = scene[(scene["t"] >= cut["t_start"] - 1e-9) & (scene["t"] < cut["t_end"] - 1e-9)]
    alone = ego_measures(inside.assign(t=inside["t"] - cut["t_start"]))
    assert cut["min_gap_m"] == pytest.approx(alone["min_gap_m"].iat[0], abs=1e-6)
    rows = compare_contexts(occ, "a", "b", config=BootstrapConfig(n_resamples=200),
                            min_pairs=3)
    assert "min_gap_m" in set(rows["measure"])
    assert "gap_not_in_contexts" not in set(rows["measure"])


def test_no_leader_inside_a_context_has_no_minimum():
    # SPEC 6 / issue 21: "no leader" is not a 10 s observation, in a context as in an
    # episode: a run without a leader on any scored step has NaN, not the cap
    occ = context_occurrences(cut_in_scene(0, brake_at=4.0, policy="p"))
    free = occ[occ["context"] == "Free Driving"]
    assert len(free) and free["min_ttc_s"].isna().all() and free["min_headway_s"].isna().all()


def test_a_bad_in_context_is_refused():
    with pytest.raises(RegistrationError, match="in_context"):
        register_measure("bad_context", unit="m", higher_is_better=True, margin=1.0,
                         description="x", in_context="median")(lambda steps: steps.speed)
    assert "bad_context" not in MEASURES


def test_the_contexts_name_no_measure():
    # the contexts module reads entries by their in_context field, never a measure by name
    names = "|".join(m.name for m in MEASURES)
    text = (ROOT / "tap_bench" / "bench" / "scores" / "contexts.py").read_text()
    assert not re.search(rf"""MEASURES\[\s*["']({names})["']\s*\]""", text)
    assert all(m.function is None for m in CONTEXT_OWN_MEASURES)
