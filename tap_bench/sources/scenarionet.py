"""ScenarioNet scenario pickles to the trajectory table, loaded without trusting them.

ScenarioNet (metadriverse/scenarionet) converts WOMD, nuPlan, nuScenes, Argoverse 2 and
others into one "scenario description": a pickled dict of numpy arrays. Unpickling a file
from elsewhere can run any code it names, so :class:`RestrictedUnpickler` resolves only
numpy's array reconstruction, plain containers and scalars, and refuses everything else.

Per track, ``state.position`` (T, 2 or 3) gives x, y; ``state.heading`` (T,), ``state.velocity``
(T, 2) and ``state.valid`` (T,); ``metadata.ts`` (T,) gives ``t``. ``source`` is ``womd`` for
ScenarioNet's ``waymo`` data set and the data set's own name otherwise.
"""

from __future__ import annotations

import io
import os
import pickle
from pathlib import Path

import numpy as np
import pyarrow as pa

from tap_bench.errors import WomdRecordError
from tap_bench.womd.scenario import trajectory_table

__all__ = ["RestrictedUnpickler", "decode_scenarionet", "load_scenarionet"]

_ALLOWED = {
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy", "ndarray"), ("numpy", "dtype"),
    ("collections", "defaultdict"), ("collections", "OrderedDict"),
    ("builtins", "int"), ("builtins", "float"), ("builtins", "str"), ("builtins", "bool"),
    ("builtins", "list"), ("builtins", "dict"), ("builtins", "set"), ("builtins", "tuple"),
    ("builtins", "frozenset"), ("builtins", "bytes"), ("builtins", "complex"),
}
"""(module, name) pairs a ScenarioNet pickle may refer to: numpy arrays, dtypes and
scalars, plain containers (``defaultdict`` with a built-in type as its factory)."""
_TYPES = {"VEHICLE": "vehicle", "PEDESTRIAN": "pedestrian", "CYCLIST": "cyclist"}
_SOURCES = {"waymo": "womd"}


class RestrictedUnpickler(pickle.Unpickler):
    """An unpickler that builds numpy arrays and plain containers, and nothing else."""

    def find_class(self, module: str, name: str) -> object:
        if (module, name) in _ALLOWED:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(
            f"refused to load {module}.{name}: a ScenarioNet scenario holds only numpy "
            "arrays and plain containers")


def load_scenarionet(path: str | os.PathLike) -> dict:
    """Load a ScenarioNet pickle with :class:`RestrictedUnpickler`.

    Raises:
        WomdRecordError: the file cannot be unpickled or names a class outside numpy
            arrays and plain containers (record 0, byte offset 0: a pickle is one record).
    """
    data = Path(path).read_bytes()
    try:
        scenario = RestrictedUnpickler(io.BytesIO(data)).load()
    except Exception as err:  # any unpickling failure is a bad file
        raise WomdRecordError(
            str(path), 0, 0, f"cannot be loaded as a ScenarioNet scenario pickle: {err}",
            "Only ScenarioNet scenario files (sd_*.pkl) are read; they must hold nothing "
            "but numpy arrays and plain containers.") from None
    return scenario


