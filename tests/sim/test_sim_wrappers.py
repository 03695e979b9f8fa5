"""The labels wrapper and the coverage measure of the training callback."""

from __future__ import annotations

import gymnasium as gym
import pandas as pd
import pytest

import tap_bench
from tap_bench.sim import EpisodeLabels, episode_trajectories
from tap_bench.sim.policies import CHEAP_OBSERVATION


def run_to_end(env, action=1, seed=0):
    env.reset(seed=seed)
    while True:
        _, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return info


@pytest.mark.parametrize("level", ["trend", "action"])
def test_info_labels_equal_labelling_the_recorded_table(level):
    env = EpisodeLabels(gym.make("tap_bench/highway-v0", duration=6,
                                 config={"observation": CHEAP_OBSERVATION}), level=level)
    info = run_to_end(env, action=0)  # keeps asking for the left lane
    afterwards = tap_bench.label(episode_trajectories(env), level=level)
    pd.testing.assert_frame_equal(info["tap_labels"], afterwards)
    ego = afterwards.loc[afterwards["track_id"] == "ego", "sdl"]
    assert info["tap_ego_sdl"] == ego.iloc[0]
    assert set(info["tap_labels"]["level"]) == {level}


def test_ego_only_labels_the_ego():
    env = EpisodeLabels(gym.make("tap_bench/merge-v0", duration=3,
                                 config={"observation": CHEAP_OBSERVATION}), tracks="ego")
    info = run_to_end(env)
    assert info["tap_labels"]["track_id"].tolist() == ["ego"]


def test_labels_need_a_recording_env():
    with pytest.raises(ValueError, match="record=True"):
        EpisodeLabels(gym.make("tap_bench/merge-v0", record=False))


def test_label_coverage_by_hand():
    from tap_bench.sim import coverage
    labels = ["Straight | Maintain Fast Speed",
              "Straight > Left Merge > Straight | Maintain Fast Speed > Decelerate Fast Speed"]
    # single labels seen: Straight, Left Merge, Maintain Fast Speed, Decelerate Fast Speed
    n_vocabulary = len(coverage.vocabulary_tokens("action"))
    assert n_vocabulary == 9 + 11  # ... + Stopped and Reversing (SPEC 4.6)
    assert coverage.label_coverage(labels) == pytest.approx(4 / 20)
    reference = {"Straight | Maintain Fast Speed", "Straight | Stopped"}
    assert coverage.label_coverage(labels, reference) == pytest.approx(1 / 2)
    assert coverage.label_coverage([], reference) == 0.0
