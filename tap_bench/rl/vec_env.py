"""Training envs stepped by worker processes and by the training process itself.

With ``n`` training envs on ``n`` free cores, Stable-Baselines3's ``SubprocVecEnv`` runs
``n`` worker processes beside the training process: ``n + 1`` busy processes (the learner's
gradient steps overlap the workers' simulation, :mod:`tap_bench.rl.overlap`) take turns on
``n`` cores, and every step of every env goes through a pipe. :class:`SharedVecEnv` steps
env 0 in the training process, after the actions of the others are sent, while the workers
step envs 1 to ``n - 1``: ``n`` busy processes on ``n`` cores, one env fewer through the
pipes. On 2 free cores of this machine, DQN on highway with 2 envs: 500.0 env steps per
second against 454.5 with 2 workers (medians of 3 rounds, load 1.0-1.4; 383-403 against
328-361 before the simulation's last cuts), the same weights
(``benchmarks/bench_train_speed.py``, variants ``2-envs-one`` and ``2-envs-workers``;
docs/simulation.md).

Everything else is ``SubprocVecEnv``'s: the same commands, in the same order, answered by
the same code (``_worker``'s, repeated for env 0 by :class:`_LocalRemote`), and both the
command and env 0's answer go through a pickle round trip, as a worker's through its pipe:
the training sees the same observations, rewards, infos and seeds, and trains the same
weights (tested). The repeated code is that of Stable-Baselines3 2.x's ``_worker``
(:func:`shared_envs_supported` checks its source and ``SubprocVecEnv``'s): where the
installed ones differ, :func:`training_vec_env` uses ``SubprocVecEnv``.

Parts of this module re-state Stable-Baselines3's ``_worker`` (MIT License, Copyright (c)
2019 Antonin Raffin): see THIRD_PARTY_NOTICES.md. It subclasses Stable-Baselines3 classes:
it is imported only where SB3 is installed.
"""

from __future__ import annotations

import contextlib
import functools
import multiprocessing as mp
from collections.abc import Callable
from multiprocessing.reduction import ForkingPickler
from typing import Any

import gymnasium as gym
from stable_baselines3.common.env_util import is_wrapped
from stable_baselines3.common.vec_env import SubprocVecEnv, VecEnv, subproc_vec_env
from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper
from stable_baselines3.common.vec_env.patch_gym import _patch_env

from tap_bench.sim.fast_idm import sources_match

__all__ = ["SharedVecEnv", "shared_envs_supported", "training_vec_env"]

_WORKER_CODE = {"_worker": "1be31eb7f21f5d1f", "SubprocVecEnv": "ab7a417dc590024c"}
"""sha256 (first 16 hex digits) of the sources of Stable-Baselines3's ``_worker`` (2.x, as of
2.9), which :meth:`_LocalRemote._answer` repeats, and of its ``SubprocVecEnv``, whose
``__init__`` and ``close`` :class:`SharedVecEnv` re-states and whose other methods it runs
with env 0's end of a "pipe" (:class:`_LocalRemote`: ``send`` and ``recv`` only)."""


@functools.cache
def shared_envs_supported() -> bool:
    """Whether the installed Stable-Baselines3's ``_worker`` and ``SubprocVecEnv`` are the
    code :class:`_LocalRemote` and :class:`SharedVecEnv` repeat and rely on (checked once
    per process)."""
    return sources_match([subproc_vec_env._worker, SubprocVecEnv], _WORKER_CODE)


def _copy(obj: Any) -> Any:
    """``obj`` through a pickle round trip, as a pipe between processes carries it."""
    return ForkingPickler.loads(ForkingPickler.dumps(obj))


