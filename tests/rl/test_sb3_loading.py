"""A model loaded by tap-bench (:func:`tap_bench.sim.sb3.load_model`, which skips the
orthogonal initialisation of an actor-critic network the file's weights then replace) is
the model Stable-Baselines3's own ``load`` gives: every parameter and optimiser value, the
policy's settings, and its actions, greedy and sampled."""

from __future__ import annotations

import importlib.util
import io
import warnings
from pathlib import Path

import numpy as np
import pytest

from tap_bench.sim.sb3 import _algo_of, algorithm_class, load_model

# Stable-Baselines3 and torch are imported by the tests that run, not when the suite is
# collected: every pytest worker collects every file, and torch's import costs about 2 CPU s
pytestmark = pytest.mark.skipif(importlib.util.find_spec("stable_baselines3") is None,
                                reason="needs stable-baselines3 (the sb3 extra)")

POLICIES = Path(__file__).resolve().parents[2] / "policies"


def _made(tmp_path: Path, algo: str, **policy_kwargs) -> Path:
    """A model of ``algo`` built and saved here (an untrained network on CartPole)."""
    import gymnasium as gym

    model = algorithm_class(algo)("MlpPolicy", gym.make("CartPole-v1"), seed=4, device="cpu",
                                  policy_kwargs=policy_kwargs or None)
    path = tmp_path / f"{algo}.zip"
    model.save(path)
    return path


def _assert_same_model(ours, theirs) -> None:
    import torch

    assert type(ours) is type(theirs) and type(ours.policy) is type(theirs.policy)
    assert ours.policy_kwargs == theirs.policy_kwargs
    assert getattr(ours.policy, "ortho_init", None) == getattr(theirs.policy, "ortho_init", None)
    for module, a, b in (("policy", ours.policy, theirs.policy),
                         ("optimizer", ours.policy.optimizer, theirs.policy.optimizer)):
        flat_a, flat_b = _flat(a.state_dict()), _flat(b.state_dict())
        assert flat_a.keys() == flat_b.keys(), module
        for key, value in flat_a.items():
            other = flat_b[key]
            if isinstance(value, torch.Tensor):
                assert torch.equal(value, other), (module, key)
            else:
                assert value == other, (module, key)
    space = ours.observation_space
    space.seed(11)
    observations = np.stack([space.sample() for _ in range(32)])
    for deterministic in (True, False):
        actions = []
        for model in (ours, theirs):  # the random streams are global: seeded before each
            model.set_random_seed(5)
            actions.append(model.predict(observations, deterministic=deterministic)[0])
        np.testing.assert_array_equal(*actions)


def _flat(state, prefix: str = "") -> dict:
    """A (nested) state dict as {path: value}."""
    if isinstance(state, dict):
        out = {}
        for key, value in state.items():
            out.update(_flat(value, f"{prefix}{key}/"))
        return out
    if isinstance(state, list | tuple):
        out = {}
        for i, value in enumerate(state):
            out.update(_flat(value, f"{prefix}{i}/"))
        return out
    return {prefix: state}


@pytest.mark.parametrize("case", ["ppo-highway", "ppo-womd-seed0", "dqn-highway",
                                  "a2c made here", "ppo made without ortho_init"])
def test_a_model_loaded_is_the_model_stable_baselines3_loads(case, tmp_path):
    if case == "a2c made here":
        path = _made(tmp_path, "a2c")
    elif case == "ppo made without ortho_init":
        path = _made(tmp_path, "ppo", ortho_init=False)
    else:
        path = POLICIES / f"{case}.zip"
    cls = algorithm_class(_algo_of(path))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ours = load_model(path)
    theirs = cls.load(io.BytesIO(path.read_bytes()), device="cpu")
    _assert_same_model(ours, theirs)
