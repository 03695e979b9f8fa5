"""Gradient steps of an off-policy learner overlapped with its envs' simulation.

Stable-Baselines3's off-policy loop (DQN) alternates: the envs simulate one step while the
learner waits, then the learner takes its gradient steps while the envs wait. With the envs
in worker processes the two can run at once: :func:`overlapping` makes a learner whose
``train`` only notes the gradient steps asked for, and :class:`OverlapVecEnv` runs them
after it has sent the next actions to the workers, while they simulate. The differences
from the plain loop: the action of a step is chosen by the network as it was before the
previous step's gradient steps (one update of lag, among thousands; highway-env's DQN takes
one gradient step per step); the exploration draws and the replay buffer's sample draws
come in another order from the same generator, so a seeded run reproduces itself, not the
plain loop's run; and the learner now computes while the workers do, three busy
processes on two cores. Nothing in the gradient steps may talk to the envs (the workers'
reply to the pending step would be read instead): DQN's do not.
``benchmarks/bench_train_speed.py`` measures what it saves.

This module subclasses Stable-Baselines3 classes: it is imported only where SB3 is installed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

__all__ = ["FlushPendingCallback", "OverlapVecEnv", "overlapping"]


class OverlapVecEnv(VecEnvWrapper):
    """A vectorised env that runs the learner's pending gradient steps while its workers
    simulate the step just sent (see the module docstring)."""

    def __init__(self, venv: VecEnv) -> None:
        super().__init__(venv)
        self.pending: Callable[[], None] | None = None

    def reset(self) -> Any:
        """Reset every env."""
        return self.venv.reset()

    def step_wait(self) -> Any:
        """Run the pending gradient steps, then wait for the workers' step."""
        self.flush()
        return self.venv.step_wait()

    def flush(self) -> None:
        """Run the pending gradient steps now, if any."""
        pending, self.pending = self.pending, None
        if pending is not None:
            pending()


def overlapping(cls: type, env: OverlapVecEnv) -> type:
    """A subclass of the off-policy algorithm ``cls`` whose gradient steps wait in ``env``
    for the next simulated step (:class:`OverlapVecEnv`)."""

    class Overlapping(cls):  # type: ignore[misc, valid-type]
        def train(self, gradient_steps: int, batch_size: int = 100) -> None:
            env.flush()  # never more than one batch of gradient steps pending
            env.pending = lambda: cls.train(self, gradient_steps, batch_size)

    Overlapping.__name__ = Overlapping.__qualname__ = cls.__name__
    return Overlapping


class FlushPendingCallback(BaseCallback):
    """Runs the gradient steps still pending in ``env`` when the training ends, before the
    callbacks after it (a learning curve's last point) see the model."""

    def __init__(self, env: OverlapVecEnv) -> None:
        super().__init__()
        self.env = env

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self.env.flush()