class _LocalRemote:
    """The training process's end of a "pipe" to the env it steps itself: a command sent
    is answered when its reply is read (so that the workers get their commands first), by
    the code of Stable-Baselines3's ``_worker`` loop; command and reply are copied as a
    pipe copies them (nothing the env keeps is shared with the learner).

    Attributes:
        env: the env.
        pending: the commands sent and not yet answered, oldest first.
        reset_info: the info of the env's last reset, which ``_worker`` sends with every
            step (a local of its loop, kept from one command to the next: a step that ends
            no episode answers with the info of the last reset, not ``{}``).
    """

    def __init__(self, env: gym.Env) -> None:
        self.env = env
        self.pending: list[tuple[str, Any]] = []
        self.reset_info: dict[str, Any] | None = {}

    def send(self, command: tuple[str, Any]) -> None:
        """Queue ``command`` (answered by the next :meth:`recv`)."""
        self.pending.append(_copy(command))

    def recv(self) -> Any:
        """The answer to the oldest command sent and not yet answered."""
        if not self.pending:
            raise EOFError("no command is waiting for the env stepped in this process")
        return _copy(self._answer(*self.pending.pop(0)))

    def discard(self) -> None:
        """Forget the commands not answered (the training stopped half-way)."""
        self.pending.clear()

    def close(self) -> None:
        """Close the env."""
        self.pending.clear()
        self.env.close()

    def _answer(self, cmd: str, data: Any) -> Any:
        """Stable-Baselines3 2.x ``_worker``'s answer to ``(cmd, data)``."""
        env = self.env
        if cmd == "step":
            observation, reward, terminated, truncated, info = env.step(data)
            done = terminated or truncated
            info["TimeLimit.truncated"] = truncated and not terminated
            if done:
                info["terminal_observation"] = observation
                observation, self.reset_info = env.reset()
            return observation, reward, done, info, self.reset_info
        if cmd == "reset":
            maybe_options = {"options": data[1]} if data[1] else {}
            observation, self.reset_info = env.reset(seed=data[0], **maybe_options)
            return observation, self.reset_info
        if cmd == "render":
            return env.render()
        if cmd == "get_spaces":
            return env.observation_space, env.action_space
        if cmd == "env_method":
            return env.get_wrapper_attr(data[0])(*data[1], **data[2])
        if cmd == "get_attr":
            return env.get_wrapper_attr(data)
        if cmd == "has_attr":
            try:
                env.get_wrapper_attr(data)
            except AttributeError:
                return False
            return True
        if cmd == "set_attr":
            return setattr(env, data[0], data[1])
        if cmd == "is_wrapped":
            return is_wrapped(env, data)
        raise NotImplementedError(f"`{cmd}` is not implemented in the worker")


class SharedVecEnv(SubprocVecEnv):
    """``SubprocVecEnv`` whose env 0 is stepped in this process (see the module docstring).

    Args:
        local_fn: builds env 0, in this process.
        worker_fns: build envs 1 to ``n - 1``, one per worker process.
        start_method: multiprocessing's start method for the workers.
    """

    def __init__(self, local_fn: Callable[[], gym.Env],
                 worker_fns: list[Callable[[], gym.Env]], start_method: str) -> None:
        self.waiting = False
        self.closed = False
        ctx = mp.get_context(start_method)
        self.processes = []
        remotes: list[Any] = []
        for env_fn in worker_fns:  # started first: they build their envs meanwhile
            remote, work_remote = ctx.Pipe()
            process = ctx.Process(target=subproc_vec_env._worker, daemon=True,  # type: ignore[attr-defined]
                                  args=(work_remote, remote, CloudpickleWrapper(env_fn)))
            process.start()
            self.processes.append(process)
            work_remote.close()
            remotes.append(remote)
        try:
            local = _LocalRemote(_patch_env(local_fn()))
        except BaseException:
            for process in self.processes:
                process.terminate()
            raise
        self.remotes = (local, *remotes)
        self.work_remotes = ()
        local.send(("get_spaces", None))
        observation_space, action_space = local.recv()
        VecEnv.__init__(self, len(self.remotes), observation_space, action_space)

    def close(self) -> None:
        """Close every env: env 0 here, the workers' (which then end)."""
        if self.closed:
            return
        local, workers = self.remotes[0], self.remotes[1:]
        if self.waiting:  # a step was sent and not read: the workers' replies are read
            local.discard()
            for remote in workers:
                # a worker whose env failed has ended (the error that stopped the training,
                # env 0's or theirs, stays the one the caller sees)
                with contextlib.suppress(EOFError, ConnectionError):
                    remote.recv()
            self.waiting = False
        try:
            local.close()
        finally:  # the workers end even when env 0's close fails, as a worker's env may
            for remote in workers:
                with contextlib.suppress(ConnectionError):  # ended already
                    remote.send(("close", None))
            for process in self.processes:
                process.join()
            for remote in workers:
                remote.close()
            self.closed = True


def training_vec_env(local_fn: Callable[[], gym.Env], worker_fn: Callable[[], gym.Env],
                     n_envs: int, *, one_here: bool,
                     start_method: str = "forkserver") -> SubprocVecEnv:
    """``n_envs`` training envs in worker processes (each built by ``worker_fn``), env 0 in
    this process (built by ``local_fn``) when ``one_here`` (:class:`SharedVecEnv`, where
    :func:`shared_envs_supported`; else every env in a worker: ``SubprocVecEnv``)."""
    if one_here and shared_envs_supported():
        return SharedVecEnv(local_fn, [worker_fn] * (n_envs - 1), start_method=start_method)
    return SubprocVecEnv([worker_fn] * n_envs, start_method=start_method)
