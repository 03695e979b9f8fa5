"""The sim-to-real behaviour gap on label tables small enough to check by hand."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.scores.gap import behaviour_gap, labelled_with_speed
from tap_bench.errors import LabelTableError
from tap_bench.stats.bootstrap import BootstrapConfig


def labels(rows, speed=None):
    out = pd.DataFrame(rows, columns=["lateral", "longitudinal", "interaction"])
    out["mean_speed"] = np.nan if speed is None else speed
    return out


def test_gap_by_hand():
    # policy: 10 trajectories "Straight | Maintain Speed | Following" (3 label occurrences
    # each: shares 1/3, 1/3, 1/3); reference: 10 with Following, 10 with Free Driving
    # (shares: Straight 1/3, Maintain Speed 1/3, Following 1/6, Free Driving 1/6)
    pol = labels([("Straight", "Maintain Speed", "Following")] * 10)
    ref = labels([("Straight", "Maintain Speed", "Following")] * 10
                 + [("Straight", "Maintain Speed", "Free Driving")] * 10)
    result = behaviour_gap(pol, ref, config=BootstrapConfig(n_resamples=500))
    assert result.gap == pytest.approx(1 / 6)  # 0.5 * (1/6 + 1/6)
    table = result.labels.set_index("label")
    assert table.loc["Following", "diff"] == pytest.approx(1 / 6)
    assert table.loc["Free Driving", "diff"] == pytest.approx(-1 / 6)
    assert table.loc["Straight", "diff"] == pytest.approx(0)
    assert 0.5 * table["diff"].abs().sum() == pytest.approx(result.gap)  # it decomposes
    assert result.gap_low <= result.gap <= result.gap_high
    # a policy drawn from the reference itself sits near its floor
    same = behaviour_gap(ref, ref, config=BootstrapConfig(n_resamples=500))
    assert same.gap == 0 and same.floor > 0


def test_comparable_situations_by_speed_and_errors():
    pol = labels([("Straight", "Maintain Speed", "Following")] * 4, speed=[22.0, 24, 26, 28])
    ref = labels([("Straight", "Maintain Speed", "Following")] * 3
                 + [("Left Turn", "Decelerate", "Free Driving")] * 3,
                 speed=[25, 26, 24, 5, 6, 4])
    result = behaviour_gap(pol, ref, config=BootstrapConfig(n_resamples=200))
    assert result.n_reference == 3 and result.gap == 0  # only the fast ones compared
    assert "22.3 to 27.7 m/s" in result.reference  # the policy's 5 % and 95 % quantiles
    with pytest.raises(LabelTableError, match="nothing to compare"):
        behaviour_gap(pol, ref, min_speed=30.0)


def test_labelled_with_speed_gives_each_trajectorys_mean_speed():
    t = np.arange(30) / 10
    table = pd.DataFrame({"scenario_id": "s", "track_id": np.repeat(["a", "b"], 30),
                          "t": np.tile(t, 2), "x": np.r_[10 * t, 20 * t], "y": 0.0,
                          "heading": 0.0, "speed": np.repeat([10.0, 20.0], 30),
                          "is_ego": np.repeat([True, False], 30)})
    out = labelled_with_speed(table, "maneuver", interactions="all")
    assert list(out["mean_speed"]) == pytest.approx([10.0, 20.0])
    assert out["interaction"].notna().all()


def test_a_reference_faster_than_10_hz_gets_the_mean_speeds_of_its_labelled_rows():
    """20 Hz driving data is labelled on its 10 Hz resampling, and the mean speeds are taken
    from those rows (the speeds were taken from the 20 Hz table, which raised)."""
    from tap_bench.errors import ResampledWarning

    t = np.arange(60) / 20
    table = pd.DataFrame({"scenario_id": "s", "track_id": np.repeat(["a", "b"], 60),
                          "t": np.tile(t, 2), "x": np.r_[10 * t, 20 * t], "y": 0.0,
                          "heading": 0.0, "speed": np.repeat([10.0, 20.0], 60)})
    with pytest.warns(ResampledWarning):
        out = labelled_with_speed(table, "maneuver", interactions="all")
    assert list(out["mean_speed"]) == pytest.approx([10.0, 20.0])


def test_debiased_gap_and_its_interval():
    from tap_bench.bench.scores.gap import debias

    # by hand: plug-in 0.3, resampled mean 0.35, quantiles 0.2 and 0.5 -> 0.25, [0.1, 0.4]
    boot = np.r_[np.full(30, 0.2), np.full(40, 0.35), np.full(30, 0.5)]
    est, lo, hi = debias(0.3, boot, 0.5)
    assert est == pytest.approx(0.25) and lo == pytest.approx(0.1) and hi == pytest.approx(0.4)
    assert debias(0.3, boot, 0.5, same=0.35)[1] == 0  # within what one behaviour shows
    assert debias(0.05, boot, 0.5) == (0.0, 0.0, 0.0)  # clipped: a distance
    # the same behaviour on both sides: the plug-in gap is above 0, its percentile interval
    # misses 0; the debiased interval holds it
    rng = np.random.default_rng(0)
    rows = [("Straight", "Maintain Speed", "Following"), ("Left Merge", "Accelerate",
                                                           "Free Driving"),
            ("Straight", "Decelerate", "Cut-in")]
    held = 0
    for rep in range(20):
        pol = labels([rows[i] for i in rng.integers(0, 3, 30)])
        ref = labels([rows[i] for i in rng.integers(0, 3, 200)])
        res = behaviour_gap(pol, ref, config=BootstrapConfig(n_resamples=400, seed=rep))
        held += res.debiased_low == 0
        assert res.gap_debiased <= res.gap
    assert held >= 17


def test_windows_cut_episodes_to_the_reference_length():
    from tap_bench.bench.scores.windows import track_seconds, windows

    t = np.arange(300) / 10  # a 30 s episode at 10 Hz
    table = pd.DataFrame({"scenario_id": "ep", "track_id": "ego", "t": t, "x": t, "y": 0.0,
                          "heading": 0.0, "speed": 1.0})
    ref = pd.DataFrame({"scenario_id": np.repeat(["a", "b", "c"], 92), "track_id": "v",
                        "t": np.tile(np.arange(92) / 10, 3)})
    assert track_seconds(ref) == pytest.approx(9.1)
    cut = windows(table, 9.1)
    sizes = cut.groupby("scenario_id").size()
    assert list(sizes.index) == ["ep#0", "ep#1", "ep#2"]  # 2.7 s left over: dropped
    assert (sizes == 91).all()
    with pytest.raises(ValueError, match="positive"):
        windows(table, 0)


def test_gap_command_windows_and_crashes(tmp_path, capsys):
    from tap_bench.cli import main

    t = np.arange(200) / 10
    rows = []
    for ep, crashed in (("e1", False), ("e2", True)):
        rows.append(pd.DataFrame({"scenario_id": ep, "track_id": "ego", "t": t, "x": 20 * t,
                                  "y": 0.0, "heading": 0.0, "speed": 20.0, "is_ego": True,
                                  "crashed": np.r_[np.zeros(199, bool), [crashed]],
                                  "policy": "p"}))
    pd.concat(rows).to_parquet(tmp_path / "pol.parquet")
    ref = pd.concat([pd.DataFrame({"scenario_id": f"r{i}", "track_id": "v", "t": t[:91],
                                   "x": 20 * t[:91], "y": 0.0, "heading": 0.0,
                                   "speed": 20.0}) for i in range(4)])
    ref.to_parquet(tmp_path / "ref.parquet")
    assert main(["gap", str(tmp_path / "pol.parquet"), "--reference",
                 str(tmp_path / "ref.parquet"), "--resamples", "200",
                 "-o", str(tmp_path / "gap.csv")]) == 0
    out = capsys.readouterr().out
    assert "crash rate 50%" in out and "4 9.0 s windows" in out and "debiased" in out
    row = pd.read_csv(tmp_path / "gap.csv").iloc[0]
    assert row["window_s"] == pytest.approx(9.0) and row["crash_rate"] == 0.5


def test_window_episodes_label_each_window_of_the_egos_once():
    """The windows bench run scores against a real corpus: one episode row per window of
    an ego, numbered seeds (one seed is one episode), the episode's seed kept aside; and
    'auto' windows only episodes longer than the reference's tracks."""
    from tap_bench.bench.scores.windows import window_episodes, window_seconds

    t = np.arange(300) / 10
    rows = []
    for seed in (3, 4):
        rows.append(pd.DataFrame({"env": "highway", "policy": "p", "seed": seed,
                                  "scenario_id": f"ep{seed}", "track_id": "ego", "t": t,
                                  "x": 20 * t, "y": 0.0, "heading": 0.0, "speed": 20.0,
                                  "is_ego": True}))
        rows.append(rows[-1].assign(track_id="other", is_ego=False, y=4.0))
    table = pd.concat(rows, ignore_index=True)
    ref = pd.DataFrame({"scenario_id": np.repeat(["a", "b"], 92), "track_id": "v",
                        "t": np.tile(np.arange(92) / 10, 2)})
    assert window_seconds("auto", ref, table) == pytest.approx(9.1)
    assert window_seconds("auto", table, ref) is None  # 9 s tracks need no cutting
    assert window_seconds("none", ref, table) is None
    eps = window_episodes(table, 9.1, "maneuver")
    assert len(eps) == 6 and eps["seed"].is_unique  # 3 windows of each ego only
    assert set(eps["scenario_id"]) == {f"ep{s}#{k}" for s in (3, 4) for k in range(3)}
    assert set(eps["env"]) == {"highway"} and set(eps["policy"]) == {"p"}
    assert eps["sdl"].notna().all()


