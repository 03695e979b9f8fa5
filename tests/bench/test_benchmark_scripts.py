"""Scripts of ``benchmarks/`` that choose agents or reproduce a figure of the docs: they
drive policies as a bench run does."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(PROJECT_ROOT / "benchmarks"))

import agents_validation  # noqa: E402
import bench_lane_change_merges  # noqa: E402


@pytest.mark.parametrize("name", ["lane-keeping", "ppo-womd-seed0"])
def test_validation_configures_each_policy_as_a_bench_run_does(monkeypatch, name):
    from tap_bench.sim.policies import load_policy
    from tap_bench.sim.rollout import policy_overrides
    from tap_bench.sim.womd_scene import WomdScenes

    monkeypatch.setattr(agents_validation, "WomdEnv", lambda scenes, record: scenes)
    scenes = WomdScenes(("scenes.tfrecord",))
    policy = load_policy(name)
    driven = agents_validation.policy_env(scenes, policy)
    assert driven.config == scenes.with_overrides(policy_overrides(policy)).config


def test_every_vehicle_counts_each_vehicle_with_a_turn_once():
    # seed 0: the ego keeps its lane; vehicle 2 turns in two of its segments; seed 1: the
    # ego turns once
    labels = pd.DataFrame({
        "scenario_id": ["s0", "s0", "s0", "s0", "s1", "s1"],
        "track_id": ["1", "2", "2", "2", "1", "3"],
        "seed": [0, 0, 0, 0, 1, 1],
        "is_ego": [True, False, False, False, True, False],
        "lateral": ["Straight", "Left Turn", "Straight", "Right Turn",
                    "Straight > Left Turn", "Left Merge"]})
    figures = bench_lane_change_merges.vehicles_with_a_turn(labels)
    assert figures == {"vehicles": 4, "with_a_turn": 2, "egos": 2, "egos_with_a_turn": 1,
                       "which": ["seed 0 vehicle 2", "seed 1 vehicle 1 (ego)"]}


def _validation_episodes(fault_b: dict[int, list[int]]) -> pd.DataFrame:
    """Two drivers in each of 4 scenes: agent ``a`` (two seeds) never at fault, progress 0.8;
    ``b`` (one run) at fault on the drivers ``fault_b`` names per scene, progress 0.4."""
    rows = []
    for scene in range(4):
        for track in ("1", "2"):
            for policy, progress in (("a0", 0.8), ("a1", 0.8), ("b", 0.4)):
                fault = policy == "b" and int(track) in fault_b.get(scene, [])
                rows.append({"policy": policy, "scene": scene, "track": track,
                             "status": "ok", "route_progress": progress,
                             "crash_at_fault": fault, "off_road": False})
    return pd.DataFrame(rows)


def test_scene_intervals_separate_only_what_more_than_one_scene_shows():
    groups = {"a": ["a0", "a1"], "b": ["b"]}
    everywhere = agents_validation.scene_intervals(
        _validation_episodes({s: [1, 2] for s in range(4)}), groups, "a", n_resamples=200)
    b = everywhere.set_index("policy").loc["b"]
    assert b["d_at_fault"] == -1.0 and b["d_at_fault_high"] == -1.0
    assert b["d_iqm"] == pytest.approx(0.4) and b["d_iqm_low"] == pytest.approx(0.4)
    # b at fault in one scene only: a draw without that scene ties, so 0 stays inside
    one_scene = agents_validation.scene_intervals(
        _validation_episodes({0: [1, 2]}), groups, "a", n_resamples=200)
    b = one_scene.set_index("policy").loc["b"]
    assert b["d_at_fault"] == pytest.approx(-0.25)
    assert b["d_at_fault_low"] < -0.25 and b["d_at_fault_high"] == pytest.approx(0.0, abs=0.1)
    assert b["at_fault_low"] <= 0.0 + 0.1 and b["at_fault_high"] > 0.25


def test_seed_intervals_pool_the_seeds_over_the_drivers_each_seed_drove():
    eps = _validation_episodes({})
    eps.loc[eps["policy"] == "a1", "route_progress"] = 0.6
    out = agents_validation.seed_intervals(eps, ["a0", "a1"], n_resamples=200)
    assert out["iqm"] == pytest.approx(0.7) and out["at_fault"] == 0.0
    assert out["iqm_low_run"] < 0.7 < out["iqm_high_run"]
    assert out["iqm_low_task"] < 0.7 < out["iqm_high_task"]


def test_scene_intervals_of_an_at_fault_rate_stay_within_0_and_1():
    """The draws widened by sqrt(G / (G - 1)) about a small rate go below 0 (one scene of 4
    at fault: -0.019 before); a rate's interval is cut at 0 and 1, a difference's is not."""
    groups = {"a": ["a0", "a1"], "b": ["b"]}
    table = agents_validation.scene_intervals(
        _validation_episodes({0: [1]}), groups, "a", n_resamples=200).set_index("policy")
    assert (table["at_fault_low"] >= 0.0).all() and (table["at_fault_high"] <= 1.0).all()
    assert table.loc["b", "at_fault_high"] > 0.125 > table.loc["b", "at_fault_low"]
    assert table.loc["b", "d_at_fault_low"] < -0.125 < table.loc["b", "d_at_fault_high"]


def _fold_episodes() -> pd.DataFrame:
    """Fold A's seeds a0, a1 on scenes 0, 1, fold B's b0, b1 on scenes 2, 3, baseline ``c``
    on all four; two drivers a scene; progress 0.9 / 0.7 (a), 0.5 / 0.3 (b), 0.2 (c)."""
    rows = []
    for scene in range(4):
        fold = ("a0", "a1") if scene < 2 else ("b0", "b1")
        progress = (0.9, 0.7) if scene < 2 else (0.5, 0.3)
        for track in ("1", "2"):
            for policy, value in (*zip(fold, progress, strict=True), ("c", 0.2)):
                rows.append({"policy": policy, "scene": scene, "track": track, "status": "ok",
                             "route_progress": value, "crash_at_fault": policy == "c",
                             "off_road": False})
    return pd.DataFrame(rows)


def _fold_models(**changes) -> dict:
    """The training records of ``_fold_episodes``' models: a0, a1 (seeds 0, 1) trained on
    scenes 2, 3 and held out 0, 1; b0, b1 the other way round; ``changes`` replace some."""
    trained = agents_validation.Trained
    models = {f"a{k}": trained(k, (2, 3), (0, 1)) for k in range(2)}
    models.update({f"b{k}": trained(k, (0, 1), (2, 3)) for k in range(2)})
    return {**models, **changes}


def test_a_cross_fitted_run_is_the_same_seed_of_every_fold_on_its_held_out_scenes():
    eps, runs = agents_validation.cross_fitted(_fold_episodes(), "x", [["a0", "a1"],
                                                                       ["b0", "b1"]],
                                               _fold_models())
    assert runs == ["x#0", "x#1"]
    run0 = eps[eps["policy"] == "x#0"]
    assert sorted(run0["scene"]) == [0, 0, 1, 1, 2, 2, 3, 3]
    assert sorted(run0["route_progress"]) == [0.5] * 4 + [0.9] * 4
    table = agents_validation.summary(eps, ["c", *runs], {"x": runs}).set_index("policy")
    assert table.loc["x", "episodes"] == 16 and table.loc["c", "P(x further)"] == 1.0
    assert table.loc["c", "P(x fewer at fault)"] == 1.0
    seeds = agents_validation.seed_intervals(eps, runs, n_resamples=100)
    assert seeds["iqm"] == pytest.approx(0.6)  # 0.3, 0.5, 0.7, 0.9 over 16: the middle half


def test_a_cross_fitted_run_pairs_the_folds_models_by_their_training_seed():
    """Fold B named in another order: run 0 is still a0 with b0 (by position it was b1)."""
    eps, runs = agents_validation.cross_fitted(_fold_episodes(), "x", [["a0", "a1"],
                                                                       ["b1", "b0"]],
                                               _fold_models())
    assert runs == ["x#0", "x#1"]
    run0 = eps[eps["policy"] == "x#0"]
    assert sorted(set(run0["route_progress"])) == [0.5, 0.9]


def _trained(seed, train, held_out, refs=None):
    return agents_validation.Trained(seed, train, held_out, refs)


@pytest.mark.parametrize("name, folds, models, message", [
    ("x", [["a0", "a1"], ["b0"]], {}, "seeds"),
    ("x", [["a0", "b1"], ["b0", "a1"]], {"a1": _trained(1, (), (0, 1, 2, 3)),
                                          "b1": _trained(1, (), (0, 1, 2, 3))},
     "did not all drive the same scenes"),
    ("x", [["a0", "a1"], ["b0", "b1"]], {"a1": _trained(1, (0, 3), (1, 2))},
     "drove scenes it trained on: [0]"),
    # trained with no --hold-out: every scene a training scene, none held out
    ("x", [["a0", "a1"], ["b0", "b1"]], {"a1": _trained(1, (0, 1, 2, 3), ())},
     "drove scenes it trained on: [0, 1]"),
    ("x", [["a0", "a1"], ["b0", "b1"]], {"a1": _trained(1, None, ())},
     "drove scenes it trained on: [0, 1]"),
    ("x", [["a0", "a1"], ["b0", "b0"]], {}, "['b0'] named more than once"),
    ("x", [["a0", "a1"], ["b0", "b1"]], {"b1": _trained(2, (0, 1), (2, 3))},
     "training seeds [[0, 1], [0, 2]] differ"),
    ("x", [["a0", "a1"]], {}, "two or more"),
    ("", [["a0", "a1"], ["b0", "b1"]], {}, "needs a name"),
    ("x", [["a0", "a1"], ["b0", "typo"]], {}, "['typo'] not in the episode table"),
])
def test_cross_fitting_refuses_a_driver_seen_twice_or_by_a_model_trained_on_it(
        name, folds, models, message):
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        agents_validation.cross_fitted(_fold_episodes(), name, folds, _fold_models(**models))


def test_cross_fitting_refuses_folds_that_miss_drivers_the_baselines_drove():
    eps = _fold_episodes()
    without = eps[~((eps["scene"] == 3) & eps["policy"].isin(["b0", "b1"]))]
    with pytest.raises(ValueError, match=r"2 \(scene, track\) not driven by any fold"):
        agents_validation.cross_fitted(without, "x", [["a0", "a1"], ["b0", "b1"]],
                                       _fold_models(**{f"b{k}": _trained(k, (0, 1), (2, 3))
                                                       for k in range(2)}))
    # another policy, on a driver no other drove: a baseline by default, not if not named
    extra = pd.concat([eps, eps.iloc[:1].assign(policy="e", track="9")], ignore_index=True)
    with pytest.raises(ValueError, match=r"1 \(scene, track\) not driven by any fold"):
        agents_validation.cross_fitted(extra, "x", [["a0", "a1"], ["b0", "b1"]],
                                       _fold_models())
    _, runs = agents_validation.cross_fitted(extra, "x", [["a0", "a1"], ["b0", "b1"]],
                                             _fold_models(), baselines=["c"])
    assert runs == ["x#0", "x#1"]
    # a scene driven twice by the folds
    twice = pd.concat([eps, eps[eps["policy"] == "c"].assign(policy="d")],
                      ignore_index=True)
    models = _fold_models(c=_trained(0, (), (0, 1, 2, 3)), d=_trained(1, (), (0, 1, 2, 3)))
    with pytest.raises(ValueError, match="driven by folds"):
        agents_validation.cross_fitted(twice, "x", [["a0", "a1"], ["c", "d"]], models)


def test_cross_fitting_checks_the_tables_scenes_by_the_files_the_model_held_out():
    """A table that carries each scene's file and record: scene 1 of files read in another
    order is not the scene the model held out as 1."""
    eps = _fold_episodes()
    eps["scene_ref"] = "data/other/f.tfrecord record " + eps["scene"].astype(str)
    refs = ("/data/f.tfrecord record 0", "/data/f.tfrecord record 1")
    models = _fold_models(**{f"a{k}": _trained(k, (2, 3), (0, 1), refs) for k in range(2)})
    _, runs = agents_validation.cross_fitted(eps, "x", [["a0", "a1"], ["b0", "b1"]], models)
    assert runs == ["x#0", "x#1"]  # the same file, named from another folder
    eps.loc[eps["scene"] == 1, "scene_ref"] = "data/other/f.tfrecord record 7"
    with pytest.raises(ValueError, match=r"scene 1 is data/other/f\.tfrecord record 7, but a0"):
        agents_validation.cross_fitted(eps, "x", [["a0", "a1"], ["b0", "b1"]], models)


def test_a_model_whose_definition_records_no_training_scenes_is_refused():
    with pytest.raises(ValueError, match=r"ppo-highway: its definition records neither "
                                         r"held_out_scenes nor train_scenes.*--hold-out"):
        agents_validation.trained("ppo-highway")
    model = agents_validation.trained("ppo-womd-foldb-seed3")
    assert model.seed == 3 and model.held_out == (0, 3, 4, 6, 7, 8, 10, 11)
    assert not model.may_drive(1) and model.may_drive(0)


def test_the_cross_fitted_seed_interval_does_not_depend_on_how_the_folds_seeds_pair():
    """Each fold's seeds resampled on their own: fold B's seeds relabelled (seed k of fold A
    with another seed of fold B) leave the whole-seeds interval as it is. Paired by run, it
    was [0.374, 0.641] with fold B in seed order and [0.502, 0.545] reversed."""
    rng = np.random.default_rng(1)
    rows = []
    means = {"a": [0.3, 0.5, 0.7, 0.4, 0.6], "b": [0.35, 0.65, 0.45, 0.55, 0.75]}
    for scene in range(8):
        fold = "a" if scene < 4 else "b"
        for track in range(6):
            for k, mean in enumerate(means[fold]):
                rows.append({"policy": f"{fold}{k}", "scene": scene, "track": str(track),
                             "status": "ok", "crash_at_fault": False, "off_road": False,
                             "route_progress": float(np.clip(
                                 mean + 0.1 * rng.standard_normal(), 0, 1))})
    eps = pd.DataFrame(rows)
    folds = [[f"a{k}" for k in range(5)], [f"b{k}" for k in range(5)]]
    trained = agents_validation.Trained
    figures = []
    for order in ([0, 1, 2, 3, 4], [4, 3, 2, 1, 0]):
        models = {f"a{k}": trained(k, (4, 5, 6, 7), (0, 1, 2, 3)) for k in range(5)}
        models.update({f"b{k}": trained(s, (0, 1, 2, 3), (4, 5, 6, 7))
                       for k, s in enumerate(order)})
        crossed, runs = agents_validation.cross_fitted(eps, "x", folds, models)
        figures.append(agents_validation.seed_intervals(
            crossed, runs, strata=[range(4), range(4, 8)], n_resamples=400))
    assert figures[0]["iqm"] == pytest.approx(figures[1]["iqm"])
    assert figures[0]["iqm_low_run"] == pytest.approx(figures[1]["iqm_low_run"], abs=0.01)
    assert figures[0]["iqm_high_run"] == pytest.approx(figures[1]["iqm_high_run"], abs=0.01)
    assert figures[0]["iqm_low_run"] < figures[0]["iqm"] - 0.02


def test_runs_read_back_from_their_tables_join_and_refuse_an_episode_twice(tmp_path):
    eps = _fold_episodes()
    eps.iloc[:12].to_csv(tmp_path / "one.csv", index=False)
    eps.iloc[12:].to_csv(tmp_path / "two.csv", index=False)
    joined = agents_validation.read_episodes([str(tmp_path / "one.csv"),
                                              str(tmp_path / "two.csv")])
    pd.testing.assert_frame_equal(joined, eps)
    assert set(agents_validation.read_episodes([str(tmp_path / "two.csv")], [3])["scene"]) == {3}
    with pytest.raises(ValueError, match="more than once"):
        agents_validation.read_episodes([str(tmp_path / "one.csv")] * 2)


def test_episodes_of_log_and_idm_traffic_are_not_judged_together(tmp_path):
    """The other vehicles differ between the two, so their episodes are not paired; a table
    without a traffic column is log traffic's (every table before the column)."""
    eps = _fold_episodes()
    eps.iloc[12:].to_csv(tmp_path / "old.csv", index=False)
    eps.assign(traffic="log").iloc[:12].to_csv(tmp_path / "log.csv", index=False)
    eps.assign(traffic="idm").iloc[12:].to_csv(tmp_path / "idm.csv", index=False)
    joined = agents_validation.read_episodes([str(tmp_path / "log.csv"),
                                              str(tmp_path / "old.csv")])
    assert len(joined) == len(eps) and set(joined["traffic"].fillna("log")) == {"log"}
    with pytest.raises(ValueError, match=r"idm.csv: episodes of idm and log traffic"):
        agents_validation.read_episodes([str(tmp_path / "log.csv"), str(tmp_path / "idm.csv")])


