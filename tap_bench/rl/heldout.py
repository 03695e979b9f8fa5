"""Recorded scenes held out of training: an agent trained on some scenes of WOMD files is
judged on the others, which it never saw (``tap-bench train --env womd --hold-out SEEDS``).

Scenes are named as everywhere on recorded scenes: by their index in the files' catalog
(file and record order; :meth:`~tap_bench.sim.womd_scene.WomdScenes.seeds`), so a rollout
or suite run on the held-out scenes names the same seeds (``--seeds``).
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tap_bench.errors import ParameterError
from tap_bench.sim.womd_scene import CURRENT_STEP, Scene, SceneError, WomdScenes

__all__ = ["EGOS", "MIN_TRAVEL", "SceneSplit", "SceneSubset", "drivers", "seen_in_training",
           "split_scenes"]

EGOS = ("sdc", "all")
"""Who the agent drives in a training scene: the scene's ego (``"sdc"``), or every vehicle
of :func:`drivers` in turn (``"all"``)."""

MIN_TRAVEL = 5.0  # [m] a vehicle that drives less over the future is not a training ego


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


def drivers(scene: Scene, min_travel: float = MIN_TRAVEL) -> list[str]:
    """The track ids of ``scene``'s vehicles an agent can learn to drive: the scene's ego
    first, then every other vehicle valid from the current time to the record's end that
    travels at least ``min_travel`` [m] along its log (a parked or waiting car teaches
    little), in row order. Whether each has a route on the map is known only once the
    env builds it (:class:`SceneSubset` skips those without)."""
    valid = scene.valid[:, CURRENT_STEP:].all(axis=1)
    x, y = scene.x[:, CURRENT_STEP:], scene.y[:, CURRENT_STEP:]
    with np.errstate(invalid="ignore"):
        travel = np.nansum(np.hypot(np.diff(x, axis=1), np.diff(y, axis=1)), axis=1)
    rows = [scene.ego] + [int(r) for r in np.flatnonzero(
        valid & (scene.object_types == "vehicle") & (travel >= min_travel))
        if r != scene.ego]
    return [str(scene.track_ids[r]) for r in rows]


class SceneSubset(gym.Wrapper):
    """A :class:`~tap_bench.sim.womd_env.WomdEnv` whose resets go through ``scenes`` only, in
    turn (a reset with a seed starts at ``scenes[seed % len(scenes)]``, as the env maps seeds
    onto its scenes): the training env of a split. A scene that cannot be built is skipped
    (with a warning) for the next one of ``scenes``, never for a held-out one.

    With ``egos="all"`` the k-th visit of a scene drives the k-th of its :func:`drivers`
    (in turn, starting again after the last): the same scenes teach as many situations as
    they hold drivers. A driver the env cannot build a route for is dropped, with a
    warning, and the next one driven.

    Args:
        env: the env (``cycle=True``).
        scenes: scene indexes of its catalog to train on (at least one).
        egos: one of :data:`EGOS`.
    """

    def __init__(self, env: gym.Env, scenes: Sequence[int], egos: str = "sdc") -> None:
        super().__init__(env)
        if not scenes:
            raise ParameterError("scenes", scenes, "at least one scene index")
        if egos not in EGOS:
            raise ParameterError("egos", egos, f"one of {EGOS}")
        self.scenes = tuple(int(i) for i in scenes)
        self.egos = egos
        self._next = 0
        self._drivers: dict[int, list[str]] = {}  # scene -> its drivers (egos="all")
        self._visits: dict[int, int] = {}  # scene -> visits so far

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[Any, dict[str, Any]]:
        """Start the next training scene (see the class docstring)."""
        if seed is not None:
            self._next = int(seed) % len(self.scenes)
        inner = self.env.unwrapped
        for _ in range(len(self.scenes)):
            wanted = self.scenes[self._next]
            self._next = (self._next + 1) % len(self.scenes)
            track = self._driver(wanted)
            obs, info = self.env.reset(seed=seed, options={**(options or {}),
                                                           "scene": wanted, "ego": track})
            seed = None
            if inner.scene_index == wanted and (
                    track is None or str(inner.scene.track_ids[inner.scene.ego]) == track):
                return obs, info
            if track is not None:  # that driver has no route (or cannot be driven)
                warnings.warn(f"training scene {wanted}: track {track} cannot be driven as "
                              "the ego (no route on the map); not trained on.", stacklevel=2)
                self._drivers[wanted].remove(track)
                obs, info = self.env.reset(options={**(options or {}), "scene": wanted})
                if inner.scene_index == wanted:
                    return obs, info
            # the env skipped a scene it could not build (and may have gone on to one held
            # out): go on to the next training scene instead
            warnings.warn(f"training scene {wanted} could not be built; skipped.",
                          stacklevel=2)
        raise ParameterError("scenes", self.scenes, "scenes that can be built",
                             message=f"none of the training scenes {list(self.scenes)} can "
                             "be built (see the warnings).")

    def _driver(self, scene: int) -> str | None:
        """The track to drive on this visit of ``scene`` (None: the scene's own ego)."""
        if self.egos == "sdc":
            return None
        names = self._drivers.get(scene)
        if names is None:
            try:
                names = drivers(self.env.unwrapped.scene_at(scene))
            except SceneError:  # the reset says why (and skips it)
                return None
            self._drivers[scene] = names
        visit = self._visits.get(scene, 0)
        self._visits[scene] = visit + 1
        track = names[visit % len(names)]
        return None if track == names[0] else track


def _scene_key(ref: str, root: Path) -> tuple[str, int]:
    """A scene ref (``"file record k"``, or a pickle's ``"file"``) as (the file's real path,
    with a relative one taken from ``root``; the record)."""
    path, _, record = str(ref).rpartition(" record ")
    if not path:  # no record: a one-scene file
        path, record = str(ref), "0"
    full = Path(path) if Path(path).is_absolute() else root / path
    return os.path.realpath(full), int(record)


def seen_in_training(params: Mapping[str, Any], refs: Sequence[str],
                     roots: Sequence[str | os.PathLike]) -> list[bool | None]:
    """For each of the scenes ``refs`` (``"file record k"``, as
    :meth:`~tap_bench.sim.womd_scene.WomdScenes.catalog` names them): True where a trained
    agent's definition (``params``: ``womd``, ``train_scenes``, ``held_out_refs``, as
    ``tap-bench train --hold-out`` records them) trained on it, False where it held it out,
    None where the files it trained on do not hold it (new to it). The definition's relative
    paths are tried from each of ``roots`` in turn (the folder training ran in: the project
    root for ``policies/``, or the current folder); a root under which no training file
    exists is skipped. An empty list where the definition records no split."""
    if not params.get("womd") or "train_scenes" not in params:
        return []
    for root in map(Path, roots):
        files = [f if Path(f).is_absolute() else str(root / f) for f in params["womd"]]
        if not all(Path(f).exists() for f in files):
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a folder's README: noted when it was read
            catalog = [str(r) for r in WomdScenes(tuple(files)).catalog()]
        trained = {_scene_key(catalog[i], Path.cwd()) for i in params["train_scenes"]
                   if i < len(catalog)}
        held = {_scene_key(r, root) for r in params.get("held_out_refs") or ()}
        keys = [_scene_key(r, Path.cwd()) for r in refs]
        return [True if k in trained else False if k in held else None for k in keys]
    return [None] * len(refs)
