"""Driving policies: one protocol, a registry, and the simple built-ins.

A policy drives the ego vehicle of a scenario env. Its definition is data: a JSON file in
``policies/`` (``{"name": "idm", "kind": "idm", "description": "...", "params": {...}}``)
whose ``kind`` names the code that builds it:

================  ===========================================================================
kind              policy
================  ===========================================================================
``idm``           IDM/MOBIL drives the ego (:mod:`tap_bench.sim.idm`)
``random``        uniform random actions from a seeded copy of the action space
``lane_keeping``  always the "keep lane, keep speed" action (``IDLE``)
``log``           the human: replays the recorded ego of a real scene (``tap_bench/womd-v0``
                  only), so its trajectory and labels are the log's
``sb3``           a Stable-Baselines3 model from a ``.zip`` (:mod:`tap_bench.sim.sb3`)
``import``        your own class, ``params: {"factory": "module:Class", ...}``: built as
                  ``Class(name, **other_params)``; the module must be importable (on
                  ``PYTHONPATH``), so it also works in worker processes and on Ray
================  ===========================================================================

Policies defined in Python in this process only are added with :func:`register_policy`
(they run with ``workers=1``; use an ``import`` definition file for parallel runs).

Definition files are code: a file of kind ``import`` runs the module it names, and an
``sb3`` model file holds pickles. Before anything is called, the factory is checked to be a
class implementing :class:`Policy` (:mod:`tap_bench.usercode`); use only definition files
and models you trust.
"""

from __future__ import annotations

import copy
import importlib
import inspect
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from tap_bench import catalogue
from tap_bench.errors import (
    FileFormatError,
    ParameterError,
    RegistrationError,
    TapBenchError,
    UnknownNameError,
    did_you_mean,
)
from tap_bench.registry import Registry
from tap_bench.sim.scenario_format import read_json

if TYPE_CHECKING:
    import gymnasium as gym

__all__ = [
    "CHEAP_OBSERVATION",
    "POLICY_KINDS",
    "LaneKeepingPolicy",
    "LogPolicy",
    "Policy",
    "PolicyDefinition",
    "PolicyKind",
    "RandomPolicy",
    "SeedGroupError",
    "available_policies",
    "expand_seed_groups",
    "load_policy",
    "policy_kinds",
    "register_policy",
    "register_policy_kind",
    "seed_group",
    "seed_groups",
]

CHEAP_OBSERVATION: dict[str, Any] = {"type": "AttributesObservation", "attributes": ["time"]}
"""The observation rollouts give a policy that reads none: highway-env's clock instead of
the Kinematics table, which costs about 11 ms a decision."""


@runtime_checkable
class Policy(Protocol):
    """What drives the ego vehicle of a scenario env.

    Attributes:
        name: the policy's name in tables (``policy`` column).
        observation: the highway-env observation config the policy reads, or None when it
            reads none (rollouts then use :data:`CHEAP_OBSERVATION`).
    """

    name: str
    observation: Mapping[str, Any] | None

    def reset(self, env: gym.Env, *, seed: int) -> None:
        """Start an episode: ``env`` has just been reset with ``seed``; seed the policy's own
        randomness with it. A policy that drives through the simulator takes over here."""
        ...

    def act(self, observation: Any) -> Any:
        """The action for ``observation``, in the env's action space."""
        ...


