"""No measure picked by name outside its entry (issue 22): the verdict's families, the
trade-off view's axes and the gate's weights come from each entry's ``role``, ``words`` and
``gate_weight``; a user measure that says its role shows up where that role is read."""

from __future__ import annotations

import re
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.measures import (
    MEASURE_ROLES,
    MEASURES,
    SCENE_MEASURES,
    Measure,
    measures_with_role,
    register_measure,
)
from tap_bench.bench.report.figures import _tradeoff_plot
from tap_bench.bench.scores.scoring import score
from tap_bench.bench.scores.verdict import verdict_table
from tap_bench.bench.suite import default_weights
from tap_bench.errors import RegistrationError
from tap_bench.stats.bootstrap import BootstrapConfig

from .conftest import make_episodes

ROOT = Path(__file__).resolve().parents[2]


def test_the_built_in_entries_say_their_roles():
    assert [m.name for m in measures_with_role("safety", MEASURES)] == [
        "crashed", "min_headway_s", "min_ttc_s"]
    assert [m.name for m in measures_with_role("progress")] == ["mean_speed", "route_progress"]
    assert [m.name for m in measures_with_role("comfort")] == ["rms_jerk"]
    assert MEASURES["mean_speed"].words == ("faster", "slower")
    assert {m.name: m.gate_weight for m in MEASURES if m.gate_weight} == {
        "crashed": 0.65, "min_headway_s": 0.1, "min_ttc_s": 0.1}
    assert all(m.role in MEASURE_ROLES for m in (*MEASURES, *SCENE_MEASURES))
    assert MEASURES["rms_jerk"].to_dict()["role"] == "comfort"


def test_a_bad_role_words_or_weight_is_refused():
    def f(steps):
        return np.zeros(steps.n_episodes)

    for fields, what in (({"role": "speed"}, "role"), ({"words": ("only one",)}, "words"),
                         ({"gate_weight": 1.5}, "gate_weight")):
        with pytest.raises(RegistrationError, match=what):
            register_measure("bad_one", unit="m", higher_is_better=True, margin=1.0,
                             description="x", **fields)(f)
        assert "bad_one" not in MEASURES
    with pytest.raises(RegistrationError, match="unknown measure role"):
        measures_with_role("speedy")


def test_default_words_follow_the_direction():
    up = Measure("km", "km", True, "distance", 1.0, None, label="distance")
    down = Measure("lag", "s", False, "lag", 1.0, None)
    assert up.words == ("higher distance", "lower distance")
    assert down.words == ("lower lag", "higher lag")


@pytest.fixture
def user_measures():
    """A progress measure and a comfort measure a user registers with their roles."""

    def zeros(steps):
        return np.zeros(steps.n_episodes)

    register_measure("distance_km", unit="km", higher_is_better=True, margin=0.5,
                     description="distance driven", label="distance", role="progress")(zeros)
    register_measure("lateral_jerk", unit="m/s^3", higher_is_better=False, margin=1.0,
                     description="RMS lateral jerk", label="lateral jerk", role="comfort",
                     words=("calmer", "jumpier"))(zeros)
    yield
    MEASURES.unregister("distance_km")
    MEASURES.unregister("lateral_jerk")


def _scores():
    rng = np.random.default_rng(0)
    rows = []
    for policy, speed in (("idm", 20.0), ("fast", 24.0)):
        for s in range(10):
            rows.append({"env": "highway", "policy": policy, "seed": s,
                         "scenario_id": f"highway/{policy}/s{s}", "sdl": "Straight | Cruise",
                         "crashed": bool(rng.random() < 0.3), "mean_speed": rng.normal(speed),
                         "min_headway_s": 2.0, "min_ttc_s": 5.0, "rms_jerk": 3.0,
                         "distance_km": rng.normal(speed / 10, 0.1),
                         "lateral_jerk": rng.normal(1.0 if policy == "idm" else 3.0, 0.1)})
    return score(make_episodes(rows), reference_policy="idm", level="maneuver",
                 config=BootstrapConfig(n_resamples=200))


