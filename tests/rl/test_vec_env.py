"""SharedVecEnv: env 0 stepped in the training process, the others in workers, answering
every VecEnv call as Stable-Baselines3's SubprocVecEnv does."""

from __future__ import annotations

import functools

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from stable_baselines3.common.vec_env import SubprocVecEnv

from tap_bench.rl import vec_env as shared
from tap_bench.rl.training import _make_training_env
from tap_bench.sim.scenario_env import get_scenario


def _envs(n_envs: int, one_here: bool, scenario: str = "highway") -> SubprocVecEnv:
    make = functools.partial(_make_training_env, get_scenario(scenario), True)
    worker = functools.partial(_make_training_env, get_scenario(scenario), True, worker=True)
    return shared.training_vec_env(make, worker, n_envs, one_here=one_here)


def _reset_info(info: dict) -> dict:
    """A reset's info without what highway-env derives from the action it draws there from
    the unseeded action space: the action and its lane-change reward."""
    out = {k: v for k, v in info.items() if k != "action"}
    if isinstance(out.get("rewards"), dict):
        out["rewards"] = {k: v for k, v in out["rewards"].items()
                          if k != "lane_change_reward"}
    return out


def _run(vec: SubprocVecEnv, steps: int, seed: int,
         options: dict | None = None) -> list:
    """Everything the learner sees of ``steps`` steps with drawn actions, then of the other
    VecEnv calls (a reset with ``options``: default one vehicle fewer on highway)."""
    rng = np.random.default_rng(seed)
    vec.seed(seed)
    seen = [vec.reset(), [_reset_info(info) for info in vec.reset_infos]]
    for _ in range(steps):
        obs, rewards, dones, infos = vec.step(rng.integers(0, vec.action_space.n, vec.num_envs))
        for info in infos:  # Monitor's episode summary: all but its wall clock ("t")
            if "episode" in info:
                info["episode"] = {k: v for k, v in info["episode"].items() if k != "t"}
        # a worker answers each step with the info of its env's last reset, this step's or
        # an earlier one's (the action drawn by highway-env's reset left out, as above)
        reset_infos = [_reset_info(info) for info in vec.reset_infos]
        seen.append((obs, rewards, dones, infos, reset_infos))
    vec.seed(seed + 1)  # a reset with seeds and options, then a step
    vec.set_options(options or {"config": {"vehicles_count": 2}})
    seen.append((vec.reset(), vec.step(rng.integers(0, vec.action_space.n, vec.num_envs))[:3]))
    seen.append(vec.get_attr("spec"))
    seen.append(vec.env_method("get_episode_rewards"))
    seen.append(vec.env_method("get_episode_lengths", indices=[vec.num_envs - 1]))
    vec.set_attr("tap_note", "set", indices=[0])
    seen.append(vec.get_attr("tap_note", indices=[0]))
    seen.append(vec.has_attr("tap_note"))  # only env 0 has it
    vec.set_attr("tap_other", "set", indices=range(1, vec.num_envs))
    seen.append(vec.has_attr("tap_other"))  # all but env 0 have it
    seen.append(vec.has_attr("spec"))
    from gymnasium.wrappers import TimeLimit
    from stable_baselines3.common.monitor import Monitor

    seen.append(vec.env_is_wrapped(Monitor))
    seen.append(vec.env_is_wrapped(TimeLimit))  # not wrapped in it
    # a method called with keyword arguments: a reset to seed 7
    obs, info = vec.env_method("reset", seed=7, indices=[0])[0]
    seen.append((obs, _reset_info(info)))
    return seen


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (type(a) is type(b) and a.dtype == b.dtype
                and np.array_equal(a, b, equal_nan=True))
    if isinstance(a, dict):
        return (isinstance(b, dict) and list(a) == list(b)
                and all(_same(a[k], b[k]) for k in a))
    if isinstance(a, (list, tuple)):
        return (type(a) is type(b) and len(a) == len(b)
                and all(_same(x, y) for x, y in zip(a, b, strict=True)))
    return type(a) is type(b) and (a == b or (a != a and b != b))


