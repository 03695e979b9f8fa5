"""The same-policy null of coverage and novelty (issue 25): the reference split in halves,
the policy at the same sizes, the difference with an interval whose coverage is measured;
scored on whole labels and on segments, per env and pooled, in the scoring path."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.scores.coverage import Reference, corpus_reference, coverage, unit_items
from tap_bench.bench.scores.novelty import novelty
from tap_bench.bench.scores.null import same_policy_null
from tap_bench.bench.scores.scoring import reference_scores, score
from tap_bench.stats.bootstrap import BootstrapConfig
from tap_bench.stats.intervals import wilson_interval

A = "Straight | Maintain Speed"
B = "Straight > Left Merge > Straight | Accelerate"
C = "Right Turn | Decelerate > Stopped"


def _coverage_stream(reference, config=None):
    """coverage()'s stream in these tests: ("coverage", the reference's description)."""
    return (config or BootstrapConfig()).rng("coverage", reference.description)


def _null_stream(reference, config=None):
    """same_policy_null()'s stream in these tests: ("null", the reference's description)."""
    return (config or BootstrapConfig()).rng("null", reference.description)


def rollouts(labels: list[str], policy: str = "idm", env: str = "highway") -> pd.DataFrame:
    return pd.DataFrame({"env": env, "policy": policy, "seed": np.arange(len(labels)),
                         "scenario_id": [f"{policy}/{i}" for i in range(len(labels))],
                         "status": "ok", "sdl": labels})


def episode_table(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with the episode table's other columns (measures made up)."""
    from tap_bench.bench.measures import MEASURES

    sides = frame["sdl"].str.split(" | ", regex=False)
    out = frame.assign(lateral=sides.str[0], longitudinal=sides.str[1], error="")
    for m in MEASURES:
        out[m.name] = False if m.is_rate else 1.0 + out["seed"] % 3
    return out.assign(duration_s=8.0)


def test_segment_items_and_reference_weights():
    assert unit_items([B]) == [("lateral: Straight", "lateral: Left Merge", "lateral: Straight",
                                "longitudinal: Accelerate")]
    ref = corpus_reference(rollouts([A, B]).assign(level="maneuver"), "maneuver",
                           tracks="all", unit="segments")
    # 6 segments: Straight x3, Left Merge, Maintain Speed, Accelerate
    assert dict(zip(ref.items, ref.weights, strict=True)) == {
        "lateral: Straight": pytest.approx(3 / 6), "lateral: Left Merge": pytest.approx(1 / 6),
        "longitudinal: Maintain Speed": pytest.approx(1 / 6),
        "longitudinal: Accelerate": pytest.approx(1 / 6)}
    assert ref.unit == "segments" and list(ref.seeds) == [0, 1]
    # "Straight | Accelerate": a new whole label, but every segment known
    episodes = rollouts(["Straight | Accelerate", C], policy="p")
    result = novelty(episodes, ref)
    assert (result.n, result.n_novel) == (2, 1)
    assert set(result.labels["label"]) == {"lateral: Right Turn", "longitudinal: Decelerate",
                                           "longitudinal: Stopped"}
    cov = coverage(episodes["sdl"], ref, rng=_coverage_stream(ref))
    assert cov.coverage == pytest.approx(2 / 4)  # Straight and Accelerate of 4
    assert cov.weighted_coverage == pytest.approx(4 / 6)