def test_episodes_drive_in_the_traffic_asked(monkeypatch):
    """--traffic idm reaches the scenes every policy drives in, and each row says it."""
    made = []

    class Scenes:
        def __init__(self, files, traffic="log"):
            made.append(traffic)

        def catalog(self):
            return {3: "scene-3"}

    class Env:
        def scene_at(self, i):
            return i

        class unwrapped:
            vehicle = None

    monkeypatch.setattr(agents_validation, "WomdScenes", Scenes)
    monkeypatch.setattr(agents_validation, "policy_env", lambda scenes, policy: Env())
    monkeypatch.setattr(agents_validation, "drivers", lambda scene: ["7"])
    monkeypatch.setattr(agents_validation, "run_episode",
                        lambda *a, **k: (None, {"status": "ok", "route_progress": 1.0}))
    rows = agents_validation.episodes(["f.tfrecord"], [3], ["lane-keeping"], traffic="idm")
    assert made == ["idm"] and rows["traffic"].tolist() == ["idm"]


def test_an_episode_read_back_without_its_at_fault_or_off_road_is_refused(tmp_path):
    """A blank read back from a table counted as True (at fault, off road) where the episode
    in memory had counted as False; an error row may leave them blank."""
    eps = _fold_episodes().astype({"crash_at_fault": object, "off_road": object})
    eps.loc[3, "status"] = "error"
    eps.loc[3, ["route_progress", "crash_at_fault", "off_road"]] = None
    eps.to_csv(tmp_path / "eps.csv", index=False)
    read = agents_validation.read_episodes([str(tmp_path / "eps.csv")])
    assert agents_validation.summary(read, ["a0"])["at_fault_n"].item() == 0
    eps.loc[5, "off_road"] = None
    eps.to_csv(tmp_path / "eps.csv", index=False)
    with pytest.raises(ValueError, match=r"eps.csv: row 5 \(line 7\).*has no off_road"):
        agents_validation.read_episodes([str(tmp_path / "eps.csv")])