def test_windows_of_one_episode_are_resampled_together_in_the_gap():
    # each episode's 4 windows are copies: by whole episodes the intervals must be wider
    # than resampling the 80 windows as if independent (which 20 episodes cannot give)
    rng = np.random.default_rng(5)
    kinds = [("Straight", "Maintain Speed", "Following"), ("Left Merge", "Accelerate",
                                                            "Free Driving"),
             ("Straight", "Decelerate", "Following")]
    episodes = [kinds[i] for i in rng.integers(0, 3, 20)]
    pol = labels([e for e in episodes for _ in range(4)]).assign(
        episode=np.repeat(np.arange(20), 4))
    ref = labels([kinds[i] for i in rng.integers(0, 3, 200)])
    config = BootstrapConfig(n_resamples=1000)
    alone = behaviour_gap(pol, ref, config=config)
    together = behaviour_gap(pol, ref, config=config, clusters="episode")
    assert together.gap == alone.gap
    assert (together.gap_high - together.gap_low) > 1.3 * (alone.gap_high - alone.gap_low)
    wide = (together.labels.set_index("label")["diff_high"]
            - together.labels.set_index("label")["diff_low"])
    narrow = (alone.labels.set_index("label")["diff_high"]
              - alone.labels.set_index("label")["diff_low"])
    assert (wide > 1.3 * narrow).all()