def test_a_policy_like_its_reference_sits_on_the_null_and_one_that_differs_does_not():
    rng = np.random.default_rng(4)
    p = 1 / np.arange(1, 31) ** 1.1
    labels = np.array([f"L{i:02d} | X" for i in range(30)], object)
    ref = corpus_reference(rollouts(list(labels[rng.choice(30, 40, p=p / p.sum())]))
                           .assign(level="maneuver"), "maneuver", tracks="all")
    config = BootstrapConfig(n_resamples=500)
    # the reference policy itself on the same seeds: its halves are the null exactly
    same = same_policy_null(ref.units, ref, seeds=ref.seeds, config=config,
                            rng=_null_stream(ref, config))
    assert same.paired and same.m == 20
    assert same.coverage == pytest.approx(same.null_coverage)
    assert same.coverage_diff == pytest.approx(0) and same.novel_diff == pytest.approx(0)
    assert same.coverage_diff_low < 0 < same.coverage_diff_high  # never zero-width
    # a policy whose labels the reference never shows
    new = same_policy_null(np.array(["Z | X"] * 40, object), ref, seeds=ref.seeds,
                           config=config, rng=_null_stream(ref, config))
    assert new.coverage == 0 and new.novel_rate == 1
    assert new.coverage_diff == pytest.approx(-new.null_coverage)
    assert new.novel_diff == pytest.approx(1 - new.null_novel_rate)
    assert new.novel_diff_low > 0 and new.coverage_diff_high < 0
    assert 0 < new.null_novel_rate < 1  # a finite reference misses some of its own labels


def test_unpaired_null_takes_the_policy_at_the_half_size():
    ref = corpus_reference(rollouts([A] * 10 + [B] * 10).drop(columns="seed")
                           .assign(level="maneuver"), "maneuver", tracks="all")
    assert ref.seeds is None
    result = same_policy_null(np.array([A] * 4, object), ref, seeds=np.arange(4),
                              rng=_null_stream(ref))
    assert not result.paired and result.m == 4  # 4 episodes: halves of 10 cut to 4
    assert result.null_novel_rate == 0 and result.novel_rate == 0


def test_draws_that_cannot_move_give_a_wilson_wide_interval():
    ref = corpus_reference(rollouts([A] * 12).assign(level="maneuver"), "maneuver",
                           tracks="all")
    result = same_policy_null(np.array([A] * 12, object), ref, seeds=np.arange(12),
                              rng=_null_stream(ref))
    assert result.coverage_diff == 0 and result.novel_diff == 0
    assert result.coverage_diff_low < 0 < result.coverage_diff_high
    assert result.coverage_diff_high == pytest.approx(0.39, abs=0.01)  # Wilson 0 of 6


def test_null_interval_holds_the_true_difference_in_simulation():
    """A small version of benchmarks/null_coverage.py: same label distribution, 30
    reference rollouts and 30 policy episodes unpaired; the true difference is 0."""
    K = 25
    p = 1 / np.arange(1, K + 1) ** 1.1
    p /= p.sum()
    names = np.array([f"L{i:02d} | X" for i in range(K)], object)
    rng = np.random.default_rng(7)
    hits, reps = 0, 80
    for r in range(reps):
        units = names[rng.choice(K, 30, p=p)]
        ref = Reference(np.zeros(0, object), np.zeros(0), "corpus", "maneuver", "r",
                        n_trajectories=30, units=units)
        res = same_policy_null(names[rng.choice(K, 30, p=p)], ref,
                               config=BootstrapConfig(n_resamples=300, seed=r),
                               rng=_null_stream(ref, BootstrapConfig(seed=r)))
        hits += res.novel_diff_low <= 0 <= res.novel_diff_high
    assert hits / reps >= 0.88


def test_reference_scores_give_both_units_and_the_null_per_env_and_pooled():
    eps = pd.concat([rollouts([A, B, A, B, A, B, A, B], "idm", env)
                     for env in ("highway", "merge")]
                    + [rollouts([C, B, C, A, C, B, C, A], "random", env)
                       for env in ("highway", "merge")], ignore_index=True)
    scores = score(episode_table(eps), reference_policy="idm",
                   level="maneuver", config=BootstrapConfig(n_resamples=200))
    cov = scores.coverage.set_index(["env", "unit"])
    assert set(cov.index) == {(e, u) for e in ("highway", "merge", "all")
                              for u in ("episodes", "segments")}
    for column in ("null_coverage", "half_coverage", "coverage_diff", "coverage_diff_low",
                   "coverage_diff_high"):
        assert cov[column].notna().all(), column
    assert cov["null_paired"].all()
    row = cov.loc[("all", "episodes")]
    assert row["coverage_diff_low"] <= row["coverage_diff"] <= row["coverage_diff_high"]
    nov = scores.novelty.set_index(["env", "unit"])
    # random's C is novel as a whole label and through its segments
    assert nov.loc[("highway", "episodes"), "novel_rate"] == 0.5
    assert nov.loc[("highway", "segments"), "novel_rate"] == 0.5
    assert nov.loc[("all", "episodes"), "novel_diff"] > 0
    labels = scores.novel_labels
    assert set(labels["unit"]) == {"episodes", "segments"}
    assert not labels.duplicated(["env", "policy", "reference", "unit", "label"]).any()
    assert "same-policy null" in scores.methods