@pytest.mark.parametrize("n_envs", [2, 3])
def test_every_call_is_answered_as_by_worker_processes(n_envs, write_scenario):
    """Observations, rewards, dones, infos (terminal observations, Monitor's episodes),
    reset infos (after the resets and after every step), attributes and method calls, over
    70 steps with episode ends, by crashes and by the time limit (8 decisions)."""
    short = str(write_scenario("short", duration=8))
    results = []
    for one_here in (False, True):
        vec = _envs(n_envs, one_here, short)
        try:
            assert isinstance(vec, shared.SharedVecEnv) == one_here
            assert len(vec.processes) == n_envs - one_here
            results.append(_run(vec, 70, seed=n_envs))
        finally:
            vec.close()
    workers, mixed = results
    assert _same(workers, mixed)
    ends = [info["TimeLimit.truncated"] for step in workers[2:72]
            for k, info in enumerate(step[3]) if step[2][k]]
    assert all(info.get("terminal_observation") is not None
               for step in workers[2:72] for k, info in enumerate(step[3]) if step[2][k])
    assert True in ends and False in ends  # episodes ended by the time limit and by crashes


def test_env_0_answers_with_copies_and_closes_with_the_others():
    vec = _envs(2, True)
    local = vec.remotes[0]
    vec.reset()
    actions = np.array([1, 1])
    vec.step_async(actions)
    actions[:] = 4  # the learner reuses its array: each env got its own copy
    *_, infos = vec.step_wait()
    assert [info["action"] for info in infos] == [1, 1]
    note = {"sent": 1}
    local.send(("set_attr", ("tap_note", note)))
    note["sent"] = 2  # the sender keeps its object; the env got a copy, as through a pipe
    local.recv()
    assert local.env.get_wrapper_attr("tap_note") == {"sent": 1}
    local.send(("get_attr", "config"))  # and the answer is a copy too
    config = local.recv()
    assert config == local.env.get_wrapper_attr("config")
    assert config is not local.env.get_wrapper_attr("config")
    closed = []
    local.env.close = lambda: closed.append(True)
    vec.step_async(np.array([1, 1]))  # closed while waiting for a step: still closes
    vec.close()
    assert closed == [True]
    assert vec.closed and not any(p.is_alive() for p in vec.processes)
    vec.close()  # twice is harmless
    assert closed == [True]


def test_a_failing_env_0_stops_the_workers_and_raises(monkeypatch):
    def broken():
        raise ValueError("env 0 cannot be built")

    started = []
    original = shared.SharedVecEnv.__init__

    def init(self, local_fn, worker_fns, start_method):
        try:
            original(self, local_fn, worker_fns, start_method)
        finally:
            started.extend(self.processes)

    monkeypatch.setattr(shared.SharedVecEnv, "__init__", init)
    worker = functools.partial(_make_training_env, get_scenario("highway"), True, worker=True)
    with pytest.raises(ValueError, match="env 0 cannot be built"):
        shared.training_vec_env(broken, worker, 2, one_here=True)
    for process in started:
        process.join(5)
    assert len(started) == 1 and not started[0].is_alive()