def test_window_episode_strips_the_window_number():
    from tap_bench.bench.scores.windows import window_episode

    assert list(window_episode(["a/1#0", "a/1#12", "b#x#2", "c"])) == ["a/1", "a/1", "b#x",
                                                                         "c"]


# -- resampling by scene -----------------------------------------------------------------
A = ("Straight", "Maintain Speed", "Following")
B = ("Left Merge", "Accelerate", "Free Driving")


def scenes_of(kinds, vehicles: int, prefix: str) -> pd.DataFrame:
    """One scene per entry of ``kinds``, each of ``vehicles`` vehicles all showing that
    kind's labels; ``scenario_id`` ``<prefix><k>``."""
    rows = [kind for kind in kinds for _ in range(vehicles)]
    return labels(rows).assign(scenario_id=np.repeat([f"{prefix}{k}" for k in
                                                      range(len(kinds))], vehicles))


def test_cluster_draws_hold_whole_scenes_and_as_many_as_there_are():
    from tap_bench.stats.bootstrap import cluster_weights, scene_clusters

    table = pd.DataFrame({"scenario_id": ["s1", "s1", "s2", "s3", "s3", "s3", "e/p/s4#0",
                                          "e/p/s4#1"]})
    units = scene_clusters(table)
    assert list(units[-2:]) == ["e/p/s4", "e/p/s4"]  # a window belongs to its episode
    w = cluster_weights(np.random.default_rng(0), units, 500)
    for scene in ("s1", "s2", "s3", "e/p/s4"):
        cols = w[:, units == scene]
        assert (cols == cols[:, :1]).all()  # every vehicle of a scene drawn together
    # per draw: 4 scenes drawn in all (their counts sum to the number of scenes)
    per_scene = np.stack([w[:, np.flatnonzero(units == s)[0]]
                          for s in ("s1", "s2", "s3", "e/p/s4")], axis=1)
    assert (per_scene.sum(axis=1) == 4).all()
    assert list(scene_clusters(table.drop(columns="scenario_id"))) == [str(i)
                                                                       for i in range(8)]


