"""Stable-Baselines3 agents as policies.

Stable-Baselines3 (and torch) are imported only when a model is loaded: install them with
the ``sb3`` extra. A model file is a zip holding Python pickles: loading it can run code
from the file, so every load warns (:class:`UntrustedModelWarning`) and only files you trust
should be loaded. The models in ``policies/`` are built by ``tap-bench train``; their
SHA-256 digests are known here (:data:`SHIPPED_MODELS`), and loading a file with one of
those digests, byte for byte the one shipped, does not warn.
"""

from __future__ import annotations

import hashlib
import io
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tap_bench.errors import (
    FileFormatError,
    TapBenchError,
    UntrustedModelWarning,
    did_you_mean,
)

if TYPE_CHECKING:
    import gymnasium as gym

__all__ = ["ALGORITHMS", "SHIPPED_MODELS", "SB3Policy", "UntrustedModelWarning", "load_model",
           "shipped_model", "warn_untrusted_model"]

ALGORITHMS = ("a2c", "dqn", "ppo")
"""Stable-Baselines3 algorithms tap-bench can train and load."""

SHIPPED_MODELS: dict[str, str] = {
    "437567ecd5d39eb776d2a5ec30d982a36188980b9ae5f9ac0453c74951c917a6": "dqn-highway.zip",
    "733a5445172dcf7fcf457193bad5779c8e19afc9128173dda6d6df2610dea7fd": "ppo-highway.zip",
    "af4708a821d67b682d22caf6382089f02c43ee1b928363eef72d2fac8fc0f4c6": "ppo-womd-seed0.zip",
    "1802eca4b4f2fb173c1094eee21b6995c89a28588febcc02d46e01ea6caecad8": "ppo-womd-seed1.zip",
    "1c3dc89098a257f2e5d7a6bb68150e2377f864ca0fbd64f78dee2575408727c3": "ppo-womd-seed2.zip",
    "56273c16893b0544e24540c29de7e7c681aae25dab4f97db1ed4aa9a15329792": "ppo-womd-split-seed0.zip",
    "bc015e39831778bd15ce7cf89a91fed51717b2c972067355e679db70055b35d5": "ppo-womd-split-seed1.zip",
    "012a3275f1fec0c792f31b018f01b2095fac3d07649e907ad39dd182e75a14b6": "ppo-womd-split-seed2.zip",
    "f03bd390802de26cb7a081df232d81f88dd4dc7f701292b5ac9eb07748ca3ac2": "ppo-womd-split-seed3.zip",
    "11b55d007efa088943a77b0a2d88b96c89cdf269720f39d2f98c5d8b468108b9": "ppo-womd-split-seed4.zip",
    "8cd46404dcd0a156b09028dc901e2a9b8e72f2dbe13f156491c9d5aea47b7941": "ppo-womd-foldb-seed0.zip",
    "e00df63f56723516f4057f5e94b8f5e3813c96d94cd891f4b06421e041938366": "ppo-womd-foldb-seed1.zip",
    "8d14ab45db0a85ed2ad7e5c5b211c2ba480136c4782d97c7d4ddcd1834046606": "ppo-womd-foldb-seed2.zip",
    "e8cff1eeb05ae124f39653cac7c1f598173e5750fc33749a4217c2befe99e4a3": "ppo-womd-foldb-seed3.zip",
    "096318283b363966f2ca0241f11b9c4a26f1ee04eafe92547f2d99db6f070714": "ppo-womd-foldb-seed4.zip",
    "7bb2b6b4f904f97b411254919a54de21527eb25cdf4ce67ef5404e7e571ede54": "ppo-womd-tenth-seed0.zip",
    "aec964c6db786e2b8cca5dc4a3f58f0106096acc90fa6a344de47cece8a4679e": "ppo-womd-tenth-seed1.zip",
    "e0e659f88809f98a63affd63e90a5e7dea27f5b347ddd2074ea22916b9f8ba0e": "ppo-womd-tenth-seed2.zip",
    "2826a2a65be1b140bad23b6f9e421a511e588d2ca6e6188755d7f7489a3f438b":
        "ppo-womd-tenth-foldb-seed0.zip",
    "df685625146ae89fa677897fedb102793b1f7c16a4dd0036edac8c85a578c3a1":
        "ppo-womd-tenth-foldb-seed1.zip",
    "3ab11752afa38da2de43986874f3aec540f49acd5817209aa71bdfabbe2ec2bc":
        "ppo-womd-tenth-foldb-seed2.zip",
    "7e0adcfb8c11ba252e2e8edd55d359e0cdc11ce7e79ff269f8073c2eddd1deec":
        "ppo-womd-reactive-seed0.zip",
    "ecc34c66e31722ace0286596c280f81001709d5fc059214e95aa14e89b95b1ce":
        "ppo-womd-reactive-seed1.zip",
    "36a33e52864e437bdb66fd3af8d034e66c47b7b8a8ee9da5e5fcd88abd3f1348":
        "ppo-womd-reactive-seed2.zip",
    "4baf643bd6fd5b4ab659fa4825825912dfcdc781cb4f9da18db0580ddeb876aa":
        "ppo-womd-reactive-foldb-seed0.zip",
    "8d2b4f27a02bab8f433e0db06482fdf21cdcfdc176ce2d86d0e4ca14a6dec4b9":
        "ppo-womd-reactive-foldb-seed1.zip",
    "cffaf149996b2d5bc117b2469e4915ef6179ad738f25d2a7e223e7f089159096":
        "ppo-womd-reactive-foldb-seed2.zip",
    "ba2a31a5d6cfb72049707a834447c0dfe6c6e0bba86e4dd43aa19b69c79cd56c":
        "ppo-womd-horizon-seed0.zip",
    "804c703967ef59af803071989da83d272d2d739ffedf56775867a0be60d96c9d":
        "ppo-womd-horizon-seed1.zip",
    "dc93e2604e305c756966ebbfd1e027a1960ec3cafc92cc038f66e1072c5ecadb":
        "ppo-womd-horizon-seed2.zip",
    "3909071bfed99808e4be4cbc41a8ce55ad31cec5b9251c5eb108645a4b93e810":
        "ppo-womd-horizon-foldb-seed0.zip",
    "6625c60b41641b4b0307d4f05259a0742ac39a4435cfc5b2be6c866ccaef98ea":
        "ppo-womd-horizon-foldb-seed1.zip",
    "d4e56bfa5f22190657f4cd7982ea2dcf799cee2818cbdd293dfc6e3a28ad7800":
        "ppo-womd-horizon-foldb-seed2.zip",
    "26a135d030faf8cf997865b279b5a2f410be06a5132e550afda85368dbff6315":
        "ppo-womd-grid-seed0.zip",
    "62c3e6e49731a12f2e75a66276f89225d1715afddad843391b7d0fcdd6e1c0b7":
        "ppo-womd-grid-seed1.zip",
    "8e63ffda3cf8082b2cac24f26963793e4165d0695928e5a03a70d2cf1c04672f":
        "ppo-womd-grid-seed2.zip",
    "91af16d6e05f93de666f72ab6a826fce2e145e2e14425b3a87ac7b3e63b937c0":
        "ppo-womd-grid-foldb-seed0.zip",
    "97cbbf99ba1db619d6c60020a79b25d17183a4ee7bf309d3eb355a4d0fc1f01c":
        "ppo-womd-grid-foldb-seed1.zip",
    "5b67eaa7c4c398b85939410b2a9d4236b330e4e1e2d62ab865f1aba4e2054d56":
        "ppo-womd-grid-foldb-seed2.zip",
}
"""SHA-256 digest of each model file shipped in ``policies/`` -> its name. Known in the
installed code, not beside the file: a digest that a model folder could carry would vouch
for nothing. A model retrained (``tap-bench train -o policies/...``) gets a new digest, to
be put here when it ships."""


