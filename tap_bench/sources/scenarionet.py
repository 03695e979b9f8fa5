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
from tap_bench.womd.scenario import BOX_SIZE_FIX, bad_box_size, trajectory_table

__all__ = ["ALLOCATION_SLACK", "RestrictedUnpickler", "decode_scenarionet", "load_scenarionet"]

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


ALLOCATION_SLACK = 64 << 20
"""Bytes an unpickled scenario may allocate beyond its file's size [B] (its arrays' data is
in the file, so a real one needs about the file's size)."""


class _UnpickledArray(np.ndarray):
    """An array being unpickled by :class:`RestrictedUnpickler`: the state numpy would read
    (its shape, type and data) is checked first, since numpy trusts it (an object array of
    a large shape and a short list crashes the interpreter). ``np.asarray`` gives the plain
    array."""

    def __setstate__(self, state: object) -> None:
        unpickler = getattr(self, "unpickler", None)
        if not isinstance(state, tuple) or len(state) not in (4, 5):
            raise pickle.UnpicklingError("an array's state is not numpy's")
        shape, dtype, _, raw = state[-4:]
        if not isinstance(dtype, np.dtype):
            raise pickle.UnpicklingError("an array's state names no numpy dtype")
        if unpickler is None:
            raise pickle.UnpicklingError("an array made outside the restricted unpickler")
        unpickler._array_bytes(shape, dtype, "an array")
        count = 1
        for d in shape:
            count *= d
        if dtype.hasobject:
            if not isinstance(raw, list) or len(raw) != count:
                raise pickle.UnpicklingError(f"an object array of {count} items holds a "
                                             "list of another length")
        elif not isinstance(raw, bytes) or len(raw) != count * dtype.itemsize:
            raise pickle.UnpicklingError(f"an array of {count * dtype.itemsize} bytes holds "
                                         "data of another size")
        np.ndarray.__setstate__(self, state)
        del self.unpickler  # checked: the array no longer holds the unpickler (and its file)


class RestrictedUnpickler(pickle.Unpickler):
    """An unpickler that builds numpy arrays and plain containers, and nothing else, and
    that checks every allocation a call of the pickle asks for (an array's shape and item
    size, ``bytes(n)``, a scalar's item size) against a budget before anything is
    allocated: a pickle of a few kB cannot make it take GBs.

    Args:
        file: the pickle's stream.
        max_bytes: the budget [B] (default: :data:`ALLOCATION_SLACK`).
    """

    def __init__(self, file: io.BufferedIOBase, *, max_bytes: int = ALLOCATION_SLACK) -> None:
        super().__init__(file)
        self._left = max_bytes
        self._budget = max_bytes

        def ndarray(shape: object = (), dtype: object = float, *args: object,
                    **kwargs: object) -> object:
            self._array_bytes(shape, dtype, "an array")
            return np.ndarray(shape, dtype, *args, **kwargs)

        self._ndarray = ndarray

    def _charge(self, n_bytes: int, what: str) -> None:
        if n_bytes > self._left:
            raise pickle.UnpicklingError(
                f"{what} would allocate {n_bytes:,} bytes, beyond the {self._budget:,} bytes "
                "a scenario of this file's size may take (its arrays' data is in the file)")
        self._left -= n_bytes

    def _array_bytes(self, shape: object, dtype: object, what: str) -> None:
        dims = shape if isinstance(shape, tuple | list) else (shape,)
        if not all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in dims):
            raise pickle.UnpicklingError(f"{what}: shape {str(shape)[:80]} is not a list of "
                                         "non-negative integers")
        try:
            itemsize = np.dtype(dtype).itemsize if dtype is not None else 8
        except (TypeError, ValueError):
            itemsize = 1  # numpy refuses the dtype itself
        total = max(itemsize, 1)
        for d in dims:
            total *= d
            if total > self._left:
                break
        self._charge(total, what)

    def find_class(self, module: str, name: str) -> object:
        if (module, name) not in _ALLOWED:
            raise pickle.UnpicklingError(
                f"refused to load {module}.{name}: a ScenarioNet scenario holds only numpy "
                "arrays and plain containers")
        target = super().find_class(module, name)
        if name == "_reconstruct":
            def reconstruct(subtype: object, shape: object, dtype: object) -> object:
                self._array_bytes(shape, dtype if not isinstance(dtype, bytes) else "b",
                                  "an array")
                if subtype is not self._ndarray and subtype is not np.ndarray:
                    raise pickle.UnpicklingError("an array of another class")
                array = target(_UnpickledArray, shape, dtype)
                array.unpickler = self  # its state is checked against this budget
                return array
            return reconstruct
        if (module, name) == ("numpy", "ndarray"):
            return self._ndarray  # called: checked; as _reconstruct's class: numpy's
        if name == "scalar":
            def scalar(dtype: object, *args: object) -> object:
                self._array_bytes((), dtype, "a scalar")
                return target(dtype, *args)
            return scalar
        if (module, name) in (("builtins", "bytes"), ("builtins", "str"),
                              ("builtins", "list"), ("builtins", "tuple")):
            def sized(*args: object, **kwargs: object) -> object:
                if args and isinstance(args[0], int) and not isinstance(args[0], bool):
                    self._charge(args[0], f"{name}({args[0]})")
                return target(*args, **kwargs)
            return sized
        return target


