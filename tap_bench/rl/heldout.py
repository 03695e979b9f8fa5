"""Recorded scenes held out of training: an agent trained on some scenes of WOMD files is
judged on the others, which it never saw (``tap-bench train --env womd --hold-out SEEDS``).

Scenes are named as everywhere on recorded scenes: by their index in the files' catalog
(file and record order; :meth:`~tap_bench.sim.womd_scene.WomdScenes.seeds`), so a rollout
or suite run on the held-out scenes names the same seeds (``--seeds``).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym

from tap_bench.errors import ParameterError
from tap_bench.sim.womd_scene import WomdScenes

__all__ = ["SceneSplit", "SceneSubset", "split_scenes"]


@dataclass(frozen=True)
class SceneSplit:
    """Which scenes of ``scenes`` an agent trains on and which are held out.

    Attributes:
        scenes: the recorded scenes (all of them).
        train: scene indexes trained on, ascending.
        held_out: scene indexes never seen in training, ascending.
        refs: the scene of every index, as ``"file record k"`` (what the definition records,
            so the split can be read without the catalog).
    """

    scenes: WomdScenes
    train: tuple[int, ...]
    held_out: tuple[int, ...]
    refs: tuple[str, ...]

    def record(self) -> dict[str, Any]:
        """The split as a policy definition records it (JSON)."""
        return {"train_scenes": list(self.train), "held_out_scenes": list(self.held_out),
                "held_out_refs": [self.refs[i] for i in self.held_out]}


def split_scenes(scenes: WomdScenes, hold_out: str | Iterable[int] | None) -> SceneSplit:
    """Split ``scenes`` into training and held-out scenes.

    Args:
        scenes: the recorded scenes.
        hold_out: scene indexes to hold out (``"6,9,12,15"``, ``"6-9"``, a list), or None
            (train on all).

    Raises:
        ParameterError: an index beyond the files' scenes, or every scene held out.
    """
    catalog = scenes.catalog()
    held = () if hold_out is None or hold_out == "" else tuple(
        sorted(set(scenes.seeds(hold_out))))
    train = tuple(i for i in range(len(catalog)) if i not in held)
    if not train:
        raise ParameterError("hold_out", hold_out, "fewer scenes than the files hold",
                             message=f"--hold-out {hold_out}: every one of the "
                             f"{len(catalog)} scene(s) is held out, so none is left to "
                             "train on. Hold out fewer.")
    return SceneSplit(scenes, train, held, tuple(str(ref) for ref in catalog))


class SceneSubset(gym.Wrapper):
    """A :class:`~tap_bench.sim.womd_env.WomdEnv` whose resets go through ``scenes`` only, in
    turn (a reset with a seed starts at ``scenes[seed % len(scenes)]``, as the env maps seeds
    onto its scenes): the training env of a split. A scene that cannot be built is skipped
    (with a warning) for the next one of ``scenes``, never for a held-out one.

    Args:
        env: the env (``cycle=True``).
        scenes: scene indexes of its catalog to train on (at least one).
    """

    def __init__(self, env: gym.Env, scenes: Sequence[int]) -> None:
        super().__init__(env)
        if not scenes:
            raise ParameterError("scenes", scenes, "at least one scene index")
        self.scenes = tuple(int(i) for i in scenes)
        self._next = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[Any, dict[str, Any]]:
        """Start the next training scene (see the class docstring)."""
        if seed is not None:
            self._next = int(seed) % len(self.scenes)
        for _ in range(len(self.scenes)):
            wanted = self.scenes[self._next]
            self._next = (self._next + 1) % len(self.scenes)
            obs, info = self.env.reset(seed=seed, options={**(options or {}),
                                                           "scene": wanted})
            seed = None
            if self.env.unwrapped.scene_index == wanted:
                return obs, info
            # the env skipped a scene it could not build (and may have gone on to one held
            # out): go on to the next training scene instead
            warnings.warn(f"training scene {wanted} could not be built; skipped.",
                          stacklevel=2)
        raise ParameterError("scenes", self.scenes, "scenes that can be built",
                             message=f"none of the training scenes {list(self.scenes)} can "
                             "be built (see the warnings).")