def shipped_model(data: bytes) -> str | None:
    """The name of the shipped model whose bytes ``data`` are, or None."""
    return SHIPPED_MODELS.get(hashlib.sha256(data).hexdigest())


def algorithm_class(algo: str) -> type:
    """The Stable-Baselines3 class of ``algo`` (``"dqn"``, ``"ppo"``, ``"a2c"``)."""
    algo = algo.lower()
    if algo not in ALGORITHMS:
        raise did_you_mean("algorithm", algo, ALGORITHMS)
    try:
        import stable_baselines3
    except ImportError as err:
        raise TapBenchError(
            "Stable-Baselines3 is not installed: pip install torch==2.13.0 (a CPU build), "
            "then pip install 'tap-bench[sb3]'.") from err
    return getattr(stable_baselines3, algo.upper())


def _algo_of(path: Path) -> str:
    """Read the algorithm from the policy class recorded in an SB3 zip (no unpickling)."""
    import json
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as err:
        raise FileFormatError(f"{path}: not a Stable-Baselines3 model file ({err}).") from err
    module = str(data.get("policy_class", {}).get("__module__", ""))
    for algo in ALGORITHMS:
        if f".{algo}." in module or module.endswith(f".{algo}"):
            return algo
    # PPO and A2C share ActorCriticPolicy: tell them by their own hyper-parameters.
    if "clip_range" in data:
        return "ppo"
    if "target_update_interval" in data:
        return "dqn"
    if "ent_coef" in data:
        return "a2c"
    raise FileFormatError(f"{path}: cannot tell the algorithm from {module!r}; give \"algo\" "
                          f"({', '.join(ALGORITHMS)}) in the policy definition.")