def test_a_scene_of_identical_vehicles_carries_the_evidence_of_one():
    # 20 identical vehicles per scene: the gap, its intervals and its floor equal those of
    # one vehicle per scene (the same draws of scenes); by rows they would be far narrower
    pol_kinds, ref_kinds = [A, A, B, A, B, A], [A, B, B, A, B, A, B, B, A, B, A, B]
    config = BootstrapConfig(n_resamples=800, seed=3)
    whole = behaviour_gap(scenes_of(pol_kinds, 20, "p"), scenes_of(ref_kinds, 20, "r"),
                          config=config)
    one = behaviour_gap(scenes_of(pol_kinds, 1, "p"), scenes_of(ref_kinds, 1, "r"),
                        config=config)
    for field in ("gap", "gap_low", "gap_high", "gap_debiased", "debiased_low",
                  "debiased_high", "floor"):
        assert getattr(whole, field) == pytest.approx(getattr(one, field)), field
    assert (whole.n_policy, whole.n_policy_units, whole.n_reference_units) == (120, 6, 12)
    pd.testing.assert_frame_equal(whole.labels, one.labels)
    rows = behaviour_gap(scenes_of(pol_kinds, 20, "p"), scenes_of(ref_kinds, 20, "r"),
                         config=config, clusters=None, reference_clusters=None)
    assert rows.floor < 0.5 * whole.floor
    assert rows.gap_high - rows.gap_low < 0.5 * (whole.gap_high - whole.gap_low)


def test_each_side_draws_its_own_scenes_by_hand():
    # policy: scene p0 all A, scene p1 all B (10 vehicles each); reference: 12 scenes all A.
    # The reference cannot move; each draw takes exactly 2 policy scenes: both p0 (1/4),
    # one of each (1/2) or both p1 (1/4), so the policy's Left Merge share is 0, 1/6 or
    # 1/3, scaled about 1/6 by sqrt(2 / 1) and read at Student's t with 1 degree of
    # freedom (12.706 / 1.960): the interval of its difference is 1/6 -+ k sqrt(2) / 6 with
    # k = 12.706 / 1.960. The floor (two samples of one behaviour): a
    # draw's policy shares move by sqrt(2) / 6 on all six labels with probability 1/2,
    # a gap of sqrt(2) / 2, so the floor is sqrt(2) / 4.
    import warnings

    pol, ref = scenes_of([A, B], 10, "p"), scenes_of([A] * 12, 10, "r")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = behaviour_gap(pol, ref, config=BootstrapConfig(n_resamples=4000, seed=1))
    merge = res.labels.set_index("label").loc["Left Merge"]
    assert merge["diff"] == pytest.approx(1 / 6)
    k = 12.7062047 / 1.9599640
    assert merge["diff_low"] == pytest.approx(1 / 6 - k * np.sqrt(2) / 6)
    assert merge["diff_high"] == pytest.approx(1 / 6 + k * np.sqrt(2) / 6)
    assert res.floor == pytest.approx(np.sqrt(2) / 4, abs=0.02)
    # 2 policy episodes: the interval is flagged as resting on too few units
    from tap_bench.errors import FewClustersWarning

    assert any(issubclass(w.category, FewClustersWarning) and "2 policy episodes" in
               str(w.message) for w in caught)


