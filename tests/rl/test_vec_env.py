"""SharedVecEnv: env 0 stepped in the training process, the others in workers, answering
every VecEnv call as Stable-Baselines3's SubprocVecEnv (and DummyVecEnv) do for the same
seeds, within a tolerance of 1e-9 on floats."""

from __future__ import annotations

import functools
import importlib.util
from typing import TYPE_CHECKING

import numpy as np
import pytest

from tap_bench.rl.training import _make_training_env
from tap_bench.sim.scenario_env import get_scenario

if TYPE_CHECKING:
    from stable_baselines3.common.vec_env import VecEnv

# Stable-Baselines3 (and torch) are imported by the tests that run, not when the suite is
# collected: a pytest worker that runs none of this file's tests does not pay for them.
pytestmark = pytest.mark.skipif(importlib.util.find_spec("stable_baselines3") is None,
                                reason="needs stable-baselines3 (the sb3 extra)")


def _shared():
    """``tap_bench.rl.vec_env`` (it imports Stable-Baselines3), imported on first use."""
    from tap_bench.rl import vec_env

    return vec_env


def _envs(n_envs: int, one_here: bool, scenario: str = "highway") -> VecEnv:
    make = functools.partial(_make_training_env, get_scenario(scenario), True)
    worker = functools.partial(_make_training_env, get_scenario(scenario), True, worker=True)
    return _shared().training_vec_env(make, worker, n_envs, one_here=one_here)


def _reset_info(info: dict) -> dict:
    """A reset's info without what highway-env derives from the action it draws there from
    the unseeded action space: the action and its lane-change reward."""
    out = {k: v for k, v in info.items() if k != "action"}
    if isinstance(out.get("rewards"), dict):
        out["rewards"] = {k: v for k, v in out["rewards"].items()
                          if k != "lane_change_reward"}
    return out


def _run(vec: VecEnv, steps: int, seed: int,
         options: dict | None = None) -> list:
    """Everything the learner sees of ``steps`` steps with drawn actions, then of the other
    VecEnv calls (a reset with ``options``: default one vehicle fewer on highway)."""
    rng = np.random.default_rng(seed)
    vec.seed(seed)
    seen = [vec.reset(), [_reset_info(info) for info in vec.reset_infos]]
    for _ in range(steps):
        obs, rewards, dones, infos = vec.step(rng.integers(0, vec.action_space.n, vec.num_envs))
        infos = list(infos)  # the VecEnv contract's list (SubprocVecEnv gives a tuple)
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