def test_the_cross_fitted_verdict_reads_tables_and_the_models_held_out_scenes(
        tmp_path, monkeypatch, capsys):
    """From the command line: the folds' held-out scenes come from their definitions
    (ppo-womd-split-seed*: held out 1, 2, ...; ppo-womd-seed*: 6, 9, ...)."""
    eps = _fold_episodes().replace({"a0": "ppo-womd-split-seed0", "a1": "ppo-womd-split-seed1",
                                    "b0": "ppo-womd-seed0", "b1": "ppo-womd-seed1"})
    eps["scene"] = eps["scene"].map({0: 1, 1: 2, 2: 6, 3: 9})
    eps.to_csv(tmp_path / "eps.csv", index=False)
    reported = {}
    monkeypatch.setattr(agents_validation, "report", lambda name, figures: reported.update(figures))
    cross = ("x=ppo-womd-split-seed0,ppo-womd-split-seed1+ppo-womd-seed0,ppo-womd-seed1")
    monkeypatch.setattr(sys, "argv", ["agents_validation.py", "--episodes",
                                      str(tmp_path / "eps.csv"), "--policies", "c",
                                      "--cross", cross, "--intervals"])
    agents_validation.main()
    assert reported["scenes"] == [1, 2, 6, 9] and "over the 4 scenes" in capsys.readouterr().out
    rows = {row["policy"]: row for row in reported["scene_intervals"]}
    assert rows["x"]["iqm"] == pytest.approx(0.6) and rows["c"]["d_at_fault"] == -1.0
    eps.loc[eps["scene"] == 1, "scene"] = 0  # a scene the split seeds trained on
    eps.to_csv(tmp_path / "eps.csv", index=False)
    with pytest.raises(ValueError, match="trained on: \\[0\\]"):
        agents_validation.main()