@dataclass(frozen=True)
class PolicyDefinition:
    """A policy as data: a file in ``policies/`` or a Python registration.

    Attributes:
        name: registry name (``idm-aggressive``).
        kind: what builds it (``idm``, ``random``, ``lane_keeping``, ``sb3``, or ``python``).
        description: one line for ``tap-bench policies``.
        params: keyword arguments of the builder.
        path: the definition file, when there is one; relative paths in ``params`` are
            relative to its folder.
    """

    name: str
    kind: str
    description: str = ""
    params: Mapping[str, Any] = field(default_factory=dict)
    path: Path | None = field(default=None, compare=False)

    def build(self) -> Policy:
        """A fresh policy object."""
        if self.kind == "python":
            if self.name not in _PYTHON_POLICIES:
                raise UnknownNameError(
                    f"policy {self.name!r} was registered with register_policy in another "
                    "process; Python registrations exist only in the process that made them. "
                    "Run with workers=1, or define it in a file of kind 'import' "
                    "({\"kind\": \"import\", \"params\": {\"factory\": \"module:Class\"}}).")
            return _PYTHON_POLICIES[self.name]()
        builder = _builder(self.kind)
        params = dict(self.params)
        if self.path is not None and "base_dir" in inspect.signature(builder).parameters:
            params["base_dir"] = self.path.parent
        try:
            return builder(self.name, **params)
        except (TypeError, ValueError, UnknownNameError) as err:
            where = self.path or self.name
            raise FileFormatError(f"{where}: params do not fit policy kind {self.kind!r}: {err}"
                                  ) from err


class RandomPolicy:
    """Uniformly random actions, from a copy of the env's action space seeded per episode."""

    observation = None

    def __init__(self, name: str = "random") -> None:
        self.name = name
        self._space: gym.Space | None = None

    def reset(self, env: gym.Env, *, seed: int) -> None:
        self._space = copy.deepcopy(env.action_space)
        self._space.seed(int(seed))

    def act(self, observation: Any) -> Any:
        if self._space is None:
            raise RuntimeError("RandomPolicy.act before reset: call reset(env, seed=...) first.")
        return self._space.sample()


def idle_action(env: gym.Env) -> Any:
    """The action that keeps the lane and the speed: ``IDLE`` of a meta-action space, zero
    acceleration and steering of a continuous one."""
    import gymnasium as gym
    import numpy as np

    action_type = env.unwrapped.action_type
    indexes = getattr(action_type, "actions_indexes", None)
    if indexes is not None and "IDLE" in indexes:
        return int(indexes["IDLE"])
    space = env.action_space
    if isinstance(space, gym.spaces.Box):
        return np.zeros(space.shape, dtype=space.dtype)
    raise ParameterError("action space", str(space), "",
        message=f"no lane-keeping action in the action space {space}; use a "
                "DiscreteMetaAction or ContinuousAction env.")


class LaneKeepingPolicy:
    """Constant lane keeping: always keep the lane and the current target speed."""

    observation = None

    def __init__(self, name: str = "lane-keeping") -> None:
        self.name = name
        self._action: Any = None

    def reset(self, env: gym.Env, *, seed: int) -> None:
        self._action = idle_action(env)

    def act(self, observation: Any) -> Any:
        if self._action is None:
            raise RuntimeError("LaneKeepingPolicy.act before reset: call reset(env, seed=...).")
        return self._action


class LogPolicy:
    """The human who drove a recorded scene: the ego replays its log (SPEC section 8), the
    reference of every comparison on real scenes. Only recorded scenes have a log."""

    observation = None
    replays_log = True  # needs no route: it runs every recorded scene (SPEC section 8)

    def __init__(self, name: str = "log") -> None:
        self.name = name
        self._action: Any = None

    def reset(self, env: gym.Env, *, seed: int) -> None:
        inner = env.unwrapped
        if not hasattr(inner, "replay_ego"):
            raise ParameterError("policy", self.name, "", message=(
                f"policy {self.name!r} replays the recorded ego of a real scene; it drives "
                "only in tap_bench/womd-v0 (tap-bench rollout --womd FILES). Choose another "
                "policy for synthetic scenarios."))
        inner.replay_ego()
        self._action = idle_action(env)

    def act(self, observation: Any) -> Any:
        if self._action is None:
            raise RuntimeError("LogPolicy.act before reset: call reset(env, seed=...).")
        return self._action