def _same(a, b, *, types: bool = True, atol: float = 1e-9) -> bool:
    """``a`` and ``b`` hold the same values: the same structure and keys, floats within
    ``atol``, and (``types``) the same types and dtypes."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a_arr, b_arr = np.asarray(a), np.asarray(b)
        if types and (type(a) is not type(b) or a_arr.dtype != b_arr.dtype):
            return False
        if a_arr.shape != b_arr.shape:
            return False
        if a_arr.dtype.kind in "fc" or b_arr.dtype.kind in "fc":
            return bool(np.allclose(a_arr, b_arr, rtol=0, atol=atol, equal_nan=True))
        return bool(np.array_equal(a_arr, b_arr))
    if isinstance(a, dict):
        return (isinstance(b, dict) and list(a) == list(b)
                and all(_same(a[k], b[k], types=types, atol=atol) for k in a))
    if isinstance(a, (list, tuple)):
        return ((type(a) is type(b) or (not types and isinstance(b, (list, tuple))))
                and len(a) == len(b)
                and all(_same(x, y, types=types, atol=atol) for x, y in zip(a, b, strict=True)))
    if isinstance(a, float) or isinstance(b, float):
        numbers = (float, int, np.floating)
        return (isinstance(a, numbers) and isinstance(b, numbers)
                and (not types or type(a) is type(b))
                and (abs(a - b) <= atol or (a != a and b != b)))
    return (not types or type(a) is type(b)) and (a == b or (a != a and b != b))


@pytest.mark.parametrize("n_envs", [2, 3])
def test_every_call_is_answered_as_by_worker_processes(n_envs, write_scenario):
    """Observations, rewards, dones, infos (terminal observations, Monitor's episodes),
    reset infos (after the resets and after every step), attributes and method calls, over
    70 steps with episode ends, by crashes and by the time limit (8 decisions): the same as
    SB3's SubprocVecEnv's."""
    short = str(write_scenario("short", duration=8))
    results = []
    for one_here in (False, True):
        vec = _envs(n_envs, one_here, short)
        try:
            assert isinstance(vec, _shared().SharedVecEnv) == one_here
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


def test_the_envs_step_as_in_sb3s_dummy_vec_env(write_scenario):
    """The same values as SB3's DummyVecEnv (all envs in this process) for the same seeds:
    DummyVecEnv's rewards are float32 (rounded: within 1e-6) and its observations copies in
    its own buffers, so values are compared, not types."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    short = str(write_scenario("short", duration=8))
    make = functools.partial(_make_training_env, get_scenario(short), True)
    results = []
    for vec in (DummyVecEnv([make] * 2), _envs(2, True, short)):
        try:
            results.append(_run(vec, 40, seed=5)[:42])  # the steps and resets
        finally:
            vec.close()
    assert _same(*results, types=False, atol=1e-6)


def test_env_0_answers_with_copies_and_closes_with_the_others():
    """env 0 gets and gives copies, as a worker through its pipe: the learner's arrays and
    objects are never the env's."""
    vec = _envs(2, True)
    vec.reset()
    actions = np.array([1, 1])
    vec.step_async(actions)
    actions[:] = 4  # the learner reuses its array: each env got its own copy
    *_, infos = vec.step_wait()
    assert [info["action"] for info in infos] == [1, 1]
    note = {"sent": 1}
    vec.set_attr("tap_note", note, indices=[0])
    note["sent"] = 2  # the sender keeps its object; the env got a copy
    assert vec.local.env.get_wrapper_attr("tap_note") == {"sent": 1}
    config = vec.get_attr("config", indices=[0])[0]  # and the answer is a copy too
    assert config == vec.local.env.get_wrapper_attr("config")
    assert config is not vec.local.env.get_wrapper_attr("config")
    closed = []
    vec.local.env.close = lambda: closed.append(True)
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
    original = _shared().SharedVecEnv.__init__

    def init(self, local_fn, worker_fns, start_method):
        try:
            original(self, local_fn, worker_fns, start_method)
        finally:
            started.extend(self.processes)

    monkeypatch.setattr(_shared().SharedVecEnv, "__init__", init)
    worker = functools.partial(_make_training_env, get_scenario("highway"), True, worker=True)
    with pytest.raises(ValueError, match="env 0 cannot be built"):
        _shared().training_vec_env(broken, worker, 2, one_here=True)
    for process in started:
        process.join(5)
    assert len(started) == 1 and not started[0].is_alive()


def _unbuildable() -> None:
    raise RuntimeError("no such map")


def test_a_worker_whose_env_cannot_be_built_raises_its_error_here():
    """The worker's error, with its traceback as a note, at construction (not an EOFError
    at the first step); the other workers end."""
    make = functools.partial(_make_training_env, get_scenario("highway"), True)
    worker = functools.partial(_make_training_env, get_scenario("highway"), True, worker=True)
    with pytest.raises(RuntimeError, match="no such map") as caught:
        _shared().SharedVecEnv(make, [worker, _unbuildable], start_method="forkserver")
    assert any("worker 2" in note for note in getattr(caught.value, "__notes__", []))


def test_a_workers_error_is_raised_here_and_the_envs_answer_on():
    """A request a worker's env fails (an attribute it lacks) raises that error here, after
    every reply is read: the next requests are answered in step."""
    vec = _envs(3, True)
    try:
        vec.reset()
        vec.set_attr("tap_note", "set", indices=[0, 1])
        with pytest.raises(AttributeError, match="tap_note") as caught:
            vec.get_attr("tap_note")
        notes = getattr(caught.value, "__notes__", None)
        assert notes is None or any("worker 2" in note for note in notes)
        assert vec.get_attr("tap_note", indices=[0, 1]) == ["set", "set"]
        obs, rewards, dones, infos = vec.step(np.array([1, 1, 1]))
        assert obs.shape[0] == rewards.shape[0] == dones.shape[0] == len(infos) == 3
    finally:
        vec.close()
    assert not any(p.is_alive() for p in vec.processes)


def test_env_0_failing_to_close_still_closes_the_workers():
    """An env 0 whose ``close`` raises (as one left broken by an error mid-step may): the
    error reaches the caller, and the workers are closed and ended all the same."""
    vec = _envs(3, True)
    vec.reset()

    def broken() -> None:
        raise RuntimeError("env 0 cannot close")

    vec.local.env.close = broken
    with pytest.raises(RuntimeError, match="env 0 cannot close"):
        vec.close()
    for process in vec.processes:
        process.join(10)
    assert not any(process.is_alive() for process in vec.processes)
    assert all(connection.closed for connection in vec.connections) and vec.closed


def test_a_step_every_env_fails_raises_the_envs_error_and_close_still_closes():
    """An action no env knows: env 0's error reaches the learner; close reads the workers'
    replies (their envs' errors), closes env 0 and raises nothing, so that the env's error
    stays the one the caller sees."""
    vec = _envs(3, True)
    vec.reset()
    closed = []
    close = vec.local.env.close
    vec.local.env.close = lambda: (closed.append(True), close())
    vec.step_async(np.array([99, 99, 99]))
    with pytest.raises(KeyError):
        vec.step_wait()
    vec.close()
    assert closed == [True] and vec.closed
    for process in vec.processes:
        process.join(10)
    assert not any(process.is_alive() for process in vec.processes)


# Fast: intersection (its own observation features, 3 longitudinal actions, its own episode
# ends) and exit (its ExitObservation), beside highway in
# test_every_call_is_answered_as_by_worker_processes. Slow: merge, roundabout and cut_in,
# each starting worker processes twice (~3-5 s wall each), Kinematics observations and
# meta-actions as highway's.
_SLOW = pytest.mark.slow


@pytest.mark.parametrize(("scenario", "seed"), [
    pytest.param("merge", 11, marks=_SLOW), pytest.param("roundabout", 12, marks=_SLOW),
    ("intersection", 13), ("exit", 14),
    pytest.param("cut_in", 15, marks=_SLOW)])
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


def test_the_module_restates_no_sb3_worker_loop():
    """tap-bench's own VecEnv: no request loop of SB3's (``remote.recv()`` / ``send`` per
    command) nor a digest of SB3's source in the module."""
    import inspect

    from tap_bench.rl import vec_env

    source = inspect.getsource(vec_env)
    assert "subproc_vec_env._worker" not in source and "sources_match" not in source
    assert "_WORKER_CODE" not in source
