"""Training envs stepped by worker processes and by the training process itself.

With ``n`` training envs on ``n`` free cores, one env in a worker process per env makes
``n + 1`` busy processes (the learner's gradient steps overlap the workers' simulation,
:mod:`tap_bench.rl.overlap`) take turns on ``n`` cores, and every step of every env go
through a pipe. :class:`SharedVecEnv` steps env 0 in the training process, after the
actions of the others are sent, while worker processes step envs 1 to ``n - 1``: ``n``
busy processes on ``n`` cores, one env fewer through the pipes. The figures are in
docs/simulation.md (``benchmarks/bench_train_speed.py``, variants ``2-envs-one`` and
``2-envs-workers``).

:class:`SharedVecEnv` implements Stable-Baselines3's ``VecEnv`` interface and contract:
an env whose episode ends is reset at once, its last observation in its info
(``"terminal_observation"``) and ``"TimeLimit.truncated"`` set; ``reset_infos`` holds each
env's last reset info; ``seed`` and ``set_options`` apply to the next ``reset``. Every env
is held by an :class:`EnvHost`, which answers the requests of :data:`REQUESTS`: env 0's in
this process, the others' each in a worker (:func:`serve`). A worker answers
``(True, value)``, or ``(False, (error, traceback))`` when its env raised (the worker lives
on: the error is raised in the training process, with the worker's traceback as a note).
Everything env 0 is given and answers goes through a pickle round trip, as a worker's
does through its pipe, so that the learner and env 0 share no object: the same
observations, rewards, dones and infos as Stable-Baselines3's ``SubprocVecEnv`` for the
same seeds, and the same trained weights (tested).

This module subclasses Stable-Baselines3's ``VecEnv``: it is imported only where SB3 is
installed.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import pickle
import traceback
from collections.abc import Callable, Iterable, Sequence
from multiprocessing.connection import Connection
from multiprocessing.reduction import ForkingPickler
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import SubprocVecEnv, VecEnv

__all__ = ["REQUESTS", "EnvHost", "SharedVecEnv", "serve", "training_vec_env"]

REQUESTS = ("step", "reset", "call", "get", "has", "set", "wrapped", "spaces", "render")
"""The requests an :class:`EnvHost` answers (its methods of these names), and ``"close"``
that ends a worker."""


def _copy(obj: Any) -> Any:
    """``obj`` through a pickle round trip, as a pipe between processes carries it."""
    return ForkingPickler.loads(ForkingPickler.dumps(obj))


class EnvHost:
    """One training env and the state the requests need: the info of its last reset.

    Args:
        env: the env (gymnasium API).

    Attributes:
        env: the env.
        reset_info: the info of the env's last reset (``{}`` before the first), answered
            with every step, as ``VecEnv.reset_infos`` holds it.
    """

    def __init__(self, env: gym.Env) -> None:
        self.env = env
        self.reset_info: dict[str, Any] = {}

    def step(self, action: Any) -> tuple[Any, float, bool, dict, dict]:
        """One step with ``action``: ``(observation, reward, done, info, reset_info)``.
        When the episode ends (terminated or truncated) the env is reset at once:
        ``observation`` is then the reset's, the step's is ``info["terminal_observation"]``
        and ``reset_info`` the reset's info. ``info["TimeLimit.truncated"]``: the episode
        was truncated and not terminated."""
        observation, reward, terminated, truncated, info = self.env.step(action)
        info["TimeLimit.truncated"] = bool(truncated and not terminated)
        ended = bool(terminated or truncated)
        if ended:
            info["terminal_observation"] = observation
            observation, self.reset_info = self.env.reset()
        return observation, reward, ended, info, self.reset_info

    def reset(self, seed: int | None, options: dict[str, Any]) -> tuple[Any, dict]:
        """Reset with ``seed`` (None: the env's own stream) and ``options`` (``{}``: none
        passed): ``(observation, info)``."""
        extra = {"options": options} if options else {}
        observation, self.reset_info = self.env.reset(seed=seed, **extra)
        return observation, self.reset_info

    def call(self, name: str, args: tuple, kwargs: dict[str, Any]) -> Any:
        """What the env's method ``name`` (found through its wrappers) returns."""
        return self.env.get_wrapper_attr(name)(*args, **kwargs)

    def get(self, name: str) -> Any:
        """The env's attribute ``name``, found through its wrappers."""
        return self.env.get_wrapper_attr(name)

    def has(self, name: str) -> bool:
        """Whether the env or one of its wrappers has attribute ``name``."""
        try:
            self.env.get_wrapper_attr(name)
        except AttributeError:
            return False
        return True

    def set(self, name: str, value: Any) -> None:
        """Set attribute ``name`` of the outermost wrapper."""
        setattr(self.env, name, value)

    def wrapped(self, wrapper_class: type) -> bool:
        """Whether a wrapper of ``wrapper_class`` is in the env's wrapper chain."""
        env = self.env
        while isinstance(env, gym.Wrapper):
            if isinstance(env, wrapper_class):
                return True
            env = env.env
        return False

    def spaces(self) -> tuple[gym.Space, gym.Space]:
        """The env's observation and action spaces."""
        return self.env.observation_space, self.env.action_space

    def render(self) -> Any:
        """The env's rendering (its ``render_mode``'s)."""
        return self.env.render()

    def close(self) -> None:
        """Close the env."""
        self.env.close()