def test_windows_replace_whole_episodes_against_a_corpus_of_short_tracks():
    eps = rollouts([A, B, A, B], "idm")
    womd = pd.DataFrame({"scenario_id": [f"w{i}" for i in range(8)], "track_id": "1",
                         "object_type": "vehicle", "sdl": [A, B] * 4})
    windows = rollouts([A, A, A, B, B, B, A, C], "idm").assign(
        scenario_id=[f"idm/{i // 2}#{i % 2}" for i in range(8)], seed=[0, 0, 1, 1, 2, 2, 3, 3],
        cut_from=[f"idm/{i // 2}" for i in range(8)])
    scores = score(episode_table(eps), reference_policy="idm",
                   level="maneuver", config=BootstrapConfig(n_resamples=200),
                   references={"WOMD": womd},
                   windows={"WOMD": (episode_table(windows), "9.1 s windows")})
    real = scores.coverage[scores.coverage["reference"] == "WOMD"].set_index("unit")
    assert set(real.index) == {"9.1 s windows", "9.1 s windows, segments"}
    assert real.loc["9.1 s windows", "n"] == 8  # windows, not the 4 episodes
    nov = scores.novelty[scores.novelty["reference"] == "WOMD"].set_index("unit")
    assert nov.loc["9.1 s windows", "n_novel"] == 1  # the window showing C
    assert nov.loc["9.1 s windows", "null_paired"] == False  # noqa: E712 (numpy bool)


def test_reference_scores_say_what_they_scored_on():
    ref = corpus_reference(rollouts([A, B]).assign(level="maneuver"), "maneuver",
                           tracks="all")
    cov, nov, _ = reference_scores(rollouts([A, C], "p"), ref, "r",
                                   config=BootstrapConfig(n_resamples=200), unit="windows")
    assert set(cov["unit"]) == {"windows"} and set(nov["unit"]) == {"windows"}


def test_an_env_whose_reference_is_too_small_for_halves_is_left_out_of_the_pooled_null():
    eps = pd.concat([rollouts([A, B] * 4, "idm", "highway"), rollouts([A, B], "idm", "merge"),
                     rollouts([C, B] * 4, "random", "highway"),
                     rollouts([C, B], "random", "merge")], ignore_index=True)
    scores = score(episode_table(eps), reference_policy="idm", level="maneuver",
                   config=BootstrapConfig(n_resamples=200))
    cov = scores.coverage.set_index(["env", "unit"])
    assert np.isnan(cov.loc[("merge", "episodes"), "null_coverage"])  # 2 rollouts: no halves
    pooled = cov.loc[("all", "episodes")]
    assert pooled["null_coverage"] == cov.loc[("highway", "episodes"), "null_coverage"]


def test_rollouts_on_other_seeds_are_held_against_the_null_unpaired():
    ref = corpus_reference(rollouts([A, B] * 6).assign(level="maneuver"), "maneuver",
                           tracks="all")
    result = same_policy_null(np.array([A, C] * 3, object), ref, seeds=np.arange(100, 106),
                              rng=_null_stream(ref))
    assert not result.paired and result.m == 6 and np.isfinite(result.novel_diff)