@pytest.mark.parametrize("cross, message", [
    ("x", "write NAME=A0,A1"), ("=a0,a1+b0,b1", "write NAME=A0,A1"),
    ("x=a0,a1", "write NAME=A0,A1"), ("x=a0,a1+b0,", "write NAME=A0,A1"),
    ("x=ppo-womd-split-seed0+ppo-womd-seed0", "not in the tables --episodes read"),
])
def test_the_command_line_refuses_a_cross_it_cannot_read(tmp_path, monkeypatch, capsys,
                                                          cross, message):
    _fold_episodes().to_csv(tmp_path / "eps.csv", index=False)
    monkeypatch.setattr(agents_validation, "report", lambda name, figures: None)
    monkeypatch.setattr(sys, "argv", ["agents_validation.py", "--episodes",
                                      str(tmp_path / "eps.csv"), "--policies", "c",
                                      "--cross", cross])
    with pytest.raises(SystemExit):
        agents_validation.main()
    err = capsys.readouterr().err
    assert message in err
    if cross.startswith("x=p"):  # the missing models and the tables read, by name
        assert "ppo-womd-seed0" in err and "eps.csv" in err


HOLD_HALF = {"predicted": True, "lanes": True, "tolerance": 0.5, "hold": True}


def test_a_layer_given_replaces_only_an_agents_own_layer():
    from tap_bench.sim.policies import load_policy
    from tap_bench.sim.rollout import policy_overrides

    agent, lane_keeping = load_policy("ppo-womd-split-seed0"), load_policy("lane-keeping")
    own = dict(agent.action)
    assert agents_validation.with_layer(agent, HOLD_HALF)
    assert not agents_validation.with_layer(lane_keeping, HOLD_HALF)
    action = policy_overrides(agent)["action"]
    assert action["safety_layer"] == HOLD_HALF
    assert {k: v for k, v in action.items() if k != "safety_layer"} == {
        k: v for k, v in own.items() if k != "safety_layer"}
    assert "action" not in policy_overrides(lane_keeping)
    assert load_policy("ppo-womd-split-seed0").action == own  # the definition is unchanged
    assert agents_validation.layered(["lane-keeping", "ppo-womd-split-seed0", "idm"]) == [
        "ppo-womd-split-seed0"]


