"""Measures inside interaction contexts and the comparison by context, on hand-made data."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.scores.contexts import compare_contexts, context_occurrences
from tap_bench.stats.bootstrap import BootstrapConfig

T = np.round(np.arange(100) / 10, 10)  # 10 s


def cut_in_scene(seed: int, brake_at: float, policy: str) -> pd.DataFrame:
    """The ego at 20 m/s; a car 25 m ahead in the next lane (4 m left) moves into the ego's
    lane between 2 and 5 s (it crosses the corridor edge at 3.6 s: the Cut-in run starts
    at 2.6 s); the ego brakes at 3 m/s^2 from ``brake_at`` for 1 s."""
    v = 20 - 3 * np.clip(T - brake_at, 0, 1)
    x = np.concatenate([[0], np.cumsum((v[1:] + v[:-1]) / 2 * 0.1)])
    u = np.clip((T - 2) / 3, 0, 1)
    y_cut = 2 + 2 * np.cos(np.pi * u)
    ego = pd.DataFrame({"t": T, "x": x, "y": 0.0, "heading": 0.0, "speed": v,
                        "track_id": "ego", "is_ego": True})
    dy = np.gradient(y_cut, T)
    cut = pd.DataFrame({"t": T, "x": 25 + 20 * T, "y": y_cut,
                        "heading": np.arctan2(dy, 20.0), "speed": np.hypot(20, dy),
                        "track_id": "cutter", "is_ego": False})
    scene = pd.concat([ego, cut], ignore_index=True)
    return scene.assign(scenario_id=f"{policy}/s{seed}", env="e", policy=policy, seed=seed,
                        object_type="vehicle", crashed=False)


def test_reaction_time_from_the_cut_in_to_the_first_braking():
    occ = context_occurrences(cut_in_scene(0, brake_at=4.0, policy="p"))
    cut = occ[occ["context"] == "Cut-in"].iloc[0]
    assert cut["other_track_id"] == "cutter"
    assert cut["t_start"] == pytest.approx(2.6, abs=0.15)
    # first step with a <= a_dec (-1.37 m/s^2): the braking starts at 4.0 s (first
    # difference of speed: the step at 4.1 s)
    assert cut["reaction_time_s"] == pytest.approx(4.1 - cut["t_start"], abs=0.05)
    assert cut["braked"] == 1.0
    assert cut["peak_decel"] == pytest.approx(3.0, abs=0.01)
    never = context_occurrences(cut_in_scene(0, brake_at=50.0, policy="p"))
    cut = never[never["context"] == "Cut-in"].iloc[0]
    assert np.isnan(cut["reaction_time_s"]) and cut["braked"] == 0.0


def test_compare_by_context_pairs_seeds_where_both_meet_it():
    # A brakes 1 s (odd seeds 1.1 s) after B on every seed: reaction time +1.05 s, paired
    scenes = [cut_in_scene(s, 3.0 + 0.1 * s, "B") for s in range(6)]
    scenes += [cut_in_scene(s, 4.0 + 0.1 * s + 0.1 * (s % 2), "A") for s in range(6)]
    occ = context_occurrences(pd.concat(scenes, ignore_index=True))
    out = compare_contexts(occ, "A", "B", config=BootstrapConfig(n_resamples=500))
    row = out[(out["context"] == "Cut-in") & (out["measure"] == "reaction_time_s")].iloc[0]
    assert row["n_pairs"] == 6 and row["method"].startswith("paired by seed")
    assert row["diff"] == pytest.approx(1.05, abs=0.01)
    assert row["diff_low"] < row["diff"] < row["diff_high"]  # a t interval over 6 seeds
    braked = out[(out["context"] == "Cut-in") & (out["measure"] == "braked")].iloc[0]
    # both always braked: difference 0, but a score interval, never [0, 0]
    assert braked["diff"] == 0 and braked["diff_low"] < -0.2 and braked["diff_high"] > 0.2
    # B meets it on seeds 0-5, A only on 0-2: three pairs are too few for min_pairs 5
    few = occ[~((occ["policy"] == "A") & (occ["seed"] > 2))]
    out = compare_contexts(few, "A", "B", config=BootstrapConfig(n_resamples=500))
    row = out[(out["context"] == "Cut-in") & (out["measure"] == "reaction_time_s")].iloc[0]
    assert row["n_pairs"] == 3 and row["method"] == "too few" and np.isnan(row["diff_low"])


def test_cli_contexts_and_gap(tmp_path, capsys):
    from tap_bench.cli import main

    scenes = [cut_in_scene(s, 3.0 + 0.1 * s, "B") for s in range(5)]
    scenes += [cut_in_scene(s, 4.0 + 0.2 * s, "A") for s in range(5)]
    src = tmp_path / "runs.parquet"
    pd.concat(scenes, ignore_index=True).to_parquet(src)
    out = tmp_path / "contexts.csv"
    assert main(["contexts", str(src), "--a", "A", "--b", "B", "-o", str(out),
                 "--min-pairs", "3"]) == 0
    text = capsys.readouterr().out
    assert "e / Cut-in: 5 seed(s) where both meet it" in text
    table = pd.read_csv(out)
    row = table[(table["context"] == "Cut-in") & (table["measure"] == "reaction_time_s")]
    assert row["diff"].iloc[0] == pytest.approx(1.2, abs=0.01)  # 1 s + 0.1 s * mean(0..4)
    assert (tmp_path / "contexts.occurrences.csv").is_file()
    # the gap of A from B's trajectories as the "real" reference: same labels, no gap
    assert main(["gap", str(src), "--reference", str(src), "--min-speed", "0",
                 "--max-speed", "50", "-o", str(tmp_path / "gap.csv")]) == 0
    gap = pd.read_csv(tmp_path / "gap.csv").set_index("policy")
    assert set(gap.index) == {"A", "B"}
    assert (gap["gap"] <= gap["gap_high"]).all() and (gap["gap"] >= 0).all()