def decode_scenarionet(scenario: dict, *, path: str = "<scenario>",
                       object_types: frozenset[str] | None = None) -> pa.Table:
    """Convert a ScenarioNet scenario description into a trajectory table.

    Args:
        scenario: the unpickled scenario (see :func:`load_scenarionet`).
        path: the file it came from, for error messages.
        object_types: keep only tracks of these types (None keeps all).

    Returns:
        A table with the columns of :data:`tap_bench.womd.scenario.SCENARIO_COLUMNS`, one
        row per track per step (tracks in the file's order).

    Raises:
        WomdRecordError: the scenario does not have ScenarioNet's structure (a list where a
            dict belongs, a missing key, arrays of the wrong length, text where numbers
            belong), naming the key or the track.
    """
    def fail(problem: str) -> WomdRecordError:
        return WomdRecordError(path, 0, 0, problem, "Is it a ScenarioNet scenario file "
                               "(sd_*.pkl, not dataset_summary.pkl or dataset_mapping.pkl)?")

    if not isinstance(scenario, dict) or "tracks" not in scenario or "metadata" not in scenario:
        raise fail("not a ScenarioNet scenario: a dict with 'tracks' and 'metadata' expected")
    meta, tracks = scenario["metadata"], scenario["tracks"]
    for key, value in (("metadata", meta), ("tracks", tracks)):
        if not isinstance(value, dict):
            raise fail(f"{key!r} is a {type(value).__name__}, where a dict belongs")
    if "ts" not in meta:
        raise fail("metadata has no 'ts' (time stamps)")
    try:
        times = np.asarray(meta["ts"], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as err:
        raise fail(f"metadata 'ts' is not a list of numbers ({err})") from None
    n_steps = len(times)
    if n_steps == 0:
        raise fail("metadata 'ts' is empty: the scenario has no time steps")
    scenario_id = str(meta.get("scenario_id", scenario.get("id", Path(path).stem)))
    if not scenario_id:
        raise fail("metadata 'scenario_id' is empty: every scenario needs its id, or it "
                   "would be merged with others")
    source = _SOURCES.get(str(meta.get("dataset", "")), str(meta.get("dataset", "scenarionet")))
    sdc = str(meta.get("sdc_id", ""))
    try:
        interest = {str(i) for i in meta.get("objects_of_interest", []) or []}
        predict = meta.get("tracks_to_predict", {}) or {}
        predict = {str(k): int((v or {}).get("difficulty", 0) or 0) for k, v in predict.items()}
    except (AttributeError, TypeError, ValueError) as err:
        raise fail(f"metadata 'objects_of_interest' or 'tracks_to_predict' is malformed "
                   f"({type(err).__name__}: {err})") from None

    ids, types, parts = [], [], {k: [] for k in ("x", "y", "z", "heading", "vx", "vy", "valid",
                                                  "length", "width", "height")}
    for track_id, track in tracks.items():
        state = track.get("state", {}) if isinstance(track, dict) else None
        if not isinstance(state, dict):
            raise fail(f"track {track_id}: {'its state' if state is not None else 'it'} is "
                       f"a {type(state if state is not None else track).__name__}, where a "
                       "dict belongs")
        kind = _TYPES.get(str(track.get("type", "")).upper(), "other")
        if object_types is not None and kind not in object_types:
            continue
        try:
            position = np.asarray(state["position"], dtype=np.float64).reshape(n_steps, -1)
            velocity = np.asarray(state["velocity"], dtype=np.float64).reshape(n_steps, 2)
            heading = np.asarray(state["heading"], dtype=np.float64).reshape(n_steps)
            valid = np.asarray(state["valid"]).astype(bool).reshape(n_steps)
            sizes = {key: np.full(n_steps, np.nan) if state.get(key) is None else
                     np.asarray(state[key], dtype=np.float64).reshape(n_steps, -1)[:, 0]
                     for key in ("length", "width", "height")}
            if position.shape[1] < 2:
                raise ValueError(f"position has {position.shape[1]} coordinate(s), not 2 or 3")
        except KeyError as err:
            raise fail(f"track {track_id}: state has no {err}") from None
        except (TypeError, ValueError, IndexError) as err:
            raise fail(f"track {track_id}: state arrays are not numbers of {n_steps} steps "
                       f"({type(err).__name__}: {err})") from None
        ids.append(str(track_id))
        types.append(kind)
        parts["x"].append(position[:, 0])
        parts["y"].append(position[:, 1])
        parts["z"].append(position[:, 2] if position.shape[1] > 2 else np.zeros(n_steps))
        parts["heading"].append(heading)
        parts["vx"].append(velocity[:, 0])
        parts["vy"].append(velocity[:, 1])
        parts["valid"].append(valid)
        for key, values in sizes.items():
            parts[key].append(values)
    states = {k: (np.concatenate(v) if v else np.zeros(0, dtype=bool if k == "valid"
                                                       else np.float64))
              for k, v in parts.items()}
    ids_arr = np.array(ids, dtype=object)
    return trajectory_table(
        scenario_id, times, ids, types, states, is_ego=ids_arr == sdc,
        object_of_interest=np.isin(ids_arr, list(interest)),
        track_to_predict=np.isin(ids_arr, list(predict)),
        prediction_difficulty=np.array([predict.get(i, 0) for i in ids], dtype=np.int8),
        source=source)