def test_a_user_progress_measure_gets_its_own_row_of_the_tradeoff_view(user_measures):
    scores = _scores()
    _, svg = _tradeoff_plot(scores, "idm")
    texts = ["".join(t.itertext()) for t in ElementTree.fromstring(svg).iter(
        "{http://www.w3.org/2000/svg}text")]
    assert "distance [km] (progress)" in texts and "mean speed [m/s] (progress)" in texts
    assert "highway: crash rate / distance" in texts
    assert sum(t.startswith("crash rate [%]") for t in texts) == 2  # one per row


def test_without_a_progress_role_there_is_no_tradeoff_view(monkeypatch):
    # the view reads roles, not names: the built-in mean speed without its role is not drawn
    scores = _scores()
    assert _tradeoff_plot(scores, "idm") is not None
    from tap_bench.bench.report import figures as report_figures

    monkeypatch.setattr(report_figures, "measures_with_role",
                        lambda role: () if role == "progress" else measures_with_role(role))
    assert _tradeoff_plot(scores, "idm") is None


def test_the_verdict_reads_a_user_comfort_measure_with_its_words(user_measures):
    rows = [{"env": "all", "measure": m, "higher_is_better": MEASURES[m].higher_is_better,
             "diff": d, "diff_low": d - 0.5, "diff_high": d + 0.5, "policy_a": "fast",
             "policy_b": "idm"}
            for m, d in (("crashed", 0.0), ("mean_speed", 4.0), ("rms_jerk", 0.0),
                         ("distance_km", 0.4), ("lateral_jerk", 2.0))]
    table = verdict_table(pd.DataFrame(rows)).set_index("area")
    assert table.loc["efficiency", "word"] == (
        "faster, no RMS jerk difference detected, no distance difference detected, jumpier")
    assert "lateral jerk +2.00 m/s³" in table.loc["efficiency", "evidence"]


def test_the_gate_weights_come_from_the_entries(user_measures):
    weights = default_weights()
    assert weights["crashed"] == 0.65 and weights["min_ttc_s"] == 0.1
    rest = [k for k in weights if k not in ("crashed", "min_ttc_s", "min_headway_s")]
    assert "distance_km" in rest
    assert all(weights[k] == pytest.approx(0.15 / len(rest)) for k in rest)


def test_no_consumer_names_a_built_in_measure():
    # outside the measures' own module, no code of the bench picks a measure by its name
    names = "|".join(m.name for m in (*MEASURES, *SCENE_MEASURES))
    pattern = re.compile(rf"""(==|!=)\s*["']({names})["']|["']({names})["']\s*(==|!=)""")
    found = []
    for path in sorted((ROOT / "tap_bench").rglob("*.py")):
        if path.name == "measures.py":
            continue
        for k, line in enumerate(path.read_text().splitlines(), 1):
            if pattern.search(line):
                found.append(f"{path.relative_to(ROOT)}:{k}: {line.strip()}")
    assert not found, "\n".join(found)


def test_the_against_the_human_summary_reads_safety_rates_by_role():
    from tap_bench.bench.scores.agreement import SCENE_SUMMARY_MEASURES, scene_summary_measures

    assert scene_summary_measures() == SCENE_SUMMARY_MEASURES == (
        "crashed", "crashed_at_fault", "off_road", "route_progress", "ran_red_light", "log_ade",
        "log_fde")

    def f(steps):
        return np.zeros(steps.n_episodes)

    register_measure("hit_kerb", unit="share", higher_is_better=False, margin=0.1,
                     description="touched a kerb", kind="rate", role="safety")(f)
    try:
        assert scene_summary_measures()[:2] == ("crashed", "hit_kerb")
    finally:
        MEASURES.unregister("hit_kerb")