def test_windows_of_one_episode_are_resampled_together():
    # every episode cut into 3 windows that are copies of each other: 3x the windows but
    # no more information than the 20 episodes. Resampled as independent units the
    # interval would be as narrow as 60 episodes'; by whole episodes it must be wider.
    rng = np.random.default_rng(3)
    pool = [A, B, C, "Left Turn | Accelerate", "Straight | Decelerate"]
    ref = Reference(np.zeros(0, object), np.zeros(0), "corpus", "maneuver", "synthetic",
                    n_trajectories=40, units=np.array(rng.choice(pool[:3], 40), object))
    episodes = rng.choice(pool, 20)
    windows = np.repeat(episodes, 3).astype(object)
    episode_of = np.repeat(np.arange(20), 3)
    config = BootstrapConfig(n_resamples=1000)
    alone = same_policy_null(windows, ref, config=config, rng=np.random.default_rng(0))
    together = same_policy_null(windows, ref, clusters=episode_of, config=config,
                                rng=np.random.default_rng(0))
    assert together.novel_diff == alone.novel_diff  # the estimate does not move
    width = {name: r.novel_diff_high - r.novel_diff_low
             for name, r in (("alone", alone), ("together", together))}
    assert width["together"] > 1.2 * width["alone"]
    # windows that are each their own episode: the ordinary bootstrap's width
    own = same_policy_null(windows, ref, clusters=np.arange(60), config=config,
                           rng=np.random.default_rng(0))
    assert own.novel_diff_high - own.novel_diff_low == pytest.approx(width["alone"], rel=0.15)


def test_scoring_windows_resamples_them_by_episode():
    ref_table = rollouts([A, B, C] * 8, policy="womd").assign(level="maneuver")
    labels = np.random.default_rng(1).choice([A, B, C, "Left Turn | Accelerate"], 12)
    windows = episode_table(pd.DataFrame({
        "env": "highway", "policy": "dqn", "seed": np.arange(36), "status": "ok",
        "scenario_id": [f"dqn/{i // 3}#{i % 3}" for i in range(36)],
        "sdl": np.repeat(labels, 3)})).assign(cut_from=[f"dqn/{i // 3}" for i in range(36)])
    ref = corpus_reference(ref_table, "maneuver", tracks="all", name="womd")
    config = BootstrapConfig(n_resamples=1000)
    rows = {w: reference_scores(windows, ref, "womd", config=config, unit="9.0 s windows",
                                windowed=w)[1].iloc[0]
            for w in (False, True)}
    width = {w: r["novel_diff_high"] - r["novel_diff_low"] for w, r in rows.items()}
    assert width[True] > 1.2 * width[False]
    # the novel rate's Wilson interval: at 12 episodes' worth, not 36 windows'
    assert rows[True]["novel_rate"] == rows[False]["novel_rate"]
    k = rows[True]["novel_rate"] * 12
    lo, hi = wilson_interval(k, 12, 0.95)
    assert (rows[True]["novel_low"], rows[True]["novel_high"]) == (
        pytest.approx(lo, abs=0.03), pytest.approx(hi, abs=0.03))
    assert rows[False]["novel_high"] - rows[False]["novel_low"] < 0.7 * (hi - lo)


def test_the_shown_half_figures_always_subtract_to_the_shown_difference():
    """The policy's figure at halves is the same-policy figure plus the difference, not
    rounded: three roundings need not agree at 2 decimals (the demo's report showed 'policy
    58.56 % vs same policy 38.44 %: +20.11 pts'). Drawn fractions: the shown figures always
    subtract to the shown difference, the policy's within half a unit of its last digit
    of its own value (0.01 points at 2 decimals)."""
    import re
    from decimal import Decimal

    from tap_bench.bench.scores.null import halves_text

    gen = np.random.default_rng(11)
    seen_sum = 0
    for _ in range(5000):
        null, diff = float(gen.random()), float(gen.uniform(-1, 1))
        half = null + diff
        text = halves_text(half, null, diff, diff - 0.1, diff + 0.1)
        policy, same, shown = re.match(r"halves: policy ([\d.-]+)% vs same policy ([\d.]+)%: "
                                       r"([+-][\d.]+) pts", text).groups()
        assert Decimal(policy) - Decimal(same) == Decimal(shown), text
        digits = len(shown.partition(".")[2])  # half a unit of the last digit, or 0.01
        assert abs(float(policy) - 100 * half) <= max(0.5 * 10.0 ** -digits, 0.01) + 1e-9, text
        seen_sum += f"{100 * half:.2f}" != policy
    assert seen_sum  # the drawn values reach the case rounding alone gets wrong
    assert halves_text(0.585555, 0.384444, 0.201111, 0.0134, 0.3888) == (
        "halves: policy 58.55% vs same policy 38.44%: +20.11 pts [+1.34, +38.88]")


