"""A Stable-Baselines3 callback that logs the behaviour coverage of recent episodes.

Coverage here is the quick training-time signal of :func:`tap_bench.sim.coverage.label_coverage`
over the ego's SDL labels of the last ``window`` episodes.

This module imports Stable-Baselines3: import it only where SB3 is installed.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Collection

from stable_baselines3.common.callbacks import BaseCallback

from tap_bench.errors import ParameterError
from tap_bench.sim.coverage import label_coverage

__all__ = ["CoverageCallback"]


class CoverageCallback(BaseCallback):
    """Logs ``tap/coverage`` (:func:`label_coverage` of the ego labels of the last
    ``window`` episodes), ``tap/distinct_labels`` and ``tap/episodes_labelled`` to SB3's
    logger at every episode end.

    The training env must be wrapped in :class:`tap_bench.sim.wrappers.EpisodeLabels`
    (``tracks="ego"`` is enough), which puts ``tap_ego_sdl`` in the final ``info``.

    Args:
        window: number of recent episodes.
        reference: labels to cover; None for the single labels of ``level``.
        level: the TAP level the env's wrapper labels at.
    """

    def __init__(self, window: int = 100, reference: Collection[str] | None = None, *,
                 level: str = "action", verbose: int = 0) -> None:
        super().__init__(verbose)
        if window < 1:
            raise ParameterError("window", window, "",
                message=f"CoverageCallback: window must be >= 1 episode, got {window}.")
        self.window = window
        self.reference = reference
        self.level = level
        self.recent: deque[str] = deque(maxlen=window)
        self.episodes = 0
        self.coverage = 0.0

    def _on_step(self) -> bool:
        infos = self.locals.get("infos", ())
        dones = self.locals.get("dones", ())
        for done, info in zip(dones, infos, strict=False):
            if not done:
                continue
            if "tap_ego_sdl" not in info:
                raise RuntimeError(
                    "CoverageCallback: the finished episode's info has no 'tap_ego_sdl'; wrap "
                    "the training env in tap_bench.sim.wrappers.EpisodeLabels.")
            self.episodes += 1
            if info["tap_ego_sdl"] is not None:
                self.recent.append(info["tap_ego_sdl"])
            self.coverage = (label_coverage(self.recent, self.reference, level=self.level)
                             if self.recent else 0.0)
            self.logger.record("tap/coverage", self.coverage)
            self.logger.record("tap/distinct_labels", len(set(self.recent)))
            self.logger.record("tap/episodes_labelled", self.episodes)
        return True
