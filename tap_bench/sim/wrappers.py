"""Gymnasium wrappers around scenario envs."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import pandas as pd

from tap_bench import sdl
from tap_bench.errors import ParameterError, did_you_mean
from tap_bench.labelling import tap
from tap_bench.sim.recorder import EGO_TRACK_ID
from tap_bench.sim.scenario_env import find_scenario_env

__all__ = ["EpisodeLabels"]

_TRACKS = ("all", "ego")


class EpisodeLabels(gym.Wrapper):
    """Labels each finished episode with TAP and puts the labels in ``info``.

    At the step that ends an episode (terminated or truncated), ``info`` gets:

    - ``"tap_labels"``: the label table (SPEC section 1) of the episode's trajectories at
      ``level``, exactly what ``tap_bench.label(episode_trajectories(env), ...)`` returns;
    - ``"tap_ego_sdl"``: the ego's SDL label (str), or None when its trajectory is shorter
      than 1 s and carries no label.

    Args:
        env: a scenario env (``gymnasium.make("tap_bench/...")``), recording.
        level: TAP level: ``"trace"``, ``"trend"``, ``"maneuver"``, ``"action"``.
        thresholds: a thresholds preset name, file or object (``"paper"``).
        tracks: ``"all"`` vehicles, or only the ``"ego"`` (faster: what the coverage
            callback needs).
    """

    def __init__(self, env: gym.Env, *, level: str = "action",
                 thresholds: Any = "paper", tracks: str = "all") -> None:
        super().__init__(env)

        sdl.check_level(level)
        if tracks not in _TRACKS:
            raise did_you_mean("tracks", tracks, _TRACKS)
        scenario_env = find_scenario_env(env)
        if not scenario_env.recorder.record:
            raise ParameterError("env", "a non-recording env", "",
                message="EpisodeLabels needs a recording env; build it with record=True.")
        self._scenario_env = scenario_env
        self.level = level
        self.thresholds = thresholds
        self.tracks = tracks

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if terminated or truncated:
            labels = self.episode_labels()
            info["tap_labels"] = labels
            ego = labels.loc[labels["track_id"] == EGO_TRACK_ID, "sdl"]
            info["tap_ego_sdl"] = str(ego.iloc[0]) if len(ego) else None
        return obs, reward, terminated, truncated, info

    def episode_labels(self) -> pd.DataFrame:
        """The label table of the current episode so far (see the class docstring)."""
        table = self._scenario_env.trajectories()
        if self.tracks == "ego":
            table = table[table["track_id"] == EGO_TRACK_ID]
        # Vehicles that enter or leave the road near the episode's end carry no label;
        # that is expected here, so no ShortSegmentWarning each episode.
        return tap(table, self.thresholds,
                   source=f"{self._scenario_env.scenario.env_id} episode").labels(self.level)