def test_a_corpus_of_scenes_is_resampled_by_whole_scenes():
    # 4 scenes of 50 vehicles: two show only L0, two only L1; the policy shows L0 30 times.
    # Split by trajectory, every half shows both labels: the policy covers half of a half,
    # the same-policy half all of it, -0.5 in every split and every draw by trajectory
    # (the interval is then +- the Wilson limit of 0 of 30, width 0.23). Another 4 real
    # scenes could all be L0 scenes (difference 0) or all L1 (-1), 1 in 16 each: drawn by
    # whole scenes the interval reaches both. The estimate (splits) is the same.
    # (fails when the corpus is resampled trajectory by trajectory)
    scenes = np.repeat(["s0", "s1", "s2", "s3"], 50)
    table = pd.DataFrame({"scenario_id": scenes, "level": "maneuver",
                          "sdl": np.repeat(["L0 | X", "L0 | X", "L1 | X", "L1 | X"], 50)})
    ref = corpus_reference(table, "maneuver")
    assert ref.scenes is not None and set(ref.scenes) == set(scenes)
    alone = corpus_reference(table.assign(scenario_id=np.arange(200).astype(str)),
                             "maneuver")
    assert alone.scenes is None  # one trajectory a scene: nothing to keep together
    policy = np.full(30, "L0 | X", object)
    config = BootstrapConfig(n_resamples=1000, seed=0)
    by_scene = same_policy_null(policy, ref, config=config, rng=_null_stream(ref, config))
    by_track = same_policy_null(policy, Reference(**{**ref.__dict__, "scenes": None}),
                                config=config, rng=_null_stream(ref, config))
    assert by_scene.coverage_diff == by_track.coverage_diff == pytest.approx(-0.5)
    _, u = wilson_interval(0, 30, 0.95)
    assert (by_track.coverage_diff_low, by_track.coverage_diff_high) == pytest.approx(
        (-0.5 - u, -0.5 + u))
    # ... widened by sqrt(4 / 3) (4 scenes drawn from 4) and read at t with 3 degrees of
    # freedom (3.182 / 1.960): -0.5 -+ 0.5 k, clipped at -1
    from tap_bench.stats.intervals import t_quantile, z_value

    k = np.sqrt(4 / 3) * t_quantile(0.975, 3) / z_value(0.95)
    assert (by_scene.coverage_diff_low, by_scene.coverage_diff_high) == pytest.approx(
        (-1.0, -0.5 + 0.5 * k), abs=0.02)  # the draws are re-centred on the estimate


def test_cluster_indices_draw_whole_clusters_until_m():
    from tap_bench.stats.bootstrap import cluster_indices

    clusters = np.repeat(["a", "b", "c", "d"], [1, 3, 2, 5])
    idx = cluster_indices(np.random.default_rng(0), clusters, 200, 11)
    for row in idx:
        names = clusters[row]
        starts = np.flatnonzero(np.r_[True, names[1:] != names[:-1]])
        ends = np.r_[starts[1:], len(row)]
        for s, e in zip(starts[:-1], ends[:-1], strict=True):  # the last may be cut
            assert sorted(row[s:e]) == list(np.flatnonzero(clusters == names[s])) or \
                len(row[s:e]) % (clusters == names[s]).sum() == 0  # a cluster drawn twice