def load_scenarionet(path: str | os.PathLike) -> dict:
    """Load a ScenarioNet pickle with :class:`RestrictedUnpickler`.

    Raises:
        WomdRecordError: the file cannot be unpickled or names a class outside numpy
            arrays and plain containers (record 0, byte offset 0: a pickle is one record).
    """
    data = Path(path).read_bytes()
    unpickler = RestrictedUnpickler(io.BytesIO(data), max_bytes=len(data) + ALLOCATION_SLACK)
    try:
        scenario = unpickler.load()
    except Exception as err:  # any unpickling failure is a bad file
        raise WomdRecordError(
            str(path), 0, 0, f"cannot be loaded as a ScenarioNet scenario pickle: {err}",
            "Only ScenarioNet scenario files (sd_*.pkl) are read; they must hold nothing "
            "but numpy arrays and plain containers.") from None
    finally:
        # its memo holds everything it made and its checks' functions hold it: a cycle
        # that would keep the scenario and the file's bytes until a full collection
        unpickler.memo.clear()
        unpickler.__dict__.clear()
    return scenario



def _sized(value: np.ndarray | list | tuple) -> bool:
    """Whether a state value holds anything: an empty one (``()`` is one object in Python,
    shared by every track that has it) costs nothing however often a pickle names it."""
    return bool(value.size if isinstance(value, np.ndarray) else len(value))

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
    owner: dict[int, str] = {}  # id of each state array -> the track that holds it
    for track_id, track in tracks.items():
        state = track.get("state", {}) if isinstance(track, dict) else None
        if not isinstance(state, dict):
            raise fail(f"track {track_id}: {'its state' if state is not None else 'it'} is "
                       f"a {type(state if state is not None else track).__name__}, where a "
                       "dict belongs")
        # a pickle names an object many times at the cost of one: a state array shared by
        # tracks would be copied once per track, unbounded by the file's size
        for key, value in state.items():
            if (isinstance(value, np.ndarray | list | tuple) and _sized(value) and
                    owner.setdefault(id(value), str(track_id)) != str(track_id)):
                raise fail(f"track {track_id}: its state {str(key)[:40]!r} is the same "
                           f"object as track {owner[id(value)]}'s (a pickle that names one "
                           "array for several tracks, which a ScenarioNet file never does)")
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
        given = [key for key in sizes if state.get(key) is not None]  # absent: unknown
        problem = bad_box_size([str(track_id)], n_steps, {"valid": valid, **sizes}, given)
        if problem is not None:
            raise WomdRecordError(path, 0, 0, problem, BOX_SIZE_FIX)
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