def load_model(path: str | os.PathLike, algo: str | None = None) -> Any:
    """Load a Stable-Baselines3 model on the CPU, warning that the file must be trusted.

    Args:
        path: the ``.zip`` file.
        algo: ``"dqn"``, ``"ppo"``, ``"a2c"``; read from the file when None.
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: no such model file.")
    algo = algo or _algo_of(path)
    cls = algorithm_class(algo)
    data = path.read_bytes()  # what is checked is what is loaded
    if shipped_model(data) is None:
        warn_untrusted_model(path, stacklevel=3, known=False)
    return _load_without_initialising(cls, data)


def _load_without_initialising(cls: type, data: bytes) -> Any:
    """``cls.load`` of the model file ``data`` on the CPU, without the orthogonal
    initialisation of an actor-critic network (PPO, A2C) whose weights the file's then
    replace: a QR decomposition per layer, about 0.1-0.3 CPU s a model, most of a load.

    The network is built with ``ortho_init`` off, the file's parameters are loaded into it
    (Stable-Baselines3 requires every one), and ``ortho_init`` is put back as the file has
    it, in the model's ``policy_kwargs`` and its policy: the model equals a plain load,
    parameter for parameter (tests/rl/test_sb3_loading.py). Only torch's global random
    stream differs (not drawn from for the skipped initialisation); :class:`SB3Policy`
    seeds it at each reset."""
    import zipfile

    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.save_util import json_to_data

    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            saved = json_to_data(archive.read("data").decode())
    except (KeyError, ValueError, zipfile.BadZipFile):  # Stable-Baselines3 says what is wrong
        return cls.load(io.BytesIO(data), device="cpu")
    kwargs = dict(saved.get("policy_kwargs") or {})
    policy = saved.get("policy_class")
    if not (isinstance(policy, type) and issubclass(policy, ActorCriticPolicy)
            and kwargs.get("ortho_init", True)):
        return cls.load(io.BytesIO(data), device="cpu")
    model = cls.load(io.BytesIO(data), device="cpu",
                     custom_objects={"policy_kwargs": {**kwargs, "ortho_init": False}})
    if "ortho_init" in kwargs:
        model.policy_kwargs["ortho_init"] = kwargs["ortho_init"]
    else:
        model.policy_kwargs.pop("ortho_init", None)
    model.policy.ortho_init = True
    return model


def warn_untrusted_model(path: str | os.PathLike, *, stacklevel: int = 2,
                         known: bool | None = None) -> None:
    """Warn (:class:`UntrustedModelWarning`) that loading the model ``path`` can run code
    from it, unless its bytes are a shipped model's (:data:`SHIPPED_MODELS`; ``known``:
    whether they are, when the caller has checked already). ``bench run`` calls it in the
    parent once per model, before the run: its workers load models with warnings off."""
    if known is None:
        try:
            known = shipped_model(Path(path).read_bytes()) is not None
        except OSError:
            known = False
    if known:
        return
    warnings.warn(
        f"{path}: Stable-Baselines3 model files contain Python pickles, and loading one can "
        "run code from it. Load only model files you trust.", UntrustedModelWarning,
        stacklevel=stacklevel + 1)


class SB3Policy:
    """A Stable-Baselines3 model acting on the env's observation.

    The model is loaded at the first :meth:`reset`, so the object is cheap to build and to
    send to rollout workers.

    Args:
        name: the policy's name.
        model: the ``.zip`` file (relative paths are relative to ``base_dir``).
        algo: ``"dqn"``, ``"ppo"``, ``"a2c"``; read from the file when None.
        observation: the highway-env observation config the model was trained on; rollouts
            build the env with it. None keeps the scenario's own.
        action: the action config it was trained with when that is not the env's default
            (a safety layer: :mod:`tap_bench.sim.womd_safety`); rollouts build the env with
            it. None keeps the scenario's own.
        env: the scenario the model was trained on (information only).
        deterministic: act greedily (True) or sample from the policy.
        base_dir: folder of the definition file.
        timesteps, seed, hyperparameters, train_seconds, command, n_envs, fast,
            interrupted_of, kept, kept_timesteps, kept_eval_return, kept_eval_crash_rate:
            what ``tap-bench train`` recorded (``n_envs`` parallel training envs, on the
            fast variant or not; ``interrupted_of``: the timesteps asked for when Ctrl-C
            stopped the training earlier; ``kept``: ``"last"`` or ``"best"``, the weights
            saved, with the steps, return and crash rate of the evaluation they come from;
            ``curve``: the learning curve's settings, None without one; ``womd`` and
            ``traffic``: the recorded scenes it trained on, if any, and ``egos`` whom
            it drove there (``"sdc"``: each scene's ego, ``"all"``: every driver in turn);
            ``train_scenes``, ``held_out_scenes``, ``held_out_refs``: the indexes of the
            scenes trained on and held out, and where the held-out ones are:
            :mod:`tap_bench.rl.heldout`; ``cpu_seconds``: the CPU time of the training,
            user + system, its env workers included; ``reward``: the reward settings it
            trained with on recorded scenes, the ``*_reward`` config keys of
            ``tap_bench/womd-v0``); kept in :attr:`training`.
    """

    def __init__(self, name: str, model: str, algo: str | None = None,
                 observation: Mapping[str, Any] | None = None, env: str | None = None,
                 deterministic: bool = True, base_dir: str | os.PathLike | None = None, *,
                 timesteps: int | None = None, seed: int | None = None,
                 hyperparameters: Mapping[str, Any] | None = None,
                 train_seconds: float | None = None, command: str | None = None,
                 n_envs: int | None = None, fast: bool | None = None,
                 interrupted_of: int | None = None, kept: str | None = None,
                 kept_timesteps: int | None = None, kept_eval_return: float | None = None,
                 kept_eval_crash_rate: float | None = None,
                 curve: Mapping[str, Any] | None = None,
                 womd: Sequence[str] | None = None, traffic: str | None = None,
                 egos: str | None = None,
                 train_scenes: Sequence[int] | None = None,
                 held_out_scenes: Sequence[int] | None = None,
                 held_out_refs: Sequence[str] | None = None,
                 cpu_seconds: float | None = None,
                 reward: Mapping[str, float] | None = None,
                 action: Mapping[str, Any] | None = None) -> None:
        path = Path(model)
        if not path.is_absolute() and base_dir is not None:
            path = Path(base_dir) / path
        if not path.is_file():
            raise FileFormatError(f"policy {name!r}: model file {path} does not exist; train "
                                  "it with `tap-bench train` or fix \"model\".")
        if algo is not None and algo.lower() not in ALGORITHMS:
            raise did_you_mean("algorithm", algo, ALGORITHMS)
        self.name = name
        self.path = path
        self.algo = algo.lower() if algo else None
        self.observation = dict(observation) if observation is not None else None
        self.action = dict(action) if action is not None else None
        self.env = env
        self.deterministic = deterministic
        self.training = {"timesteps": timesteps, "seed": seed,
                         "hyperparameters": hyperparameters, "train_seconds": train_seconds,
                         "command": command, "n_envs": n_envs, "fast": fast,
                         "interrupted_of": interrupted_of, "kept": kept,
                         "kept_timesteps": kept_timesteps,
                         "kept_eval_return": kept_eval_return,
                         "kept_eval_crash_rate": kept_eval_crash_rate,
                         "curve": dict(curve) if curve is not None else None,
                         "womd": list(womd) if womd is not None else None,
                         "traffic": traffic, "egos": egos,
                         "reward": dict(reward) if reward is not None else None,
                         "train_scenes": None if train_scenes is None else list(train_scenes),
                         "held_out_scenes": (None if held_out_scenes is None
                                             else list(held_out_scenes)),
                         "held_out_refs": None if held_out_refs is None else list(held_out_refs),
                         "cpu_seconds": cpu_seconds}
        self._model: Any = None

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state["_model"] = None  # workers load their own copy
        return state

    def reset(self, env: gym.Env, *, seed: int) -> None:
        if self._model is None:
            self._model = load_model(self.path, self.algo)
        expected = self._model.observation_space
        if not _same_space(expected, env.observation_space):
            raise TapBenchError(
                f"policy {self.name!r}: the env's observation space {env.observation_space} "
                f"differs from the one the model was trained on ({expected}). Build the env "
                "with the policy's observation config (rollouts do this when the model's "
                "definition .json, written by 'tap-bench train', lies beside it or is given "
                "instead of the .zip), or retrain.")
        if self._model.action_space != env.action_space:
            raise TapBenchError(
                f"policy {self.name!r}: the env's action space {env.action_space} differs from "
                f"the model's ({self._model.action_space}); the model was trained on "
                f"{self.env or 'another scenario'}.")
        self._model.set_random_seed(int(seed))

    def act(self, observation: Any) -> Any:
        import numpy as np

        if self._model is None:
            raise RuntimeError(f"policy {self.name!r}: act before reset.")
        action, _ = self._model.predict(observation, deterministic=self.deterministic)
        if isinstance(action, np.ndarray) and action.shape == ():
            return int(action)
        return action


def _same_space(a: gym.Space, b: gym.Space) -> bool:
    import gymnasium as gym

    if type(a) is not type(b):
        return False
    if isinstance(a, gym.spaces.Box):
        return a.shape == b.shape
    return a == b