def scene_effects(n_scenes: int, rng: np.random.Generator, prefix: str, kappa: float = 3.0,
                  vehicles: int = 15) -> pd.DataFrame:
    """Scenes with their own label probabilities (Dirichlet(kappa p) per axis around one
    population's p), vehicles drawing from their scene's."""
    kinds = [("Straight", "Left Merge", "Left Turn"), ("Maintain Speed", "Accelerate",
                                                       "Decelerate"),
             ("Following", "Free Driving", "Cut-in")]
    p = np.array([0.6, 0.3, 0.1])
    rows = {"scenario_id": np.repeat([f"{prefix}{s}" for s in range(n_scenes)], vehicles)}
    for axis, names in zip(("lateral", "longitudinal", "interaction"), kinds, strict=True):
        probs = rng.dirichlet(kappa * p, n_scenes)
        rows[axis] = [names[rng.choice(3, p=probs[s])] for s in range(n_scenes)
                      for _ in range(vehicles)]
    return pd.DataFrame(rows).assign(mean_speed=np.nan)


def test_null_of_scenes_with_shared_effects_is_covered():
    # two independent sets of 12 scenes from one population: the true gap is 0, and the
    # interval must reach it about 95 % of the time; drawing vehicles one by one (as the
    # gap did) reached it in 10 of these 30 data sets
    rng = np.random.default_rng(38)
    held = 0
    for rep in range(30):
        pol, ref = scene_effects(12, rng, "p"), scene_effects(12, rng, "r")
        res = behaviour_gap(pol, ref, config=BootstrapConfig(n_resamples=300, seed=rep))
        held += res.debiased_low == 0
    assert held >= 26


WOMD = [f"../shared/data/womd/{f}" for f in (
    "motion_data_one_scenario.tfrecord", "motion_data_one_example.tfrecord",
    "womd_scenario_input.tfrecord", "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")] + [
    "../shared/data/womd-dev/dev.tfrecord"]


@pytest.mark.slow
@pytest.mark.womd
def test_null_study_on_real_scenes_split_in_halves_and_on_many_generated_scenes():
    """The long null study (benchmarks/gap_coverage.py --only scenes runs it in full): the
    real scenes split at random into two halves of 8 (both real driving, the true gap is
    0), and 40 + 40 generated scenes with scene effects."""
    import warnings
    from pathlib import Path

    from tap_bench.sources import read_womd

    root = Path(__file__).resolve().parents[2]
    files = [str(root / f) for f in WOMD if (root / f).exists()]
    if len(files) < len(WOMD):
        pytest.skip("the real WOMD files are not in ../shared/data")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        real = labelled_with_speed(read_womd(files), "maneuver", interactions="all")
        real = real[real["object_type"] == "vehicle"].assign(mean_speed=np.nan)
        ids = np.array(sorted(real["scenario_id"].unique()), object)
        assert len(ids) == 16
        rng = np.random.default_rng(380)
        held = 0
        for rep in range(60):
            first = real["scenario_id"].isin(rng.permutation(ids)[:8]).to_numpy()
            res = behaviour_gap(real[first], real[~first],
                                config=BootstrapConfig(n_resamples=500, seed=rep))
            assert (res.n_policy_units, res.n_reference_units) == (8, 8)
            held += res.debiased_low == 0
        assert held >= 54  # 0.90 of splits (the interval's level is 0.95)
        held = 0
        for rep in range(60):
            pol, ref = scene_effects(40, rng, "p"), scene_effects(40, rng, "r")
            res = behaviour_gap(pol, ref, config=BootstrapConfig(n_resamples=500, seed=rep))
            held += res.debiased_low == 0
        assert held >= 54
