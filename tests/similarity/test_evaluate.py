"""The paper's experiments on sets whose mismatch rates are known by construction."""

from __future__ import annotations

import json

import numpy as np
import pytest
from similarity_helpers import pairs_of_cruises, triples

from tap_bench.similarity import brute_force_nearest, evaluate, normalised_shapes
from tap_bench.similarity.evaluate import markdown
from tap_bench.similarity.figures import write_evaluation


def test_pairs_known_by_construction():
    table = pairs_of_cruises()
    ev = evaluate(table, progress=False, timing_trajectories=4)
    s = ev.summary
    # the construction holds: partners are mutual nearest neighbours by both metrics
    partner = np.arange(14) ^ 1
    assert ev.neighbours["ade_neighbour"].tolist() == partner.tolist()
    assert ev.neighbours["dtw_neighbour"].tolist() == partner.tolist()
    labels = ev.neighbours["sdl"].tolist()
    # rows: c0 base, c0 partner, c1 base, c1 partner (turns) ...
    assert labels[0] == labels[1] == labels[2] == "Straight | Maintain Slow Speed"
    assert labels[3] == "Straight > Gradual Left Turn > Straight | Maintain Slow Speed"
    assert labels[7] == labels[9] == ("Straight > Gradual Left Turn > Straight | Maintain "
                                      "Medium Speed")
    for m in ("ade", "dtw"):
        assert s[m]["different_label"] == 6
        assert s[m]["share_different"] == pytest.approx(6 / 14)
        assert s[m]["lateral_different"] == 6
        assert s[m]["longitudinal_different"] == 0
    # the turners at 18 and 23 m/s share a label; the one at 8 m/s, the only slow turner,
    # is the one unique trajectory
    assert s["sdl_exact"]["unique_labels"] == 1
    assert ev.unique[["scenario_id", "track_id"]].values.tolist() == [["c1", "partner"]]


def test_triples_known_by_construction(tmp_path):
    table, labels = triples()
    shapes = normalised_shapes(table, labels)
    ade = brute_force_nearest(shapes, metric="ade")
    dtw = brute_force_nearest(shapes, metric="dtw")
    r, t, o = np.arange(0, 12, 3), np.arange(1, 12, 3), np.arange(2, 12, 3)
    assert (ade.neighbour[r] == o).all() and (dtw.neighbour[r] == t).all()
    assert (ade.neighbour[t] == r).all() and (dtw.neighbour[t] == r).all()
    assert (ade.neighbour[o] == r).all() and (dtw.neighbour[o] == r).all()

    ev = evaluate(table, labels, object_types=None, progress=False, timing_trajectories=3)
    s = ev.summary
    assert s["ade"]["different_label"] == 4 and s["dtw"]["different_label"] == 8
    assert s["ade"]["share_different"] == pytest.approx(1 / 3)
    assert s["dtw"]["share_different"] == pytest.approx(2 / 3)
    assert s["ade"]["longitudinal_different"] == 4 and s["ade"]["lateral_different"] == 0
    assert s["sdl_exact"]["unique_labels"] == 0
    np.testing.assert_allclose(ev.neighbours["ade_distance"].to_numpy()[r], 0.285)
    # DTW(R, T): everything warps onto R except R's last step
    last_step = [np.hypot(1.0, 5 * c * (19**2 - 18**2) / 19**2) for c in range(4)]
    np.testing.assert_allclose(ev.neighbours["dtw_distance"].to_numpy()[r], last_step)

    # a sample of queries answers the same for those queries
    sample = evaluate(table, labels, object_types=None, queries=5, seed=3, progress=False,
                      timing_trajectories=3)
    q = sample.neighbours["query"].to_numpy()
    assert len(q) == 5 and sample.summary["data"]["sampled"]
    assert (sample.neighbours["dtw_neighbour"].to_numpy() == dtw.neighbour[q]).all()

    written = write_evaluation(ev, tmp_path / "eval")
    names = sorted(p.name for p in written)
    assert names == ["evaluation.json", "evaluation.md", "fig5_similarity.png",
                     "fig6_unique.png", "neighbours.parquet", "unique.parquet"] or \
        names == ["evaluation.json", "evaluation.md", "fig5_similarity.png",
                  "neighbours.parquet", "unique.parquet"]
    assert json.loads((tmp_path / "eval" / "evaluation.json").read_text())["dtw"][
        "different_label"] == 8
    assert (tmp_path / "eval" / "fig5_similarity.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in (tmp_path / "eval").iterdir() if p.name.startswith(".")]
    md = markdown(ev)
    assert "| ADE | 4 of 12 | 33.33 % |" in md and "| DTW | 8 of 12 | 66.67 % |" in md
    assert "7,924 of 25,889" in md


def test_full_length_by_default_and_stationary_queries_apart():
    import pandas as pd

    import tap_bench as tb

    names = ("parked", "cruise_slow", "cruise_medium", "gradual_left_turn")
    tracks = [tb.behaviour(n, scenario_id="s") for n in names]
    tracks.append(tb.behaviour("parked", scenario_id="s", track_id="parked_2", x0=50.0))
    late = tb.behaviour("cruise_slow", scenario_id="s", track_id="late").iloc[20:]
    table = pd.concat([*tracks, late], ignore_index=True)
    ev = evaluate(table, object_types=None, progress=False, timing_trajectories=2)
    d = ev.summary["data"]
    # 'late' starts at 2 s, not at the scenario's first time stamp: not full length
    assert d["segments"] == "full" and d["trajectories"] == 5
    assert d["segments_before_selection"] == 6
    assert d["stationary_trajectories"] == 2 and d["stationary_queries"] == 2
    assert ev.neighbours.set_index("track_id")["stationary"].to_dict() == {
        "parked": True, "cruise_slow": False, "cruise_medium": False,
        "gradual_left_turn": False, "parked_2": True}
    for m in ("ade", "dtw"):
        assert ev.summary[m]["stationary"]["queries"] == 2
        assert ev.summary[m]["moving"]["queries"] == 3
        # the two parked cars are each other's neighbours at distance 0, with one label
        assert ev.summary[m]["stationary"]["different_label"] == 0
        assert ev.summary[m]["stationary"]["median_distance"] == 0.0
    every = evaluate(table, object_types=None, segments="all", progress=False,
                     timing_trajectories=2)
    assert every.summary["data"]["trajectories"] == 6
    assert "Moving and stationary queries apart" in markdown(ev)
