"""The episode cache of ``bench run``: rollouts stored by what made them, so that a re-run
simulates only the episodes whose inputs changed.

**The key** of an episode is the SHA-256 of a JSON document (:func:`episode_key`) holding
everything the rollout's trajectory table depends on:

- the env: the highway-env id and its *resolved* config (highway-env's defaults updated with
  the scenario's overrides, the suite's overrides, the episode length), the lane-change
  setting, the duration and the number of decisions;
- the policy: its full definition (name, kind, parameters), the SHA-256 of every file a
  parameter names (an SB3 ``.zip``, with the versions of Stable-Baselines3 and torch that
  run it), and for kind ``import`` the SHA-256 of the factory's module source;
- the seed;
- the code and versions: the cache entry format, tap-bench's version, the SHA-256 of every
  module of :mod:`tap_bench.sim` (recorder, scenario env, vehicles, policies, rollout ...;
  so an edit to the recorder or to IDM invalidates the episodes even when the version
  number stays), and the versions of highway-env, Gymnasium and NumPy.

Policies registered in Python with :func:`tap_bench.register_policy` have no definition to
hash and are never cached; failed episodes are never cached either.

**An entry** is one file ``<dir>/episodes/<key[:2]>/<key>.episode``: one line of JSON (the
key, its document, the episode-table row, the rollout's wall time, the payload's size and
SHA-256), then the trajectory table as Parquet. A reader checks the key, the document's
hash and the payload's hash before using an entry; an entry that fails a check (a torn
write, a flipped bit, a file copied under the wrong name) is deleted and its episode
simulated again, never used. Entries are written to a temporary file in the same folder and
renamed into place, so readers never see half an entry, and concurrent writers of the same
episode each leave a whole, equal file. Labels and scores are never cached: ``bench run``
recomputes them from the trajectory tables with the run's thresholds.

**Location and size**: ``$TAP_BENCH_CACHE``, else ``$XDG_CACHE_HOME/tap-bench``, else
``~/.cache/tap-bench`` (:func:`default_cache_dir`). An entry of the default suite is about
80 kB (its 750 episodes take about 60 MiB; ``benchmarks/bench_incremental.py`` measures
it). After each run the cache is pruned to ``max_bytes`` (:data:`DEFAULT_MAX_BYTES`),
least recently used entries first (a hit refreshes an entry's time); ``tap-bench bench
cache prune --max-size`` prunes by hand.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import io
import json
import math
import os
import re
import tempfile
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import pandas as pd

from tap_bench import catalogue
from tap_bench._version import __version__
from tap_bench.errors import ParameterError
from tap_bench.sim.policies import PolicyDefinition
from tap_bench.sim.schema import default_config
from tap_bench.sim.suite import Scenario

__all__ = ["DEFAULT_MAX_BYTES", "ENTRY_FORMAT", "CachedEpisode",
           "EpisodeCache", "default_cache_dir", "episode_key", "parse_size",
           "policy_fingerprint", "scenario_fingerprint", "simulation_fingerprint"]

DEFAULT_MAX_BYTES = 2 << 30
"""Size the cache is pruned to after a run [B]: ten default suites."""
ENTRY_FORMAT = 1
"""Layout of an entry file; raised when it changes (old entries then miss)."""
def _simulation_modules() -> list[Path]:
    """Every module of :mod:`tap_bench.sim`: the code an episode's trajectory table depends
    on (all of them, so that a module added there is covered without a list to update; an
    edit to one an episode does not use costs only a re-simulation)."""
    return sorted((Path(__file__).resolve().parent.parent / "sim").glob("*.py"))
_SUFFIX = ".episode"
_STALE_TMP_S = 3600.0  # a temporary file this old belongs to a writer that died [s]
_KEY = re.compile(r"^[0-9a-f]{64}$")


def default_cache_dir() -> Path:
    """:func:`tap_bench.catalogue.cache_dir`: ``$TAP_BENCH_CACHE``, else
    ``$XDG_CACHE_HOME/tap-bench``, else ``~/.cache/tap-bench``."""
    return catalogue.cache_dir()


def parse_size(text: str | int, parameter: str = "--max-size") -> int:
    """Bytes from ``"500M"``, ``"2G"``, ``"0"``, ``"1.5GB"`` or an int (powers of 1024).

    Raises:
        ParameterError: not a size.
    """
    if isinstance(text, int) and not isinstance(text, bool) and text >= 0:
        return text
    match = re.fullmatch(r"\s*(\d+(?:\.\d+)?)\s*([kKmMgGtT]?)i?[bB]?\s*", str(text))
    if not match:
        raise ParameterError(parameter, text, "a size such as 500M, 2G or 0 (bytes, with an "
                             "optional K, M, G or T suffix)")
    scale = 1024 ** " KMGT".index(match.group(2).upper() or " ")
    return int(float(match.group(1)) * scale)


def _sha256_file(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "absent"


def simulation_fingerprint() -> dict[str, Any]:
    """The code and versions every episode's key includes (module docstring)."""
    digest = hashlib.sha256()
    for path in _simulation_modules():
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return {"entry_format": ENTRY_FORMAT, "tap-bench": __version__,
            "simulation_code": digest.hexdigest(), "highway-env": _version("highway-env"),
            "gymnasium": _version("gymnasium"), "numpy": _version("numpy")}