@dataclass(frozen=True)
class PolicyKind:
    """What a definition's ``kind`` names: the builder of its policies.

    Attributes:
        name: the kind (``"idm"``).
        builder: ``"module:attribute"`` of a callable ``builder(name, **params) -> Policy``
            (a name, not an object: every worker process imports it by this name).
        description: one line.
    """

    name: str
    builder: str
    description: str = ""


def _check_kind(kind: PolicyKind) -> None:
    module, sep, attribute = str(kind.builder).partition(":")
    if (not isinstance(kind.name, str) or not kind.name or not sep or not module
            or not attribute):
        raise RegistrationError(f"policy kind {kind.name!r}: builder {kind.builder!r} must be "
                                "'module:attribute' (a name every worker can import).")


POLICY_KINDS: Registry[PolicyKind] = Registry("policy kind", check=_check_kind)
"""The kinds a policy definition can name (:class:`tap_bench.registry.Registry`)."""
for _kind in (PolicyKind("idm", "tap_bench.sim.idm:IDMPolicy", "IDM/MOBIL drives the ego"),
              PolicyKind("random", "tap_bench.sim.policies:RandomPolicy",
                         "uniform random actions"),
              PolicyKind("lane_keeping", "tap_bench.sim.policies:LaneKeepingPolicy",
                         "always keep lane, keep speed"),
              PolicyKind("log", "tap_bench.sim.policies:LogPolicy",
                         "the human: replays the recorded ego of a real scene"),
              PolicyKind("sb3", "tap_bench.sim.sb3:SB3Policy", "a Stable-Baselines3 model"),
              PolicyKind("import", "tap_bench.sim.policies:import_policy",
                         "your own class or function, params.factory 'module:name'"),
              PolicyKind("seeds", "tap_bench.sim.policies:seed_group",
                         "an agent standing for its trained seeds, params.seeds (policy "
                         "names); tap-bench agents aggregates over them")):
    POLICY_KINDS.register(_kind)


def register_policy_kind(name: str, builder: str, description: str = "") -> PolicyKind:
    """Add a policy kind: definition files may then name ``"kind": name``. Register it in a
    plugin module (:mod:`tap_bench.plugins`) so that every worker knows it.

    Raises:
        RegistrationError: the name is taken, or ``builder`` is not ``"module:attribute"``.
    """
    return POLICY_KINDS.register(PolicyKind(name, builder, description))
_PYTHON_POLICIES: dict[str, Callable[[], Policy]] = {}
_PYTHON_DESCRIPTIONS: dict[str, str] = {}


def import_policy(name: str, factory: str, **params: Any) -> Policy:
    """The policy of the class ``factory`` (``"module:Class"``): ``Class(name, **params)``.

    A definition file is code: before anything is called, the module's source must define
    ``Class`` as a class (read without running it), and, imported, ``Class`` must implement
    the :class:`Policy` protocol (``reset`` and ``act`` methods); see
    :mod:`tap_bench.usercode`. So ``"os:system"`` or ``"subprocess:Popen"`` is refused, never
    run.

    Raises:
        ParameterError: ``factory`` is not ``module:Class``, cannot be imported, is not a
            class or does not implement the protocol (nothing of it was called), or the
            object it built is not a Policy.
    """
    from tap_bench.usercode import import_checked_class

    target = import_checked_class(
        str(factory), "factory", kind="a class implementing the Policy protocol (name, "
        "observation, reset(env, seed=), act(obs))", methods=("reset", "act"))
    policy = target(name, **params)
    if not isinstance(policy, Policy):
        raise ParameterError("factory", factory, "a class whose objects are Policies (name, "
                             "observation, reset(env, seed=), act(obs))")
    return policy


def policy_kinds() -> list[str]:
    """The kinds a definition file can name."""
    return sorted(POLICY_KINDS.names())


