"""What scenario files are checked against: highway-env's default config of each env and the
keyword parameters of its observation and action types.

Importing highway-env takes about a second (it imports pygame and matplotlib), which
``tap-bench envs`` and every other reader of scenario files would pay only to look up
defaults. So the answers are read from highway-env once per installation and kept in
``<cache>/highway-env-schema.json`` (:func:`tap_bench.catalogue.cache_dir`), under a
fingerprint of the installed highway-env (its version and the path, size and modification
time of each of its source files): a new or edited highway-env is read again. Each env's
defaults are added the first time it is asked for. Without a writable cache folder the
answers are computed in every process, as before.
"""

from __future__ import annotations

import contextlib
import copy
import functools
import hashlib
import importlib
import importlib.util
import inspect
import json
import os
import tempfile
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

from tap_bench import catalogue
from tap_bench.errors import ParameterError, RegistrationError
from tap_bench.registry import Registry
from tap_bench.sim.registration import WOMD_ENV_ID

__all__ = ["OWN_KINDS", "SCENARIO_KINDS", "SPACES", "ScenarioKind", "check_scenario_kind",
           "default_config", "env_class", "scenario_kinds", "space_parameters"]

SPACES = ("observation", "action")
"""The config keys whose value is a highway-env type with parameters."""
_FILE = "highway-env-schema.json"


@functools.cache
def _fingerprint() -> str:
    """Version and source files of the installed highway-env (not imported), and the
    source of tap-bench's own scenario kinds (:data:`OWN_KINDS`)."""
    digest = hashlib.sha256()
    try:
        digest.update(metadata.version("highway-env").encode())
    except metadata.PackageNotFoundError:
        pass
    spec = importlib.util.find_spec("highway_env")
    if spec is not None and spec.origin:
        root = Path(spec.origin).parent
        for path in sorted(root.rglob("*.py")):
            st = path.stat()
            digest.update(f"{path.relative_to(root)}:{st.st_size}:{st.st_mtime_ns};".encode())
    for entry, _ in OWN_KINDS.values():  # tap-bench's own kinds' code too
        path = Path(__file__).with_name(entry.partition(":")[0].rpartition(".")[2] + ".py")
        with contextlib.suppress(OSError):
            digest.update(f"{path.name}:{path.read_bytes()!r};".encode())
    return digest.hexdigest()


def _path() -> Path:
    return catalogue.cache_dir() / _FILE


_MEMORY: dict[str, Any] = {}


def _schema() -> dict[str, Any]:
    """The schema of this installation (from memory, the file, or empty)."""
    fingerprint = _fingerprint()
    if _MEMORY.get("fingerprint") != fingerprint:
        _MEMORY.clear()
        try:
            doc = json.loads(_path().read_text())
        except (OSError, ValueError):
            doc = {}
        if not isinstance(doc, dict) or doc.get("fingerprint") != fingerprint:
            doc = {}
        _MEMORY.update(fingerprint=fingerprint, envs=doc.get("envs") or {},
                       spaces=doc.get("spaces") or {})
    return _MEMORY


def _save(schema: dict[str, Any]) -> None:
    path = _path()
    with contextlib.suppress(OSError):  # a read-only cache costs only the time
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{_FILE}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "w") as stream:
                json.dump(schema, stream, sort_keys=True)
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise


def default_config(highway_env_id: str) -> dict[str, Any]:
    """highway-env's default config of ``highway_env_id`` (a fresh copy).

    Raises:
        UnknownNameError: not a highway-env id (with the closest ids).
    """
    known = SCENARIO_KINDS[highway_env_id] if highway_env_id in SCENARIO_KINDS else None
    if (highway_env_id not in OWN_KINDS and known is not None
            and not known.entry_point.startswith("highway_env")):
        # plugins' kinds: their code is not in the fingerprint
        config = env_class(highway_env_id).default_config()
        return json.loads(json.dumps(config, default=repr))
    schema = _schema()
    config = schema["envs"].get(highway_env_id)
    if config is None:  # read from highway-env once, and answered as the file keeps it
        # (JSON values, keys sorted): the same dict as every later process reads, whose
        # order the cache's keys hash
        config = json.loads(json.dumps(env_class(highway_env_id).default_config(),
                                       default=repr, sort_keys=True))
        schema["envs"][highway_env_id] = config
        _save({"fingerprint": schema["fingerprint"], "envs": schema["envs"],
               "spaces": schema["spaces"]})
    return copy.deepcopy(config)


def space_parameters(space: str) -> dict[str, frozenset[str]]:
    """Type name -> the keyword parameters it accepts (``type`` included), for the
    ``observation`` or ``action`` of a config; ``**kwargs`` followed up the class hierarchy,
    since they swallow misspelled keys otherwise."""
    if space not in SPACES:
        raise ParameterError("space", space, f"one of {SPACES}")
    schema = _schema()
    if not schema["spaces"]:
        schema["spaces"] = {name: {kind: sorted(_init_parameters(cls))
                                   for kind, cls in classes().items()}
                            for name, classes in (("observation", _observation_classes),
                                                  ("action", _action_classes))}
        _save({"fingerprint": schema["fingerprint"], "envs": schema["envs"],
               "spaces": schema["spaces"]})
    return {kind: frozenset(params) for kind, params in schema["spaces"][space].items()}