def scenario_fingerprint(scenario: Scenario) -> dict[str, Any]:
    """The env part of a key: the highway-env id, its resolved config, lane changes,
    duration [s] and decisions per episode."""
    config = default_config(scenario.highway_env_id)
    config.update(scenario.config)
    return {"highway_env_id": scenario.highway_env_id, "config": config,
            "lane_change": scenario.lane_change, "duration": scenario.duration,
            "max_steps": scenario.max_steps}


def policy_fingerprint(definition: PolicyDefinition) -> dict[str, Any] | None:
    """The policy part of a key, or None for a policy that cannot be cached (a Python
    registration: no definition to hash).

    Every string parameter naming an existing file (relative to the definition file's
    folder, as the builders read them) adds that file's SHA-256; kind ``sb3`` adds the
    versions of Stable-Baselines3 and torch; kind ``import`` adds the SHA-256 of the
    factory module's source.
    """
    if definition.kind == "python":
        return None
    base = definition.path.parent if definition.path is not None else Path.cwd()
    files = {}
    for key, value in sorted(definition.params.items()):
        if isinstance(value, str) and value:
            path = Path(value) if Path(value).is_absolute() else base / value
            if path.is_file():
                files[key] = _sha256_file(path)
    doc: dict[str, Any] = {"name": definition.name, "kind": definition.kind,
                           "params": dict(definition.params), "files": files}
    if definition.kind == "sb3":  # the same weights act otherwise under another torch
        doc["versions"] = {pkg: _version(pkg) for pkg in ("stable-baselines3", "torch")}
    if definition.kind == "import":
        module = str(definition.params.get("factory", "")).partition(":")[0]
        try:
            spec = importlib.util.find_spec(module) if module else None
        except (ImportError, ValueError):
            spec = None
        origin = Path(spec.origin) if spec is not None and spec.origin else None
        if origin is None or not origin.is_file():
            return None  # code we cannot hash is not cached
        doc["code"] = _sha256_file(origin)
    return doc


def _canonical(doc: Any) -> bytes:
    return json.dumps(doc, sort_keys=True, separators=(",", ":"), default=repr,
                      allow_nan=True).encode()


def episode_key(env: Mapping[str, Any], policy: Mapping[str, Any], seed: int,
                versions: Mapping[str, Any]) -> tuple[str, dict[str, Any]]:
    """The key of one episode and the document it hashes.

    Args:
        env: :func:`scenario_fingerprint`.
        policy: :func:`policy_fingerprint`.
        seed: the episode's seed.
        versions: :func:`simulation_fingerprint`.

    Returns:
        (64 hex digits, the document).
    """
    doc = {"env": dict(env), "policy": dict(policy), "seed": int(seed),
           "versions": dict(versions)}
    return hashlib.sha256(_canonical(doc)).hexdigest(), doc