def _builder(kind: str) -> Callable[..., Policy]:
    module, _, name = POLICY_KINDS[kind].builder.partition(":")
    return getattr(importlib.import_module(module), name)


def register_policy(name: str, factory: Callable[[], Policy], description: str = "") -> None:
    """Make a Python policy available by name (to :func:`load_policy`, rollouts, the CLI).

    Args:
        name: a name not yet taken by a file in ``policies/`` or another registration.
        factory: builds a fresh policy; it must be importable by name (a module-level
            function or class) for rollouts with several workers.
        description: one line for ``tap-bench policies``.

    Raises:
        ValueError: the name is taken.
    """
    if name in _PYTHON_POLICIES or name in _file_definitions():
        raise ValueError(f"policy {name!r} is already registered; choose another name.")
    _PYTHON_POLICIES[name] = factory
    _PYTHON_DESCRIPTIONS[name] = description


def _read_definition(path: Path) -> PolicyDefinition:
    doc = read_json(path, "policy")
    allowed = ("name", "kind", "description", "params")
    for key in doc:
        if key not in allowed:
            raise FileFormatError(f"{path}: {did_you_mean('policy field', key, allowed)}")
    for key in ("name", "kind"):
        if not isinstance(doc.get(key), str):
            raise FileFormatError(f"{path}: field {key!r} (a string) is missing.")
    if doc["name"] != path.stem:
        raise FileFormatError(f"{path}: name {doc['name']!r} differs from the file name; rename "
                              f"the file to {doc['name']}.json or fix the name.")
    if doc["kind"] not in POLICY_KINDS:
        raise FileFormatError(f"{path}: "
                              f"{did_you_mean('policy kind', doc['kind'], POLICY_KINDS.names())}")
    params = doc.get("params", {})
    if not isinstance(params, dict):
        raise FileFormatError(f"{path}: params must be an object of keyword arguments.")
    return PolicyDefinition(name=doc["name"], kind=doc["kind"],
                            description=str(doc.get("description", "")), params=params,
                            path=path)


def _file_definitions(folder: str | os.PathLike | None = None) -> dict[str, Path]:
    if folder:
        return {p.stem: p for p in sorted(Path(folder).glob("*.json"))}
    return catalogue.files("policies")


def available_policies(folder: str | os.PathLike | None = None) -> dict[str, PolicyDefinition]:
    """Every policy by name: the files of ``folder`` (default ``policies/``) and the Python
    registrations.

    Raises:
        FileFormatError: a definition file is broken (naming it and the field).
    """
    out = {name: _read_definition(path) for name, path in _file_definitions(folder).items()}
    for name, description in _PYTHON_DESCRIPTIONS.items():
        out[name] = PolicyDefinition(name=name, kind="python", description=description)
    return dict(sorted(out.items()))


def get_definition(name: str | os.PathLike) -> PolicyDefinition:
    """The definition of a policy given by name or by the path of its ``.json`` file."""
    text = str(name)
    if text.endswith(".json"):
        path = Path(text)
        if not path.is_file():
            raise FileFormatError(f"{path}: no such policy file.")
        return _read_definition(path)
    if text.endswith(".zip"):
        return _model_definition(Path(text))
    if text in _PYTHON_POLICIES:
        return PolicyDefinition(name=text, kind="python",
                                description=_PYTHON_DESCRIPTIONS.get(text, ""))
    files = _file_definitions()
    if text not in files:
        raise did_you_mean("policy", text, [*files, *_PYTHON_POLICIES])
    return _read_definition(files[text])