def test_another_sb3_worker_loop_falls_back_to_worker_processes(tmp_path, write_scenario):
    """Where the installed Stable-Baselines3's ``_worker`` is not the code repeated for env
    0, every env runs in a worker, and the start line says why."""
    from tap_bench.rl.training import train

    digests = shared._WORKER_CODE
    shared._WORKER_CODE = {"_worker": "0" * 16}
    shared.shared_envs_supported.cache_clear()
    try:
        assert not shared.shared_envs_supported()
        vec = _envs(2, True)
        try:
            assert type(vec) is SubprocVecEnv
        finally:
            vec.close()
        lines = []
        train("dqn", write_scenario("short", duration=5), timesteps=20, seed=0, n_envs=2,
              in_process="one", hyperparameters={"learning_starts": 10},
              output=tmp_path / "m.zip", announce=lines.append)
        starting = next(line for line in lines if "training env(s)" in line)
        assert "in worker processes" in starting
        assert "worker loop (SubprocVecEnv, _worker) is not" in starting
        lines = []  # one env runs in this process whatever in_process says: no reason given
        train("dqn", write_scenario("short", duration=5), timesteps=20, seed=0, n_envs=1,
              in_process="one", hyperparameters={"learning_starts": 10},
              output=tmp_path / "m1.zip", announce=lines.append)
        starting = next(line for line in lines if "training env(s)" in line)
        assert starting == "starting 1 training env(s) of tap_bench/short-v0 (fast variant) ..."
    finally:
        shared._WORKER_CODE = digests
        shared.shared_envs_supported.cache_clear()
    assert shared.shared_envs_supported()


def test_the_subprocvecenv_it_restates_is_checked_too(monkeypatch):
    """SharedVecEnv re-states SubprocVecEnv's ``__init__`` and ``close`` and uses its other
    methods with env 0's end of a pipe: another SB3 whose ``_worker`` is unchanged but whose
    SubprocVecEnv differs falls back to worker processes as well."""
    assert set(shared._WORKER_CODE) == {"_worker", "SubprocVecEnv"}
    monkeypatch.setattr(shared, "_WORKER_CODE", {**shared._WORKER_CODE, "SubprocVecEnv": "0" * 16})
    shared.shared_envs_supported.cache_clear()
    try:
        assert not shared.shared_envs_supported()
    finally:
        monkeypatch.undo()
        shared.shared_envs_supported.cache_clear()
    assert shared.shared_envs_supported()


def test_env_0_failing_to_close_still_closes_the_workers():
    """An env 0 whose ``close`` raises (as one left broken by an error mid-step may): the
    error reaches the caller, and the workers are closed and ended all the same, as
    SubprocVecEnv's workers end whatever their env's ``close`` does."""
    vec = _envs(3, True)
    vec.reset()

    def broken() -> None:
        raise RuntimeError("env 0 cannot close")

    vec.remotes[0].env.close = broken
    with pytest.raises(RuntimeError, match="env 0 cannot close"):
        vec.close()
    for process in vec.processes:
        process.join(10)
    assert not any(process.is_alive() for process in vec.processes)
    assert all(remote.closed for remote in vec.remotes[1:]) and vec.closed


def test_a_step_every_env_fails_raises_the_envs_error_and_close_still_closes():
    """An action no env knows: env 0's error reaches the learner; the workers died of the
    same error, and close reads no reply from them, closes env 0 and raises nothing, so
    that the env's error stays the one the caller sees (it was an EOFError from close)."""
    vec = _envs(3, True)
    vec.reset()
    closed = []
    close = vec.remotes[0].env.close
    vec.remotes[0].env.close = lambda: (closed.append(True), close())
    vec.step_async(np.array([99, 99, 99]))
    with pytest.raises(KeyError):
        vec.step_wait()
    vec.close()
    assert closed == [True] and vec.closed
    for process in vec.processes:
        process.join(10)
    assert not any(process.is_alive() for process in vec.processes)


@pytest.mark.parametrize(("scenario", "seed"), [("merge", 11), ("roundabout", 12),
                                                ("intersection", 13), ("exit", 14),
                                                ("cut_in", 15)])
def test_other_scenarios_and_seeds_are_answered_as_by_worker_processes(scenario, seed):
    """The every-call comparison on the other scenarios (their own observations, actions,
    rewards and episode ends), each with its own seed and drawn actions, 2 envs."""
    results = []
    for one_here in (False, True):
        vec = _envs(2, one_here, scenario)
        try:
            results.append(_run(vec, 25, seed=seed,
                                options={"config": {"collision_reward": -0.5}}))
        finally:
            vec.close()
    assert _same(*results)