@pytest.mark.parametrize("text, setting", [
    ('{"predicted": true, "lanes": true, "tolerance": 0.5, "hold": true}', HOLD_HALF),
    ("true", True), ("false", False), ('{"time_gap": 0.5}', {"time_gap": 0.5})])
def test_a_layer_is_read_as_json(text, setting):
    assert agents_validation.parse_layer(text) == setting


@pytest.mark.parametrize("text, message", [
    ("{tolerance: 0.5}", "not JSON"), ('{"tolerence": 0.5}', "a mapping of max_acceleration"),
    ('{"hold": true}', "with predicted and lanes true"), ('{"tolerance": -1}', "> 0"),
    ("3", "true, false or a mapping")])
def test_a_bad_layer_is_refused_with_the_reason(text, message):
    with pytest.raises(ValueError, match="--layer") as error:
        agents_validation.parse_layer(text)
    assert message in str(error.value)


@pytest.mark.parametrize("argv, message", [
    (["--womd", "x.tfrecord", "--scenes", "0", "--policies", "ppo-womd-split-seed0",
      "--layer", '{"tolerence": 0.5}'], "a mapping of max_acceleration"),
    (["--womd", "x.tfrecord", "--scenes", "0", "--policies", "lane-keeping", "random",
      "--layer", "true"], "none of --policies"),
    (["--episodes", "eps.csv", "--policies", "c", "--layer", "true"], "not --episodes"),
])
def test_the_command_line_refuses_a_layer_it_cannot_drive(monkeypatch, capsys, argv, message):
    monkeypatch.setattr(agents_validation, "episodes", lambda *a: pytest.fail("drove"))
    monkeypatch.setattr(sys, "argv", ["agents_validation.py", *argv])
    with pytest.raises(SystemExit):
        agents_validation.main()
    assert message in capsys.readouterr().err