def serve(connection: Connection, build: Callable[[], gym.Env]) -> None:
    """A worker process: build the env, answer ``("built", spaces)`` (or the build's
    error), then answer each request ``(name, args)`` received until ``"close"`` or the
    training process's end of the pipe closes. A request the env fails is answered with
    the error and its traceback; the worker then waits for the next."""
    try:
        host = EnvHost(build())
        connection.send((True, host.spaces()))
    except Exception as error:  # the training process raises it
        connection.send((False, (error, traceback.format_exc())))
        return
    try:
        while True:
            try:
                name, args = connection.recv()
            except EOFError:  # the training process is gone
                break
            if name == "close":
                host.close()
                break
            try:
                answer = (True, getattr(host, name)(*args))
            except Exception as error:
                answer = (False, (error, traceback.format_exc()))
            try:
                connection.send(answer)
            except (pickle.PicklingError, TypeError, AttributeError) as error:
                connection.send((False, (error, traceback.format_exc())))
    except KeyboardInterrupt:  # Ctrl-C reaches the whole process group: end quietly
        pass
    finally:
        connection.close()


def _answer(reply: tuple[bool, Any], worker: int) -> Any:
    """The value of a worker's reply; its env's error raised, with the worker's traceback
    as a note (Python 3.11+)."""
    ok, value = reply
    if ok:
        return value
    error, trace = value
    if hasattr(error, "add_note"):
        error.add_note(f"raised in the env of worker {worker}:\n{trace}")
    raise error


def _stack(observations: Sequence[Any], space: gym.Space) -> Any:
    """The envs' observations as one batch: an array with the envs first, per key for a
    ``Dict`` space and per element for a ``Tuple`` space."""
    if isinstance(space, gym.spaces.Dict):
        return {key: np.stack([o[key] for o in observations]) for key in space.spaces}
    if isinstance(space, gym.spaces.Tuple):
        return tuple(np.stack([o[k] for o in observations]) for k in range(len(space.spaces)))
    return np.stack(observations)