def _observation_classes() -> dict[str, type]:
    from highway_env.envs.common import observation as obs

    return {
        "Kinematics": obs.KinematicObservation,
        "TimeToCollision": obs.TimeToCollisionObservation,
        "OccupancyGrid": obs.OccupancyGridObservation,
        "KinematicsGoal": obs.KinematicsGoalObservation,
        "GrayscaleObservation": obs.GrayscaleObservation,
        "AttributesObservation": obs.AttributesObservation,
        "TupleObservation": obs.TupleObservation,
        "LidarObservation": obs.LidarObservation,
        "ExitObservation": obs.ExitObservation,
    }


def _action_classes() -> dict[str, type]:
    from highway_env.envs.common import action as act

    return {
        "ContinuousAction": act.ContinuousAction,
        "DiscreteAction": act.DiscreteAction,
        "DiscreteMetaAction": act.DiscreteMetaAction,
    }


def _init_parameters(cls: type) -> set[str]:
    names: set[str] = set()
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        params = inspect.signature(klass.__init__).parameters
        names |= {n for n, p in params.items() if n not in ("self", "env")
                  and p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)}
        if not any(p.kind == p.VAR_KEYWORD for p in params.values()):
            break
    return names | {"type"}


@dataclass(frozen=True)
class ScenarioKind:
    """An environment a scenario file's ``highway_env_id`` may name.

    Args:
        name: the Gymnasium id (``"highway-v0"``).
        entry_point: ``"module:Class"`` of the environment class; it is built with
            ``Class(config=..., render_mode=...)`` and must have ``default_config()``.
        description: where it comes from, for messages and listings.
        configurable: False for an environment a scenario file cannot configure (it takes
            no highway-env config); naming it is refused with ``description`` as the fix.
    """

    name: str
    entry_point: str
    description: str = ""
    configurable: bool = True


def check_scenario_kind(kind: ScenarioKind) -> None:
    """Refuse an entry whose environment workers could not import by name.

    Raises:
        RegistrationError: ``entry_point`` is not a ``"module:attribute"`` string.
    """
    module, _, attr = str(kind.entry_point).partition(":")
    if not isinstance(kind.entry_point, str) or not module or not attr:
        raise RegistrationError(
            f"scenario kind {kind.name!r}: entry_point must be 'module:attribute' (got "
            f"{kind.entry_point!r}), so that every worker process can import the environment.")


SCENARIO_KINDS: Registry[ScenarioKind] = Registry("scenario kind (highway_env_id)",
                                                  check=check_scenario_kind)
"""The environments a scenario file may name; filled with highway-env's Gymnasium ids (and
``tap_bench/womd-v0``, which cannot be configured by a file) by :func:`scenario_kinds`.
Plugins add their own with ``SCENARIO_KINDS.register(ScenarioKind(...))``."""
_FILLED = False

OWN_KINDS = {"exit-seeded-v0": ("tap_bench.sim.exit_env:SeededExitEnv",
                                "tap-bench: highway-env's exit scene drawn from its seed, "
                                "the IDM ego routed to the exit")}
"""tap-bench's own scenario kinds: name -> (entry point, description)."""


def scenario_kinds() -> Registry[ScenarioKind]:
    """:data:`SCENARIO_KINDS`, first filled with every Gymnasium id whose entry point is in
    highway-env (importing highway-env: about a second, once per process), with
    ``tap_bench/womd-v0`` when it is registered and with tap-bench's seeded exit scene
    (:mod:`tap_bench.sim.exit_env`)."""
    global _FILLED
    if not _FILLED:
        import gymnasium
        import highway_env  # noqa: F401  (registers the highway-env ids)

        for key, spec in gymnasium.registry.items():
            entry = spec.entry_point
            if key in SCENARIO_KINDS or not isinstance(entry, str):
                continue
            if entry.startswith("highway_env"):
                SCENARIO_KINDS.register(ScenarioKind(key, entry, "highway-env"))
            elif key == WOMD_ENV_ID:
                SCENARIO_KINDS.register(ScenarioKind(
                    key, entry, configurable=False, description=(
                        "recorded WOMD scenes in closed loop take driving-data files, not a "
                        "highway-env config: run them with `tap-bench rollout --womd FILES` or "
                        "a suite's womd scenes, and name a highway-env id here")))
        for key, (entry, description) in OWN_KINDS.items():
            if key not in SCENARIO_KINDS:
                SCENARIO_KINDS.register(ScenarioKind(key, entry, description))
        _FILLED = True
    return SCENARIO_KINDS


def env_class(highway_env_id: str) -> type:
    """The environment class behind a scenario kind (:func:`scenario_kinds`).

    Raises:
        UnknownNameError: not a scenario kind (with the closest names).
        ParameterError: a kind a scenario file cannot configure (``tap_bench/womd-v0``).
    """
    kind = scenario_kinds()[highway_env_id]
    if not kind.configurable:
        raise ParameterError("highway_env_id", highway_env_id, "a highway-env id",
                             message=f"highway_env_id {highway_env_id!r}: {kind.description}.")
    module, _, name = kind.entry_point.partition(":")
    return getattr(importlib.import_module(module), name)