def test_the_episodes_say_which_layer_their_agent_drove_with(monkeypatch):
    """One episode per policy on a stand-in env: the agent's row records the layer given
    (compact JSON) and its env is built with it; lane keeping's has none."""
    built = []

    class Env:
        def __init__(self, scenes, record):
            built.append(scenes.config["action"].get("safety_layer")
                         if "action" in scenes.config else None)
            self.unwrapped, self.vehicle = self, None

        def scene_at(self, i):
            return i

    monkeypatch.setattr(agents_validation, "WomdEnv", Env)
    monkeypatch.setattr(agents_validation.WomdScenes, "catalog", lambda self: ["f record 0"])
    monkeypatch.setattr(agents_validation, "drivers", lambda scene: ["7"])
    monkeypatch.setattr(agents_validation, "run_episode",
                        lambda env, policy, i, record, options: (None, {"status": "ok"}))
    eps = agents_validation.episodes(["scenes.tfrecord"], [0],
                                     ["ppo-womd-split-seed0", "lane-keeping"], HOLD_HALF)
    assert built == [HOLD_HALF, None]
    assert eps["layer"].tolist()[0] == (
        '{"hold":true,"lanes":true,"predicted":true,"tolerance":0.5}')
    assert pd.isna(eps["layer"].tolist()[1])
    own = agents_validation.episodes(["scenes.tfrecord"], [0], ["ppo-womd-split-seed0"])
    assert "layer" not in own and built[-1] == load_layer("ppo-womd-split-seed0")


def load_layer(name):
    from tap_bench.sim.policies import load_policy

    return load_policy(name).action["safety_layer"]


def test_a_policy_whose_drivers_never_moved_has_no_progress_figure():
    eps = _validation_episodes({0: [1]})
    eps.loc[eps["policy"] == "b", "route_progress"] = np.nan
    table = agents_validation.summary(eps, ["a0", "b"]).set_index("policy")
    assert np.isnan(table.loc["b", "progress_iqm"]) and np.isnan(table.loc["b", "progress_mean"])
    assert table.loc["b", "at_fault_n"] == 1 and table.loc["a0", "progress_iqm"] == 0.8
