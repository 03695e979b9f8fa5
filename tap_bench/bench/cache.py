"""The episode cache of ``bench run``: rollouts stored by what made them, so that a re-run
simulates only the episodes whose inputs changed.

**The key** of an episode is the SHA-256 of a JSON document (:func:`episode_key`) holding
everything that can change its trajectory table (any byte changed in any input changes it;
``tests/bench/test_cache_keys.py``):

- the env (:func:`scenario_fingerprint`): its name in the suite, every field of the
  resolved scenario (name, version, script, lane changes, config overrides ...), the
  SHA-256 of the scenario file and of every file a field names, the highway-env id and its
  *resolved* config, the duration and the number of decisions, the code of a user
  vehicle class the config names, and for a scenario kind a plugin registers its entry
  point and code;
- the policy (:func:`policy_fingerprint`): its full definition and the SHA-256 of its file
  and of every file a parameter names (an SB3 ``.zip``, with the versions of
  Stable-Baselines3 and torch), for kind ``import`` the code of the factory's module, of
  every module it imports in the user's code and of its whole top-level package
  (:func:`tap_bench.usercode.code_files`), and for a policy kind a plugin registers the
  builder's name and code, hashed the same way;
- the seed;
- the code and versions: the cache entry format, tap-bench's version, the SHA-256 of its
  simulation code (:data:`SIMULATION_CODE`), and the versions of highway-env, Gymnasium
  and NumPy.

Policies registered in Python with :func:`tap_bench.register_policy`, code without Python
source and failed episodes are never cached.

**Modules loaded by name** as a policy, a vehicle class or a measure is built or runs
(``importlib.import_module("helper")``) are in no key: the run notes every module of the
user's code its processes import for the first time while they do so
(:func:`tap_bench.usercode.recording`) and each episode and label entry keeps them with
their files' SHA-256 (``loaded``); an entry is served only while every one still hashes the
same, else it is a miss (made again, no warning: it is not damaged).

**An entry** is one file ``<dir>/episodes/<key[:2]>/<key>.episode``: one line of JSON (the
key, its document, the episode-table row, the rollout's wall time, the payload's size and
SHA-256, and a checksum of the whole header, the row included), then the trajectory table
as Parquet. A reader verifies the whole entry before using it (:func:`_decode`: the header
an object of the expected fields and types, its checksum, the key, the payload, a row of
one successful episode of the key's seed); an entry that fails (a torn write, a flipped
bit, an edited row, a header of ``null`` or deep nesting, a file copied under the wrong
name) is deleted and its episode simulated again, with a note (:meth:`EpisodeCache.read`).
Entries are written to a temporary file in the same folder and renamed into place, so
readers never see half an entry, and concurrent writers of the same episode each leave a
whole, equal file. The checksums catch damage, not intent: a shared cache needs trusted
writers.

**Labels and measures** of an episode are kept beside it (``<dir>/labels/``,
:meth:`EpisodeCache.put_labels`, as Arrow IPC tables), keyed by the episode's key, the
thresholds, the level and the code of labelling and measures (:func:`label_key`,
:func:`label_code`), and verified whole in the same way; a re-run reads them and only
scores and writes the report. Labelling and measuring never depend on the other episodes
of a batch, so the tables are the same, float for float, whatever the cache holds
(``tests/bench/test_rerun.py``).

**Derived outputs** of a run whose inputs are unchanged are kept too (``<dir>/derived/``,
:func:`memoised`): the scores (when the run has no reference corpora or plug-ins), each
env's road map, the report's figures and the replay viewer's episode data. Each is keyed by
the content of its inputs (:func:`table_digest` of each input table, the settings that
matter) and the code of the whole tap-bench package with the versions of NumPy, pandas,
PyArrow and SciPy (:func:`derived_key`), and verified whole like the other entries, so a
change of any input or of any tap-bench module makes them again, and what a re-run serves
is what it would have made. A damaged one is made again with a warning and listed in the
run's ``cache.refused`` (:func:`note_refused`). A whole run whose every input is unchanged
is kept too (kind ``runs``: its run folder, served without reading an episode;
:mod:`tap_bench.bench.run.served`).

**Location and size**: ``$TAP_BENCH_CACHE``, else ``$XDG_CACHE_HOME/tap-bench``, else
``~/.cache/tap-bench`` (:func:`default_cache_dir`); how much an episode takes is measured
by ``benchmarks/bench_incremental.py`` (docs/benchmark.md, "Incremental runs"). After each
run the cache is pruned to ``max_bytes`` (:data:`DEFAULT_MAX_BYTES`),
least recently used entries first (a hit refreshes an entry's time); ``tap-bench bench
cache prune --max-size`` prunes by hand.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import io
import json
import math
import os
import re
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from tap_bench import catalogue
from tap_bench._version import __version__
from tap_bench.errors import ParameterError
from tap_bench.sim.policies import POLICY_KINDS, PolicyDefinition
from tap_bench.sim.scenario_format import VEHICLE_TYPE_KEYS, Scenario
from tap_bench.sim.schema import SCENARIO_KINDS
from tap_bench.usercode import (
    TRUSTED_PACKAGES,
    _source_path,
    code_digest,
    find_module_source,
    user_code_holds,
)

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["DEFAULT_MAX_BYTES", "ENTRY_FORMAT", "CachedEpisode",
           "EpisodeCache", "default_cache_dir", "derived_key", "episode_key", "memoised",
           "package_code", "parse_size", "table_digest",
           "policy_fingerprint", "scenario_fingerprint", "simulation_fingerprint"]

T = TypeVar("T")

DEFAULT_MAX_BYTES = 2 << 30
"""Size the cache is pruned to after a run [B]: ten default suites."""
ENTRY_FORMAT = 3
"""Layout of an entry file; raised when it changes (old entries then miss). 3: the user's
modules loaded while the episode was made (``loaded``)."""
SIMULATION_CODE = ("sim", "trajectories.py", "womd", "sources")
"""tap-bench's simulation code, relative to the package: every module of :mod:`tap_bench.sim`
(all of them, so that a module added there is covered without a list to update; an edit to
one an episode does not use costs only a re-simulation), the trajectory contract the
recorder writes to, and the readers recorded scenes are built from (``womd/``: the road
map, its topology and the record decoders; ``sources/``: the ScenarioNet reader).
Labelling and measures are not here: they are keyed by the label cache (:data:`LABEL_CODE`),
so an edit to them re-labels without re-simulating."""


def _simulation_modules() -> list[Path]:
    """The source files of :data:`SIMULATION_CODE`."""
    package = Path(__file__).resolve().parent.parent
    out: list[Path] = []
    for name in SIMULATION_CODE:
        path = package / name
        out += sorted(path.rglob("*.py")) if path.is_dir() else [path]
    return out


_SUFFIX = ".episode"
_LABELS_SUFFIX = ".labels"
_DERIVED_SUFFIX = ".derived"
_FILE_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9._-]{0,199}$")
_PATH_PART = re.compile(r"^(?!\.{1,2}$)[A-Za-z0-9._-]{1,200}$")


def _file_name_ok(name: str) -> bool:
    """Whether ``name`` is a file name a derived entry may hold: a plain name, or (a run's
    files, :mod:`tap_bench.bench.run.served`) a relative path of two to eight parts
    (``viewer/data/index.js``, ``viewer/.tap-bench-folder``; no empty, ``.`` or ``..``
    part)."""
    parts = name.split("/")
    if len(parts) == 1:
        return bool(_FILE_NAME.match(name))
    return len(parts) <= 8 and all(_PATH_PART.match(part) for part in parts)


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


@functools.cache
def _version(package: str) -> str:
    """An installed package's version (read once a process: each read parses its
    metadata file)."""
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "absent"


def simulation_fingerprint(modules: list[Path] | None = None) -> dict[str, Any]:
    """The code and versions every episode's key includes (module docstring).

    Args:
        modules: the simulation's source files (default :data:`SIMULATION_CODE`'s).
    """
    digest = hashlib.sha256()
    package = Path(__file__).resolve().parent.parent
    for path in _simulation_modules() if modules is None else modules:
        name = path.relative_to(package) if path.is_relative_to(package) else path.name
        digest.update(Path(name).as_posix().encode() + b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return {"entry_format": ENTRY_FORMAT, "tap-bench": __version__,
            "simulation_code": digest.hexdigest(), "highway-env": _version("highway-env"),
            "gymnasium": _version("gymnasium"), "numpy": _version("numpy")}


def _plain(value: Any) -> Any:
    """``value`` as JSON-able data: objects with ``to_dict`` (a script) as their dict,
    tuples as lists, mappings as dicts."""
    if hasattr(value, "to_dict"):
        return _plain(value.to_dict())
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def _named_files(doc: Any, base: Path, found: dict[str, str], where: str = "") -> None:
    """The SHA-256 of every existing file a string of ``doc`` names (relative to ``base``),
    by where in ``doc`` it is named."""
    if isinstance(doc, Mapping):
        for key, value in sorted(doc.items(), key=lambda kv: str(kv[0])):
            _named_files(value, base, found, f"{where}.{key}" if where else str(key))
    elif isinstance(doc, list | tuple):
        for i, value in enumerate(doc):
            _named_files(value, base, found, f"{where}[{i}]")
    elif isinstance(doc, str) and doc and len(doc) < 4096 and "\0" not in doc:
        with contextlib.suppress(OSError, ValueError):
            path = Path(doc) if Path(doc).is_absolute() else base / doc
            if path.is_file():
                found[where] = _sha256_file(path)


def _user_code(module: str) -> dict[str, Any] | None:
    """:func:`tap_bench.usercode.code_digest` of ``module`` ({} for tap-bench's and
    highway-env's own modules: the versions and simulation code cover them), None when it
    has no Python source to hash."""
    if module.split(".")[0] in TRUSTED_PACKAGES:
        return {}
    return code_digest(module)


def scenario_fingerprint(scenario: Scenario, env: str | None = None) -> dict[str, Any] | None:
    """The env part of a key, or None when the scenario names code that cannot be hashed
    (a vehicle class of a module without Python source: never cached).

    It holds the env's name in the suite (``env``, default the scenario's name), every field
    of the resolved scenario (name, version, script, lane changes, description, the config
    overrides ...), the highway-env id, its resolved config (highway-env's defaults updated
    with the overrides), the duration [s] and decisions per episode, the SHA-256 of the
    scenario file and of every file a field names, and the code of each user vehicle class
    the config names (:data:`tap_bench.sim.scenario_format.VEHICLE_TYPE_KEYS`, hashed with the
    modules it loads in the user's package).
    """
    config = scenario.env_config
    fields = {f.name: _plain(getattr(scenario, f.name)) for f in dataclasses.fields(scenario)
              if f.name != "path"}
    doc: dict[str, Any] = {"env": env if env is not None else scenario.name,
                           "scenario": fields, "highway_env_id": scenario.highway_env_id,
                           "config": _plain(config), "lane_change": scenario.lane_change,
                           "duration": scenario.duration, "max_steps": scenario.max_steps}
    base = scenario.path.parent if scenario.path is not None else Path.cwd()
    if scenario.path is not None and scenario.path.is_file():
        doc["file_sha256"] = _sha256_file(scenario.path)
    files: dict[str, str] = {}
    _named_files(fields, base, files)
    doc["files"] = files
    kind = SCENARIO_KINDS.get(scenario.highway_env_id)
    if kind is not None:  # a plugin's environment class (highway-env's and tap-bench's are
        code = _user_code(kind.entry_point.partition(":")[0])  # keyed by their versions)
        if code is None:
            return None
        if code:
            doc["kind"] = {"entry_point": kind.entry_point, "code": code}
    vehicles = {}
    for key in VEHICLE_TYPE_KEYS:
        if isinstance(config.get(key), str):
            code = _user_code(config[key].rpartition(".")[0])
            if code is None:
                return None
            vehicles[key] = code
    doc["vehicle_code"] = vehicles
    return doc


def policy_fingerprint(definition: PolicyDefinition) -> dict[str, Any] | None:
    """The policy part of a key, or None for a policy that cannot be cached (a Python
    registration: no definition to hash; an ``import`` factory without Python source).

    It holds the definition (name, kind, parameters), the SHA-256 of its file, of every
    file a string parameter names (relative to the definition file's folder, as the
    builders read them: an SB3 ``.zip``), for kind ``sb3`` the versions of
    Stable-Baselines3 and torch, and for kind ``import`` the code of the factory's module
    and of every module it loads in the user's package (:func:`tap_bench.usercode.
    code_files`).
    """
    if definition.kind == "python":
        return None
    base = definition.path.parent if definition.path is not None else Path.cwd()
    files: dict[str, str] = {}
    _named_files(dict(definition.params), base, files)
    doc: dict[str, Any] = {"name": definition.name, "kind": definition.kind,
                           "params": _plain(definition.params), "files": files}
    if definition.path is not None and definition.path.is_file():
        doc["file_sha256"] = _sha256_file(definition.path)
    kind = POLICY_KINDS.get(definition.kind)
    if kind is not None:  # the builder a kind names: a plugin's code is keyed like a factory
        builder = kind.builder.partition(":")[0]
        code = _user_code(builder)
        if code is None:
            return None
        if code:
            doc["builder"] = {"name": kind.builder, "code": code}
    if definition.kind == "sb3":  # the same weights act otherwise under another torch
        doc["versions"] = {pkg: _version(pkg) for pkg in ("stable-baselines3", "torch")}
    if definition.kind == "import":
        module = str(definition.params.get("factory", "")).partition(":")[0]
        code = _user_code(module) if module else None
        if code is None:
            return None  # code we cannot hash is not cached
        doc["code"] = code
    return doc


LABELS_FORMAT = 3
"""Layout of a label entry file; raised when it changes (old entries then miss). 2: the
tables as Arrow IPC streams (a re-run reads them four times quicker than Parquet); 3: the
user's modules loaded while they were made (``loaded``)."""
LABEL_CODE = ("tap_bench.labelling", "tap_bench.bench.episodes", "tap_bench.bench.measures",
              "tap_bench.bench.scores.contexts", "tap_bench.sim.roads", "tap_bench.bench.run.tasks")
"""The modules that make an episode's label entry (labels, measures, segments and context
occurrences); their code and every module of tap-bench they import (followed transitively)
key the label cache (:func:`label_code`). ``tap_bench.bench.run.tasks`` chooses the map an
episode is labelled along and calls the others; ``tap_bench.bench.scores.contexts`` makes the
occurrences; ``tap_bench.sim.roads`` builds a highway-env episode's map table
(:data:`ROAD_MAP`) and brings :mod:`tap_bench.maps` (its sampling step), which the episode
key does not hold."""


_IMPORT = re.compile(r"^[ \t]*(?:from[ \t]+(tap_bench[\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n]+)"
                     r"|import[ \t]+(tap_bench[\w.]*))", re.MULTILINE)


def _tap_bench_closure(starts: tuple[str, ...]) -> dict[str, Path]:
    """The source files of ``starts`` and of every tap-bench module they import (at any
    depth, function-level imports included; the import lines are read as text, which is
    twenty times quicker than parsing every module on every run)."""
    files: dict[str, Path] = {}
    specs: dict[str, Any] = {}  # each package looked up once
    todo = list(starts)
    while todo:
        name = todo.pop()
        if name in files:
            continue
        path = _source_path(find_module_source(name, specs))
        if path is None:
            continue
        files[name] = path
        named: set[str] = set()
        for base, names, plain in _IMPORT.findall(path.read_text(errors="replace")):
            if plain:
                named.add(plain)
                continue
            named.add(base)
            for part in names.strip("()").replace("\n", ",").split(","):
                word = part.split("#")[0].split(" as ")[0].strip()
                if word.isidentifier():
                    named.add(f"{base}.{word}")
        todo += [m for m in named if m not in files]
    return dict(sorted(files.items()))


def label_code(measures: Iterable[Any] | None = None) -> dict[str, Any]:
    """What the labels and measures of an episode depend on besides its trajectories, the
    thresholds and the level: the code of :data:`LABEL_CODE` (with what it imports in
    tap-bench), the run's measure entries and the scene measures registered (every field,
    the function by name, and the code of those a plug-in adds), the versions of
    tap-bench, NumPy, pandas, numba and PyArrow.

    Args:
        measures: the run's measure entries (default: those registered now); the scene
            measures (:data:`~tap_bench.bench.measures.SCENE_MEASURES`, which a recorded
            scene's episode is measured with) are added to them.
    """
    from tap_bench.bench.measures import MEASURES, SCENE_MEASURES

    if measures is None:
        measures = MEASURES
    measures = list(measures)
    named = {m.name for m in measures}
    measures += [m for m in SCENE_MEASURES if m.name not in named]
    digest = hashlib.sha256()
    for name, path in _tap_bench_closure(LABEL_CODE).items():
        digest.update(name.encode() + b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    entries = []
    for m in measures:
        function = m.function
        module = getattr(function, "__module__", "") or ""
        entry = {f.name: _plain(getattr(m, f.name)) for f in dataclasses.fields(m)
                 if f.name != "function"}
        entry["function"] = f"{module}:{getattr(function, '__qualname__', repr(function))}"
        if module and module.split(".")[0] not in TRUSTED_PACKAGES:
            entry["code"] = code_digest(module)
        entries.append(entry)
    return {"labels_format": LABELS_FORMAT, "tap-bench": __version__,
            "code": digest.hexdigest(), "measures": entries,
            "versions": {pkg: _version(pkg) for pkg in ("numpy", "pandas", "numba",
                                                        "pyarrow")}}


ROAD_MAP = "highway-env road"
"""The ``map`` of a label key whose episode is labelled and measured along its scenario's
highway-env road (:func:`tap_bench.bench.run.tasks._road`)."""
SCENE_MAP = "recorded scene's lanes"
"""The ``map`` of a label key whose recorded (WOMD) scene is labelled and measured along the
lanes of its own map (:func:`tap_bench.bench.run.tasks._scene_lanes`)."""


def label_key(episode: str, thresholds: Mapping[str, Any], level: str,
              code: Mapping[str, Any], map_source: str | None = None
              ) -> tuple[str, dict[str, Any]]:
    """The key of an episode's labels and measures and the document it hashes: the
    episode's key, the thresholds (their JSON document), the level, :func:`label_code`,
    and the map the ego's path goes on along beyond its record (``map_source``:
    :data:`ROAD_MAP`, :data:`SCENE_MAP`, or None for the arc). The map itself needs no hash
    of its own: a highway-env road is built from the scenario and highway-env, a recorded
    scene's lanes are read from its record: the record's content hash and the code that
    builds or reads the map (:data:`SIMULATION_CODE`) are in the episode's key. The key says
    which map was used, so that labels made along an arc are never read for a run along a
    map."""
    doc = {"episode": episode, "thresholds": _plain(thresholds), "level": level,
           "code": dict(code), "map": map_source}
    return hashlib.sha256(_canonical(doc)).hexdigest(), doc


DERIVED_FORMAT = 1
"""Layout of a derived-output entry file; raised when it changes (old entries then miss)."""
DERIVED_KINDS = ("scores", "roads", "plots", "viewer", "runs")
"""The derived outputs kept (:func:`memoised`; ``runs``: whole run folders,
:mod:`tap_bench.bench.run.served`)."""
_PACKAGE_CODE: list[str] = []


def package_code() -> str:
    """The SHA-256 of every module of tap-bench (names and bytes), computed once a process:
    what a derived output is made by (an edit anywhere in the package makes them again)."""
    if not _PACKAGE_CODE:
        _PACKAGE_CODE.append(_package_digest())
    return _PACKAGE_CODE[0]


def package_code_holds() -> bool:
    """Whether tap-bench's modules still hash as :func:`package_code` found them (about 4 ms).

    The code in a derived entry's key is hashed when the run starts, but some of the code
    that makes the output is imported later (the report, the viewer): a module edited while
    the run went on would make the output with the new code under the old code's key, and
    a later run back on the old files would be served it. Such outputs are not kept (they
    are written; the next run makes them again under the new code's key)."""
    return not _PACKAGE_CODE or _package_digest() == _PACKAGE_CODE[0]


def _package_digest(package: Path | None = None) -> str:
    """SHA-256 of the names and bytes of every ``.py`` file under ``package`` (default:
    tap-bench's own folder)."""
    package = package or Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode() + b"\0")
        digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()


def table_digest(table: pd.DataFrame | None) -> str:
    """The SHA-256 of a table's content: column names and types, the index and every value
    bit for bit (numbers as their bytes, so -0.0 and 0.0 differ, NaN as one NaN whatever
    its payload; text through ``pd.util.hash_pandas_object``, 64 bits a cell, the same for
    an ``object`` and a ``str`` column of the same strings, as labelled and cached episodes
    give them; cells it cannot hash, such as lists, through the column's Parquet bytes).
    ``None`` and an empty table differ."""
    import numpy as np
    import pandas as pd

    if table is None:
        return "none"
    digest = hashlib.sha256()
    digest.update(_canonical([[str(c), _type_name(t)] for c, t in table.dtypes.items()]))
    digest.update(f"{len(table)} {type(table.index).__name__} "
                  f"{_type_name(table.index.dtype)}".encode())
    index = table.index.to_frame(index=False)
    columns = [*(index.iloc[:, k] for k in range(index.shape[1])),
               *(table.iloc[:, k] for k in range(table.shape[1]))]
    for column in columns:
        if isinstance(column.dtype, np.dtype) and column.dtype.kind in "biufcmM":
            values = np.ascontiguousarray(column.to_numpy())
            if values.dtype.kind in "fc":
                values = np.where(np.isnan(values), np.nan, values)  # one NaN
            digest.update(values.tobytes())
            continue
        try:
            digest.update(pd.util.hash_pandas_object(column, index=False).to_numpy().tobytes())
        except TypeError:  # unhashable cells (lists, dicts)
            buffer = io.BytesIO()
            column.to_frame("c").to_parquet(buffer, index=False)
            digest.update(buffer.getvalue())
    return digest.hexdigest()


def _type_name(dtype: Any) -> str:
    """A column type for :func:`table_digest`: ``text`` for object and string columns."""
    import numpy as np
    import pandas as pd

    text = isinstance(dtype, pd.StringDtype) or (isinstance(dtype, np.dtype) and dtype.kind == "O")
    return "text" if text else str(dtype)


def derived_key(kind: str, inputs: Mapping[str, Any]) -> tuple[str, dict[str, Any]]:
    """The key of a derived output of ``kind`` (one of :data:`DERIVED_KINDS`) and the
    document it hashes: ``inputs`` (table digests and settings, JSON), the code of the whole
    package (:func:`package_code`) and the versions of what computes and writes it."""
    if kind not in DERIVED_KINDS:
        raise ParameterError("kind", kind, f"one of {', '.join(DERIVED_KINDS)}")
    doc = {"derived": kind, "format": DERIVED_FORMAT, "tap-bench": __version__,
           "code": package_code(), "inputs": _plain(dict(inputs)),
           "versions": {pkg: _version(pkg) for pkg in ("numpy", "pandas", "pyarrow", "scipy")}}
    return hashlib.sha256(_canonical(doc)).hexdigest(), doc


def memoised(cache: EpisodeCache | None, kind: str, inputs: Mapping[str, Any] | None,
             build: Callable[[], T], encode: Callable[[T], Mapping[str, bytes]],
             decode: Callable[[dict[str, bytes]], T]) -> T:
    """``build()``, or what an earlier run stored for the same ``inputs`` (its key:
    :func:`derived_key`); a new result is stored (atomically). Without a cache or with
    ``inputs`` None (inputs that cannot be keyed) it is built every time.

    The built value is returned as ``decode(encode(value))``, as a stored one is, so that a
    run gives the same value whether the entry was there or not (a value ``encode`` cannot
    hold is returned as built, and not kept); an entry that fails its checks, or that
    ``decode`` refuses, is deleted and built again.
    """
    if cache is None or inputs is None:
        return build()
    key, doc = derived_key(kind, inputs)
    files, note = cache.read_derived(kind, key)
    if note is not None:
        note_refused(note)
    if files is not None:
        try:
            return decode(files)
        except Exception as err:  # whatever is wrong with it, it is made again
            with contextlib.suppress(OSError):
                cache.derived_path(kind, key).unlink()
            note_refused(f"derived entry {cache.derived_path(kind, key).name} refused and "
                         f"deleted: its files do not decode ({type(err).__name__}: "
                         f"{str(err)[:200]})")
    value = build()
    try:
        files = dict(encode(value))
        stored = decode(files)
    except Exception:  # a value these files cannot hold is not kept
        return value
    if not package_code_holds():  # edited while it was built: not made by the key's code
        return stored
    # the cache is a convenience: the run goes on without it (a full disk, a file name it
    # does not keep)
    with contextlib.suppress(OSError, ParameterError):
        cache.put_derived(kind, key, doc, files)
    return stored


_REFUSED: list[str] = []  # derived entries refused since the last run took them


def note_refused(note: str) -> None:
    """Say that a derived entry was refused (a :class:`~tap_bench.errors.CacheEntryWarning`)
    and keep the note for the run going on (:func:`take_refused`): a damaged entry is made
    again, never silently."""
    from tap_bench.errors import CacheEntryWarning

    _REFUSED.append(note)
    warnings.warn(f"{note}; it was made again.", CacheEntryWarning, stacklevel=3)


def take_refused() -> list[str]:
    """The derived entries refused in this process since the last call (their notes), for
    a run's ``summary.json`` (``cache.refused``)."""
    out = list(_REFUSED)
    del _REFUSED[:len(out)]
    return out


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
class Recalled:
    """What the cache holds for the episodes of a run, read in one pass
    (:meth:`EpisodeCache.recall`).

    Attributes:
        timings: what earlier runs measured (:meth:`EpisodeCache.timings`).
        labelled: episode index -> (its label entry's tables, its trajectories or None when
            not asked for), the episodes held whole, labels and measures included.
        seconds: episode index -> the wall time reading its entries took [s] (labelled
            ones).
        notes: episode index -> why an entry of it was refused (it was deleted).
        stored: per episode, whether it needs no rollout: held whole, or an episode entry
            file exists for its key (unverified until read).
    """

    timings: dict[str, Any]
    labelled: dict[int, tuple[dict[str, pd.DataFrame], pd.DataFrame | None]]
    seconds: dict[int, float]
    notes: dict[int, str]
    stored: list[bool]


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
        if (isinstance(self.max_bytes, bool) or not isinstance(self.max_bytes, int)
                or self.max_bytes < 0):
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
        return self.read(key)[0]

    def read(self, key: str) -> tuple[CachedEpisode | None, str | None]:
        """(the episode of ``key`` or None, why an entry there was refused or None).

        The whole entry is verified (module docstring): an entry that fails a check is
        deleted, so that the episode is simulated and stored again, and the reason comes
        back for the run's notes. A missing entry is (None, None)."""
        return _read_entry(self.path(key), lambda data: _decode(data, key), "cache entry")

    def put(self, key: str, doc: Mapping[str, Any], trajectories: pd.DataFrame,
            row: Mapping[str, Any], seconds: float,
            loaded: Mapping[str, Mapping[str, str]] | None = None) -> Path:
        """Store an episode under ``key`` (atomically; see the module docstring);
        ``loaded``: the user's modules loaded while it was made
        (:func:`tap_bench.usercode.loaded_user_code`), checked whenever it is read."""
        if hashlib.sha256(_canonical(doc)).hexdigest() != key:
            raise ParameterError("key", key, "the SHA-256 of doc (episode_key)")
        buffer = io.BytesIO()
        trajectories.to_parquet(buffer, index=False)
        payload = buffer.getvalue()
        header = {"format": "tap-bench-episode", "format_version": ENTRY_FORMAT, "key": key,
                  "doc": doc, "row": _plain_row(row), "seconds": float(seconds),
                  "loaded": _plain(dict(loaded or {})),
                  "payload_bytes": len(payload),
                  "payload_sha256": hashlib.sha256(payload).hexdigest(),
                  "created": time.strftime("%Y-%m-%d %H:%M:%S")}
        header["header_sha256"] = hashlib.sha256(_canonical(header)).hexdigest()
        return self._write(self.path(key), _canonical(header) + b"\n" + payload)

    # -- labels and measures of an episode, for re-runs that redo nothing -------------
    @property
    def labels_folder(self) -> Path:
        """Where the label entries are."""
        return self.root / "labels"

    def labels_path(self, key: str) -> Path:
        """The label entry file of ``key`` (a :func:`label_key`)."""
        if not _KEY.match(key):
            raise ParameterError("key", key, "64 lower-case hex digits (a SHA-256)")
        return self.labels_folder / key[:2] / f"{key}{_LABELS_SUFFIX}"

    def put_labels(self, key: str, doc: Mapping[str, Any],
                   tables: Mapping[str, pd.DataFrame],
                   loaded: Mapping[str, Mapping[str, str]] | None = None) -> Path:
        """Store an episode's labels and measures (``tables``: name -> table) under ``key``
        (a :func:`label_key` and its document), atomically, verified whole on read;
        ``loaded`` as for :meth:`put`."""
        if hashlib.sha256(_canonical(doc)).hexdigest() != key:
            raise ParameterError("key", key, "the SHA-256 of doc (label_key)")
        parts, index = [], []
        for name, table in tables.items():
            data = _arrow_bytes(table)
            parts.append(data)
            index.append({"name": str(name), "bytes": len(data),
                          "sha256": hashlib.sha256(data).hexdigest()})
        header = {"format": "tap-bench-labels", "format_version": LABELS_FORMAT, "key": key,
                  "doc": doc, "tables": index, "loaded": _plain(dict(loaded or {})),
                  "created": time.strftime("%Y-%m-%d %H:%M:%S")}
        header["header_sha256"] = hashlib.sha256(_canonical(header)).hexdigest()
        return self._write(self.labels_path(key), _canonical(header) + b"\n" + b"".join(parts))

    def read_labels(self, key: str) -> tuple[dict[str, pd.DataFrame] | None, str | None]:
        """(the tables stored under ``key`` or None, why an entry there was refused or
        None); a refused entry is deleted, as :meth:`read` does."""
        return _read_entry(self.labels_path(key), lambda data: _decode_labels(data, key),
                           "label entry")

    def recall(self, episodes: Sequence[tuple[str | None, str | None, bool]],
               tables: Sequence[str]) -> Recalled:
        """What the cache holds for a run's ``episodes``, read in one pass: each given as
        (its label key, its episode key, whether its trajectories are wanted), a None key
        for one that is not cached. An episode is held whole when its label entry holds
        every one of ``tables`` and, when wanted, its episode entry its trajectories; a
        refused entry is deleted and its note kept (:meth:`read`)."""
        labelled: dict[int, tuple[dict[str, pd.DataFrame], pd.DataFrame | None]] = {}
        seconds: dict[int, float] = {}
        notes: dict[int, str] = {}
        for i, (label, key, with_trajectories) in enumerate(episodes):
            if not label:
                continue
            t0 = time.perf_counter()
            found, note = self.read_labels(label)
            if found is not None and set(found) == set(tables):
                entry = None
                if with_trajectories and key:
                    entry, note = self.read(key)
                if entry is not None or not with_trajectories:
                    labelled[i] = (found, None if entry is None else entry.trajectories)
                    seconds[i] = time.perf_counter() - t0
                    continue
            if note is not None:
                notes[i] = note
        stored = [i in labelled or (key is not None and self.contains(key))
                  for i, (_, key, _) in enumerate(episodes)]
        return Recalled(self.timings(), labelled, seconds, notes, stored)

    @property
    def derived_folder(self) -> Path:
        """Where the derived outputs are (:func:`memoised`)."""
        return self.root / "derived"

    def derived_path(self, kind: str, key: str) -> Path:
        """The entry file of a derived output of ``kind`` under ``key``."""
        if not _KEY.match(key):
            raise ParameterError("key", key, "64 lower-case hex digits (a SHA-256)")
        if kind not in DERIVED_KINDS:
            raise ParameterError("kind", kind, f"one of {', '.join(DERIVED_KINDS)}")
        return self.derived_folder / kind / key[:2] / f"{key}{_DERIVED_SUFFIX}"

    def put_derived(self, kind: str, key: str, doc: Mapping[str, Any],
                    files: Mapping[str, bytes]) -> Path:
        """Store a derived output (``files``: name -> bytes) under ``key`` (a
        :func:`derived_key` and its document), atomically, verified whole on read."""
        if hashlib.sha256(_canonical(doc)).hexdigest() != key:
            raise ParameterError("key", key, "the SHA-256 of doc (derived_key)")
        index = []
        for name, data in files.items():
            if not _file_name_ok(str(name)):
                raise ParameterError("files", name, "a plain file name or relative path "
                                     "(letters, digits, '.', '_', '-' and '/'; parts of at "
                                     "most 200 characters, none '.' or '..')")
            index.append({"name": str(name), "bytes": len(data),
                          "sha256": hashlib.sha256(data).hexdigest()})
        header = {"format": "tap-bench-derived", "format_version": DERIVED_FORMAT,
                  "kind": kind, "key": key, "doc": doc, "files": index,
                  "created": time.strftime("%Y-%m-%d %H:%M:%S")}
        header["header_sha256"] = hashlib.sha256(_canonical(header)).hexdigest()
        return self._write(self.derived_path(kind, key),
                           _canonical(header) + b"\n" + b"".join(files.values()))

    def read_derived(self, kind: str, key: str) -> tuple[dict[str, bytes] | None, str | None]:
        """(the files stored under ``key`` or None, why an entry there was refused or None);
        a refused entry is deleted, as :meth:`read` does."""
        return _read_entry(self.derived_path(kind, key),
                           lambda data: _decode_derived(data, kind, key), "derived entry")

    def _write(self, path: Path, data: bytes) -> Path:
        """Write ``data`` to ``path`` atomically (a temporary file beside it, then a
        rename): a reader sees the old file or the whole new one, never a part."""
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:16]}.", suffix=".tmp",
                                   dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as stream:
                stream.write(data)
            os.replace(tmp, path)
        except BaseException:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            raise
        return path

    def _entries(self) -> Iterator[tuple[Path, os.stat_result]]:
        for folder, pattern in ((self.folder, f"*/*{_SUFFIX}"),
                                (self.labels_folder, f"*/*{_LABELS_SUFFIX}"),
                                (self.derived_folder, f"*/*/*{_DERIVED_SUFFIX}")):
            if not folder.is_dir():
                continue
            for path in folder.glob(pattern):
                with contextlib.suppress(OSError):
                    yield path, path.stat()

    def forget_written_since(self, since: float) -> int:
        """Delete the entries (episodes, labels, derived outputs) written at or after
        ``since`` (``time.time()`` seconds; their modification time: an entry only read
        since, made by an earlier run, stays); returns how many. For a run during which
        tap-bench itself was edited: its workers may have imported the new code after the
        keys named the old one (:func:`package_code_holds`). It costs only reuse."""
        removed = 0
        for path, st in list(self._entries()):
            if st.st_mtime >= since:
                with contextlib.suppress(OSError):
                    path.unlink()
                    removed += 1
        return removed

    def size(self) -> tuple[int, int]:
        """(episodes, bytes) in the cache: the bytes of its label entries included."""
        entries = list(self._entries())
        return (sum(path.suffix == _SUFFIX for path, _ in entries),
                sum(st.st_size for _, st in entries))

    def prune(self, max_bytes: int | None = None) -> PruneReport:
        """Delete least recently used entries until the cache holds at most ``max_bytes``
        (default :attr:`max_bytes`), and temporary files left by writers that died."""
        limit = self.max_bytes if max_bytes is None else max_bytes
        if isinstance(limit, bool) or not isinstance(limit, int) or limit < 0:
            raise ParameterError("max_bytes", limit, "an integer >= 0 (bytes)")
        now = time.time()
        for folder, pattern in ((self.folder, "*/.*.tmp"), (self.labels_folder, "*/.*.tmp"),
                                (self.derived_folder, "*/*/.*.tmp")):
            if not folder.is_dir():
                continue
            for tmp in folder.glob(pattern):
                with contextlib.suppress(OSError):
                    if now - tmp.stat().st_mtime > _STALE_TMP_S:
                        tmp.unlink()
        # least recently used first: written (mtime) or read (atime, set on each use)
        entries = sorted(self._entries(), key=lambda e: max(e[1].st_mtime, e[1].st_atime))
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
        self._write(self.timings_path, json.dumps(doc, indent=1, sort_keys=True).encode())


    def close_run(self, since: float, simulated: Mapping[str, float],
                  cached: Mapping[str, float], overhead: float) -> None:
        """After a run that began writing at ``since`` (``time.time()`` seconds): drop what
        it kept if tap-bench was edited while it ran (:meth:`forget_written_since`),
        record its timings for the next estimate (:meth:`record_timings`: mean seconds per
        episode by env, ``overhead`` [s]) and prune to the size bound. A cache that cannot
        be written costs only reuse: the run is written, the cache is a convenience."""
        if not package_code_holds():
            # tap-bench edited while the run went on: a worker may have imported the new
            # code (labelling, simulation) after the keys named the old, so what it kept
            # is dropped
            self.forget_written_since(since)
        with contextlib.suppress(OSError):
            self.record_timings(simulated, cached, overhead)
            self.prune()


def _read_entry(path: Path, decode: Callable[[bytes], T], what: str
                ) -> tuple[T | None, str | None]:
    """(the decoded entry at ``path`` or None, why an entry there was refused or None): a
    missing file is None without a reason; an entry ``decode`` refuses (or fails on) is
    deleted, so that it is made and stored again; a used entry's time is touched (the
    cache is pruned oldest first)."""
    try:
        data = path.read_bytes()
    except OSError:
        return None, None
    try:
        entry = decode(data)
    except _Stale:  # made with user code edited since: a miss (the new entry replaces it)
        return None, None
    except Exception as err:  # whatever is wrong, the entry is never used
        with contextlib.suppress(OSError):
            path.unlink()
        reason = (str(err) if isinstance(err, _Refused) else
                  f"unreadable ({type(err).__name__}: {str(err)[:200]})")
        return None, f"{what} {path.name} refused and deleted: {reason}"
    with contextlib.suppress(OSError):
        # used, not written: the access time says when it was last used (pruning), the
        # modification time stays when it was written (forget_written_since)
        os.utime(path, ns=(time.time_ns(), path.stat().st_mtime_ns))
    return entry, None


def _positive(value: Any) -> bool:
    return (isinstance(value, int | float) and not isinstance(value, bool)
            and math.isfinite(value) and value > 0)


class _Refused(ValueError):
    """An entry that fails a check of :func:`_decode`."""


class _Stale(Exception):
    """A whole entry made with a module of the user's code that has changed since (its
    ``loaded`` files): not damage, a miss."""


def _check_loaded(header: Mapping[str, Any]) -> None:
    """:class:`_Stale` when a module the entry's maker loaded has changed since (checked
    after the header's checksum); :class:`_Refused` when ``loaded`` is malformed."""
    try:
        holds = user_code_holds(header.get("loaded"))
    except ValueError as err:
        raise _Refused(str(err)) from None
    if not holds:
        raise _Stale


MAX_HEADER_BYTES = 1 << 20
"""The longest header line an entry may have [B] (a real one is about 2 kB)."""


def _plain_row(row: Mapping[str, Any]) -> dict[str, Any]:
    """An episode row with Python scalars (NumPy's as their Python value), as JSON keeps it."""
    return {str(k): v.item() if hasattr(v, "item") else v for k, v in row.items()}


def _split_entry(data: bytes, kind: str, version: int) -> tuple[dict, bytes]:
    """An entry's header (a JSON object of format ``kind`` at ``version``) and its payload;
    :class:`_Refused` naming the failed check."""
    line, sep, payload = data.partition(b"\n")
    if not sep or len(line) > MAX_HEADER_BYTES:
        raise _Refused("no header line (or one longer than 1 MiB)")
    try:
        header = json.loads(line)
    except (ValueError, RecursionError) as err:
        raise _Refused(f"the header is not JSON ({type(err).__name__})") from None
    if not isinstance(header, dict):
        raise _Refused(f"the header is a {type(header).__name__}, not an object")
    if header.get("format") != kind or header.get("format_version") != version:
        raise _Refused("another entry format")
    return header, payload


def _decode(data: bytes, key: str) -> CachedEpisode:
    """An entry's content, verified whole; :class:`_Refused` naming the failed check (other
    exceptions of a damaged payload are caught by the caller)."""
    import pandas as pd

    from tap_bench.sim.rollout import EPISODE_COLUMNS

    header, payload = _split_entry(data, "tap-bench-episode", ENTRY_FORMAT)
    types = {"key": str, "doc": dict, "row": dict, "seconds": int | float, "loaded": dict,
             "payload_bytes": int, "payload_sha256": str, "header_sha256": str}
    wrong = [name for name, kind in types.items() if not isinstance(header.get(name), kind)
             or isinstance(header.get(name), bool)]
    if wrong:
        raise _Refused(f"header field(s) {', '.join(wrong)} missing or of the wrong type")
    body = {k: v for k, v in header.items() if k != "header_sha256"}
    if hashlib.sha256(_canonical(body)).hexdigest() != header["header_sha256"]:
        raise _Refused("the header (episode row included) does not match its checksum")
    if header["key"] != key or hashlib.sha256(_canonical(header["doc"])).hexdigest() != key:
        raise _Refused("the entry belongs to another key")
    _check_loaded(header)
    if (not header["payload_bytes"] or len(payload) != header["payload_bytes"]
            or hashlib.sha256(payload).hexdigest() != header["payload_sha256"]):
        raise _Refused("the payload is empty or does not match its hash")
    row = header["row"]
    # recorded scenes add their columns to the row (tap_bench.sim.rollout.EPISODE_COLUMNS)
    if not set(EPISODE_COLUMNS) <= set(row) or row.get("status") != "ok":
        raise _Refused("not the row of a successful episode")
    if row.get("seed") != header["doc"].get("seed"):
        raise _Refused("the episode row's seed is not the key's")
    seconds = float(header["seconds"])
    if not math.isfinite(seconds) or seconds < 0:
        raise _Refused("the rollout time is not a finite number of seconds")
    trajectories = pd.read_parquet(io.BytesIO(payload))
    if (not len(trajectories) or "scenario_id" not in trajectories.columns
            or trajectories["scenario_id"].nunique() != 1):
        raise _Refused("the trajectory table is empty or not one episode's")
    return CachedEpisode(trajectories, row, seconds)


def _arrow_bytes(table: pd.DataFrame) -> bytes:
    """A table as an Arrow IPC stream (its pandas types kept, as Parquet keeps them; no
    index)."""
    import pyarrow as pa

    data = pa.Table.from_pandas(table, preserve_index=False)
    sink = pa.BufferOutputStream()
    with pa.ipc.new_stream(sink, data.schema) as writer:
        writer.write_table(data)
    return sink.getvalue().to_pybytes()


def _arrow_table(data: bytes) -> pd.DataFrame:
    """The table :func:`_arrow_bytes` wrote."""
    import pyarrow as pa

    return pa.ipc.open_stream(pa.BufferReader(data)).read_all().to_pandas()


def _decode_labels(data: bytes, key: str) -> dict[str, pd.DataFrame]:
    """A label entry's tables, verified whole; :class:`_Refused` naming the failed check."""
    header, payload = _split_entry(data, "tap-bench-labels", LABELS_FORMAT)
    if (not isinstance(header.get("doc"), dict) or not isinstance(header.get("tables"), list)
            or not isinstance(header.get("header_sha256"), str)):
        raise _Refused("header fields missing or of the wrong type")
    body = {k: v for k, v in header.items() if k != "header_sha256"}
    if hashlib.sha256(_canonical(body)).hexdigest() != header["header_sha256"]:
        raise _Refused("the header does not match its checksum")
    if header.get("key") != key or hashlib.sha256(_canonical(header["doc"])).hexdigest() != key:
        raise _Refused("the entry belongs to another key")
    _check_loaded(header)
    tables, at = {}, 0
    for part in header["tables"]:
        if (not isinstance(part, dict) or not isinstance(part.get("name"), str)
                or not isinstance(part.get("bytes"), int) or part["bytes"] <= 0):
            raise _Refused("a table of the header is malformed")
        data_part = payload[at:at + part["bytes"]]
        at += part["bytes"]
        if (len(data_part) != part["bytes"]
                or hashlib.sha256(data_part).hexdigest() != part.get("sha256")):
            raise _Refused(f"table {part['name']!r} does not match its hash")
        tables[part["name"]] = _arrow_table(data_part)
    if at != len(payload):
        raise _Refused("bytes after the last table")
    return tables


def _decode_derived(data: bytes, kind: str, key: str) -> dict[str, bytes]:
    """A derived entry's files, verified whole; :class:`_Refused` naming the failed check."""
    header, payload = _split_entry(data, "tap-bench-derived", DERIVED_FORMAT)
    if (not isinstance(header.get("doc"), dict) or not isinstance(header.get("files"), list)
            or not isinstance(header.get("header_sha256"), str)):
        raise _Refused("header fields missing or of the wrong type")
    body = {k: v for k, v in header.items() if k != "header_sha256"}
    if hashlib.sha256(_canonical(body)).hexdigest() != header["header_sha256"]:
        raise _Refused("the header does not match its checksum")
    if (header.get("kind") != kind or header.get("key") != key
            or hashlib.sha256(_canonical(header["doc"])).hexdigest() != key):
        raise _Refused("the entry belongs to another key")
    files, at = {}, 0
    for part in header["files"]:
        if (not isinstance(part, dict) or not isinstance(part.get("name"), str)
                or not _file_name_ok(part["name"]) or part["name"] in files
                or not isinstance(part.get("bytes"), int) or isinstance(part["bytes"], bool)
                or part["bytes"] < 0):
            raise _Refused("a file of the header is malformed")
        chunk = payload[at:at + part["bytes"]]
        at += part["bytes"]
        if len(chunk) != part["bytes"] or hashlib.sha256(chunk).hexdigest() != part.get("sha256"):
            raise _Refused(f"file {part['name']!r} does not match its hash")
        files[part["name"]] = chunk
    if at != len(payload):
        raise _Refused("bytes after the last file")
    return files