class SharedVecEnv(VecEnv):
    """``n`` envs: env 0 stepped in this process, envs 1 to ``n - 1`` each in a worker
    process (see the module docstring).

    Args:
        local_fn: builds env 0, in this process.
        worker_fns: build envs 1 to ``n - 1``, one in each worker process (picklable:
            module-level functions, or ``functools.partial`` of them).
        start_method: multiprocessing's start method for the workers.

    Attributes:
        local: env 0's :class:`EnvHost`.
        connections: the pipes to the workers (env ``k`` is ``connections[k - 1]``'s).
        processes: the worker processes.
        closed: whether :meth:`close` ran (or the workers were stopped).
    """

    def __init__(self, local_fn: Callable[[], gym.Env],
                 worker_fns: Sequence[Callable[[], gym.Env]], start_method: str) -> None:
        context = mp.get_context(start_method)
        self.closed = False
        self._sent = False  # a step or reset sent to the workers and not read yet
        self._action0: Any = None
        self.processes: list[Any] = []
        self.connections: list[Connection] = []
        for build in worker_fns:  # started first: they build their envs meanwhile
            ours, theirs = context.Pipe()
            process = context.Process(target=serve, args=(theirs, build), daemon=True)
            process.start()
            theirs.close()
            self.processes.append(process)
            self.connections.append(ours)
        try:
            self.local = EnvHost(local_fn())
            for k, connection in enumerate(self.connections, start=1):
                _answer(connection.recv(), k)  # built (or its error raised)
        except BaseException:
            self._stop()
            raise
        observation_space, action_space = self.local.spaces()
        super().__init__(len(self.connections) + 1, observation_space, action_space)

    # -- requests ----------------------------------------------------------------------
    def _ask(self, name: str, args_of: Callable[[int], tuple],
             indices: Iterable[int]) -> list[Any]:
        """Request ``name`` of the envs ``indices`` (``args_of(k)``: env ``k``'s
        arguments): the workers' first, then env 0's here; the answers in ``indices``'
        order. Every reply is read before a worker's error is raised."""
        indices = list(indices)
        for k in indices:
            if k > 0:
                self.connections[k - 1].send((name, args_of(k)))
        local = None
        try:
            if 0 in indices:
                local = _copy(getattr(self.local, name)(*_copy(args_of(0))))
        finally:  # read even when env 0 raised: the pipes stay in step
            replies = {k: self.connections[k - 1].recv() for k in indices if k > 0}
        return [local if k == 0 else _answer(replies[k], k) for k in indices]

    def step_async(self, actions: np.ndarray) -> None:
        """Send envs 1 to ``n - 1`` their actions (they step now); env 0 steps in
        :meth:`step_wait`. ``actions``: one per env, the envs first."""
        for k, connection in enumerate(self.connections, start=1):
            connection.send(("step", (actions[k],)))
        self._action0 = _copy(actions[0])
        self._sent = True

    def step_wait(self) -> tuple[Any, np.ndarray, np.ndarray, list[dict]]:
        """Step env 0 here, then read the workers' steps: the observations (the envs
        first), rewards (float), dones (bool) and infos; ``reset_infos`` updated."""
        local = _copy(self.local.step(self._action0))
        replies = [connection.recv() for connection in self.connections]
        self._sent = False
        results = [local, *(_answer(reply, k) for k, reply in enumerate(replies, start=1))]
        observations, rewards, dones, infos, reset_infos = zip(*results, strict=True)
        self.reset_infos = list(reset_infos)
        return (_stack(observations, self.observation_space), np.stack(rewards),
                np.stack(dones), list(infos))

    def reset(self) -> Any:
        """Reset every env with the seeds and options set for this reset (``seed``,
        ``set_options``; then forgotten): the observations; ``reset_infos`` their infos."""
        answers = self._ask("reset", lambda k: (self._seeds[k], self._options[k]),
                            range(self.num_envs))
        observations = [observation for observation, _ in answers]
        self.reset_infos = [info for _, info in answers]
        self._reset_seeds()
        self._reset_options()
        return _stack(observations, self.observation_space)

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        """Attribute ``attr_name`` of each env of ``indices`` (None: all)."""
        return self._ask("get", lambda k: (attr_name,), self._get_indices(indices))

    def has_attr(self, attr_name: str) -> bool:
        """Whether every env has attribute ``attr_name``."""
        return all(self._ask("has", lambda k: (attr_name,), range(self.num_envs)))

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        """Set attribute ``attr_name`` of each env of ``indices`` (None: all) to a copy of
        ``value``."""
        self._ask("set", lambda k: (attr_name, value), self._get_indices(indices))

    def env_method(self, method_name: str, *method_args: Any, indices: Any = None,
                   **method_kwargs: Any) -> list[Any]:
        """What each env of ``indices`` (None: all) returns for its method
        ``method_name`` called with the arguments given."""
        return self._ask("call", lambda k: (method_name, method_args, method_kwargs),
                         self._get_indices(indices))

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper],
                       indices: Any = None) -> list[bool]:
        """Whether each env of ``indices`` (None: all) is wrapped in ``wrapper_class``."""
        return self._ask("wrapped", lambda k: (wrapper_class,), self._get_indices(indices))

    def get_images(self) -> Sequence[np.ndarray | None]:
        """Each env's rendering (``rgb_array`` mode: an image)."""
        return self._ask("render", lambda k: (), range(self.num_envs))

    # -- ending ------------------------------------------------------------------------
    def close(self) -> None:
        """Close every env: env 0 here, then the workers' (which then end). A step sent
        and not read (the training stopped by an error) is read first; env 0's error on
        closing is raised after the workers have ended."""
        if self.closed:
            return
        if self._sent:
            for connection in self.connections:
                # a worker that died has nothing to read: the error that stopped the
                # training stays the one the caller sees
                with contextlib.suppress(EOFError, OSError):
                    connection.recv()
            self._sent = False
        try:
            self.local.close()
        finally:
            for connection in self.connections:
                with contextlib.suppress(OSError):  # ended already
                    connection.send(("close", ()))
            for process in self.processes:
                process.join()
            for connection in self.connections:
                connection.close()
            self.closed = True

    def _stop(self) -> None:
        """End the workers without a word (env 0 could not be built, or a worker's env)."""
        for process in self.processes:
            process.terminate()
        for process in self.processes:
            process.join()
        for connection in self.connections:
            connection.close()
        self.closed = True


def training_vec_env(local_fn: Callable[[], gym.Env], worker_fn: Callable[[], gym.Env],
                     n_envs: int, *, one_here: bool,
                     start_method: str = "forkserver") -> VecEnv:
    """``n_envs`` training envs: env 0 in this process (built by ``local_fn``) and the others
    each in a worker process (built by ``worker_fn``) when ``one_here``
    (:class:`SharedVecEnv`); else each in a worker process (Stable-Baselines3's
    ``SubprocVecEnv``)."""
    if one_here:
        return SharedVecEnv(local_fn, [worker_fn] * (n_envs - 1), start_method=start_method)
    return SubprocVecEnv([worker_fn] * n_envs, start_method=start_method)