@dataclass(frozen=True)
class CachedEpisode:
    """An episode read from the cache.

    Attributes:
        trajectories: its trajectory table, as the rollout made it.
        row: its row of the episode table (:data:`tap_bench.sim.rollout.EPISODE_COLUMNS`).
        seconds: wall time of the rollout that made it [s].
    """

    trajectories: pd.DataFrame
    row: dict[str, Any]
    seconds: float


@dataclass(frozen=True)
class PruneReport:
    """What :meth:`EpisodeCache.prune` did: entries and bytes removed and kept."""

    removed: int
    freed_bytes: int
    kept: int
    kept_bytes: int


@dataclass(frozen=True)
class EpisodeCache:
    """The episode cache in ``root`` (see the module docstring).

    Attributes:
        root: the cache folder (created on first write).
        max_bytes: size :meth:`prune` keeps by default [B].

    Cheap to pickle: rollout workers read and write entries themselves.
    """

    root: Path = field(default_factory=default_cache_dir)
    max_bytes: int = DEFAULT_MAX_BYTES

    def __post_init__(self) -> None:
        object.__setattr__(self, "root", Path(self.root).expanduser())
        if isinstance(self.max_bytes, bool) or not isinstance(self.max_bytes, int) \
                or self.max_bytes < 0:
            raise ParameterError("max_bytes", self.max_bytes, "an integer >= 0 (bytes)")

    @property
    def folder(self) -> Path:
        """Where the entries are."""
        return self.root / "episodes"

    def path(self, key: str) -> Path:
        """The entry file of ``key``."""
        if not _KEY.match(key):
            raise ParameterError("key", key, "64 lower-case hex digits (a SHA-256)")
        return self.folder / key[:2] / f"{key}{_SUFFIX}"

    def contains(self, key: str) -> bool:
        """Whether an entry file exists for ``key`` (unverified: :meth:`get` checks it)."""
        return self.path(key).is_file()

    def get(self, key: str) -> CachedEpisode | None:
        """The episode of ``key``, or None when it is missing or fails a check (a failing
        entry is deleted, so that the episode is simulated and stored again)."""
        path = self.path(key)
        try:
            data = path.read_bytes()
        except OSError:
            return None
        try:
            episode = _decode(data, key)
        except (ValueError, KeyError, TypeError, OSError):  # corrupt or foreign: never used
            with contextlib.suppress(OSError):
                path.unlink()
            return None
        with contextlib.suppress(OSError):
            os.utime(path)  # recently used: pruned last
        return episode

    def put(self, key: str, doc: Mapping[str, Any], trajectories: pd.DataFrame,
            row: Mapping[str, Any], seconds: float) -> Path:
        """Store an episode under ``key`` (atomically; see the module docstring)."""
        if hashlib.sha256(_canonical(doc)).hexdigest() != key:
            raise ParameterError("key", key, "the SHA-256 of doc (episode_key)")
        buffer = io.BytesIO()
        trajectories.to_parquet(buffer, index=False)
        payload = buffer.getvalue()
        header = {"format": "tap-bench-episode", "format_version": ENTRY_FORMAT, "key": key,
                  "doc": doc, "row": dict(row), "seconds": float(seconds),
                  "payload_bytes": len(payload),
                  "payload_sha256": hashlib.sha256(payload).hexdigest(),
                  "created": time.strftime("%Y-%m-%d %H:%M:%S")}
        path = self.path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{key[:16]}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as stream:
                stream.write(_canonical(header) + b"\n")
                stream.write(payload)
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        return path

    def _entries(self) -> Iterator[tuple[Path, os.stat_result]]:
        if not self.folder.is_dir():
            return
        for path in self.folder.glob(f"*/*{_SUFFIX}"):
            with contextlib.suppress(OSError):
                yield path, path.stat()

    def size(self) -> tuple[int, int]:
        """(entries, bytes) in the cache."""
        entries = list(self._entries())
        return len(entries), sum(st.st_size for _, st in entries)

    def prune(self, max_bytes: int | None = None) -> PruneReport:
        """Delete least recently used entries until the cache holds at most ``max_bytes``
        (default :attr:`max_bytes`), and temporary files left by writers that died."""
        limit = self.max_bytes if max_bytes is None else max_bytes
        if isinstance(limit, bool) or not isinstance(limit, int) or limit < 0:
            raise ParameterError("max_bytes", limit, "an integer >= 0 (bytes)")
        now = time.time()
        if self.folder.is_dir():
            for tmp in self.folder.glob("*/.*.tmp"):
                with contextlib.suppress(OSError):
                    if now - tmp.stat().st_mtime > _STALE_TMP_S:
                        tmp.unlink()
        entries = sorted(self._entries(), key=lambda e: e[1].st_mtime)
        total = sum(st.st_size for _, st in entries)
        removed = freed = 0
        for path, st in entries:
            if total <= limit:
                break
            with contextlib.suppress(OSError):
                path.unlink()
                removed += 1
                freed += st.st_size
            total -= st.st_size
        return PruneReport(removed, freed, len(entries) - removed, total)

    # -- timings, for estimates of how long a run will take ------------------------------
    @property
    def timings_path(self) -> Path:
        return self.root / "timings.json"

    def timings(self) -> dict[str, Any]:
        """What earlier runs measured, for estimates: mean wall time per episode by env [s],
        of simulated and of cached episodes (labelling included), and the rest of a run's
        wall time (worker start-up, scoring, the report): ``{"simulated": {"highway": 4.1},
        "cached": {...}, "overhead": 12.0}`` (empty when unknown or unreadable)."""
        try:
            doc = json.loads(self.timings_path.read_text())
        except (OSError, ValueError):
            return {}
        out: dict[str, Any] = {}
        if not isinstance(doc, dict):
            return out
        for kind in ("simulated", "cached"):
            values = doc.get(kind)
            if isinstance(values, dict):
                out[kind] = {env: float(v) for env, v in values.items() if _positive(v)}
        if _positive(doc.get("overhead")):
            out["overhead"] = float(doc["overhead"])
        return out

    def record_timings(self, simulated: Mapping[str, float], cached: Mapping[str, float],
                       overhead: float | None = None) -> None:
        """Merge one run's figures (mean seconds per episode by env; see :meth:`timings`)
        into the timings file, the latest run winning (written atomically)."""
        doc = self.timings()
        for kind, values in (("simulated", simulated), ("cached", cached)):
            doc.setdefault(kind, {}).update({env: float(v) for env, v in values.items()
                                             if _positive(v)})
        if overhead is not None and _positive(overhead):
            doc["overhead"] = float(overhead)
        self.root.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".timings.", suffix=".tmp", dir=self.root)
        try:
            with os.fdopen(fd, "w") as stream:
                json.dump(doc, stream, indent=1, sort_keys=True)
            os.replace(tmp, self.timings_path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise


def _positive(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) \
        and math.isfinite(value) and value > 0


def _decode(data: bytes, key: str) -> CachedEpisode:
    """An entry's content, or ValueError/KeyError/TypeError naming the failed check."""
    line, sep, payload = data.partition(b"\n")
    if not sep:
        raise ValueError("no header line")
    header = json.loads(line)
    if header.get("format") != "tap-bench-episode" \
            or header.get("format_version") != ENTRY_FORMAT:
        raise ValueError("another entry format")
    if header["key"] != key or hashlib.sha256(_canonical(header["doc"])).hexdigest() != key:
        raise ValueError("the entry belongs to another key")
    if len(payload) != header["payload_bytes"] \
            or hashlib.sha256(payload).hexdigest() != header["payload_sha256"]:
        raise ValueError("the payload does not match its hash")
    trajectories = pd.read_parquet(io.BytesIO(payload))
    row = header["row"]
    if not isinstance(row, dict) or row.get("status") != "ok":
        raise ValueError("not a successful episode")
    return CachedEpisode(trajectories, row, float(header["seconds"]))
