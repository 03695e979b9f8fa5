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
import importlib.util
import inspect
import json
import os
import tempfile
from importlib import metadata
from pathlib import Path
from typing import Any

from tap_bench import catalogue
from tap_bench.errors import ParameterError, did_you_mean

__all__ = ["SPACES", "default_config", "space_parameters"]

SPACES = ("observation", "action")
"""The config keys whose value is a highway-env type with parameters."""
_FILE = "highway-env-schema.json"


@functools.cache
def _fingerprint() -> str:
    """Version and source files of the installed highway-env (not imported)."""
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
    schema = _schema()
    config = schema["envs"].get(highway_env_id)
    if config is None:

        config = env_class(highway_env_id).default_config()
        schema["envs"][highway_env_id] = json.loads(json.dumps(config, default=repr))
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


def env_class(highway_env_id: str) -> type:
    """The environment class behind a highway-env Gymnasium id."""
    import gymnasium
    import highway_env  # noqa: F401  (registers the highway-env ids)

    try:
        spec = gymnasium.spec(highway_env_id)
    except gymnasium.error.Error as err:
        known = [k for k in gymnasium.registry
                 if gymnasium.registry[k].entry_point.__str__().startswith("highway_env")]
        raise did_you_mean("highway-env id", highway_env_id, known) from err
    entry = spec.entry_point
    if callable(entry):
        return entry
    module, _, name = entry.partition(":")
    return getattr(__import__(module, fromlist=[name]), name)