def _model_definition(path: Path) -> PolicyDefinition:
    """The definition of an SB3 model file: the ``.json`` that ``tap-bench train`` wrote
    beside it (same name), which records the observation config the model reads, or, when
    there is none, the model alone (it then reads the scenario's own observation)."""
    if not path.is_file():
        raise FileFormatError(f"{path}: no such model file.")
    beside = path.with_suffix(".json")
    if beside.is_file():
        doc = read_json(beside, "policy")
        params = doc.get("params") if isinstance(doc, dict) else None
        model = params.get("model") if isinstance(params, dict) else None
        if doc.get("kind") == "sb3" and isinstance(model, str) and (
                beside.parent / model).resolve() == path.resolve():
            definition = _read_definition(beside)
            return PolicyDefinition(name=definition.name, kind="sb3",
                                    description=definition.description,
                                    params={**definition.params, "model": str(path.resolve())},
                                    path=beside)
    return PolicyDefinition(name=path.stem, kind="sb3", params={"model": str(path.resolve())})


def load_policy(name: str | os.PathLike | Policy) -> Policy:
    """A policy by name (``"idm"``), definition file (``.json``) or SB3 model (``.zip``).

    A policy object is returned as it is.

    Raises:
        UnknownNameError: no such policy, with the closest names.
        FileFormatError: a broken definition file.
    """
    if isinstance(name, Policy):
        return name
    return get_definition(name).build()


class SeedGroupError(TapBenchError, ValueError):
    """A policy of kind ``seeds`` was asked to drive: it stands for several trained seeds."""


def seed_group(name: str, seeds: Sequence[str], base_dir: str | os.PathLike | None = None
               ) -> None:
    """The builder of kind ``seeds``: it refuses to build one policy, and says which."""
    raise SeedGroupError(
        f"policy {name!r} stands for {len(seeds)} trained seeds ({', '.join(seeds)}): roll "
        f"out one of them (--policy {seeds[0] if seeds else name + '-seed0'}), or run them "
        "all in a suite and aggregate them over seeds with 'tap-bench agents'.")


def seed_groups(definitions: Mapping[str, object] | None = None) -> dict[str, tuple[str, ...]]:
    """Agent name -> the policy names of its training seeds, from the definitions of kind
    ``seeds`` (default: every policy definition found, :func:`available_policies`).

    Raises:
        FileFormatError: a group whose ``seeds`` is not a non-empty list of names, or a
            policy that is a seed of two groups.
    """
    if definitions is None:
        definitions = available_policies()
    groups: dict[str, tuple[str, ...]] = {}
    owner: dict[str, str] = {}
    for name, definition in definitions.items():
        if getattr(definition, "kind", None) != "seeds":
            continue
        seeds = dict(definition.params).get("seeds")
        where = definition.path or name
        if not isinstance(seeds, list) or not seeds or not all(
                isinstance(s, str) and s for s in seeds):
            raise FileFormatError(f"{where}: params.seeds must be a non-empty list of policy "
                                  f"names (the trained seeds of {name}), got {seeds!r}.")
        for seed in seeds:
            if seed in owner:
                raise FileFormatError(f"{where}: {seed!r} is already a seed of "
                                      f"{owner[seed]!r}; a policy is a seed of one agent.")
            owner[seed] = name
        groups[name] = tuple(seeds)
    return groups


def expand_seed_groups(policies: Sequence[object]) -> tuple[object, ...]:
    """The policies of a suite with every policy of kind ``seeds`` replaced by its training
    seeds, in order (``["idm", "ppo-womd"]`` -> ``("idm", "ppo-womd-grid-seed0", ...)``); a
    policy named twice this way is kept once. What ``bench run`` runs, so that a suite can
    name an agent and ``tap-bench agents`` aggregate its seeds.

    Raises:
        FileFormatError: a group whose ``seeds`` is not a non-empty list of names.
    """
    out: list[object] = []
    for policy in policies:
        names: list[object] = [policy]
        if isinstance(policy, str | os.PathLike):
            try:
                definition = get_definition(policy)
            except TapBenchError:
                definition = None  # not a known name: resolving it says why
            if getattr(definition, "kind", None) == "seeds":
                names = list(seed_groups({str(policy): definition})[str(policy)])
        out.extend(n for n in names if n not in out)
    return tuple(out)
