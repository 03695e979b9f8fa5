"""Recording a highway-env episode as a trajectory table (SPEC section 1).

Every vehicle on the road is recorded at every simulated step (10 Hz), in Waymo's axes:
highway-env's y axis points to the driver's right, so y, vy and heading change sign on the
way in, and a left lane change becomes a positive yaw rate. Headings are wrapped to
(-pi, pi]. The ego vehicle has ``track_id`` ``"ego"`` and ``is_ego`` true; the others are
numbered ``"1"``, ``"2"`` ... in the order they first appear on the road.

Two optional columns record what the simulator knows and a data set does not: ``road``, the
road segment the vehicle is on (highway-env's lane index without the lane, ``"a>b"``), and
``lane``, the lane's number on it (highway-env counts from the left, 0 first). A change of
``lane`` on one road is a lane change: to the right when it grows. They are the truth
``benchmarks/bench_lane_change_merges.py`` checks TAP's merges against.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from tap_bench.trajectories import HZ

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["EGO_TRACK_ID", "TrajectoryRecorder", "flag_column", "scenario_id", "string_dtype",
           "text_column"]

EGO_TRACK_ID = "ego"
_TWO_PI = 2.0 * np.pi


def string_dtype() -> Any:
    """The dtype pandas gives a column of Python strings now (pandas 3: its Arrow-backed
    ``str``, unless its ``future.infer_string`` option is off; earlier: object)."""
    try:  # pandas' own switch, read without the option's deprecation warning
        from pandas._config import using_string_dtype
    except ImportError:  # a pandas without it: asked every time
        return _string_dtype.__wrapped__(None)
    return _string_dtype(bool(using_string_dtype()))


@functools.lru_cache(maxsize=4)
def _string_dtype(infer: bool | None) -> Any:
    """:func:`string_dtype` as pandas infers it, kept per state of its string inference
    (``infer``)."""
    import pandas as pd

    return pd.Series(np.array(["a"], dtype=object)).dtype


def text_column(labels: Sequence[str], codes: np.ndarray, *, dtype: Any = None) -> Any:
    """A table column of strings, ``labels[codes]``, in the dtype pandas gives a column of
    Python strings (pandas 3: its Arrow-backed ``str``; earlier: object), built from the few
    labels without a Python string per row.

    Args:
        labels: (k,) the distinct strings (a list, or a numpy or pandas array of them).
        codes: (n,) int in 0 .. k - 1, indices into ``labels``.
        dtype: :func:`string_dtype`, when the caller has asked for it already (building
            several columns); None: asked here.

    Returns:
        (n,) an array a DataFrame takes as the column as it is (no conversion); with no
        rows, an empty object array (the dtype pandas gives an empty column of objects).
    """
    import pandas as pd

    if dtype is None:
        dtype = string_dtype()
    if dtype == np.dtype(object) or not len(codes):  # pandas infers nothing from none
        words = np.empty(len(labels), dtype=object)
        words[:] = [str(label) for label in labels]
        return words[codes]
    codes = np.asarray(codes, dtype=np.intp)
    if getattr(dtype, "storage", None) in ("pyarrow", "pyarrow_numpy"):
        return pd.array(_arrow_strings(labels, codes), dtype=dtype)
    words = np.empty(len(labels), dtype=object)
    words[:] = [str(label) for label in labels]
    return pd.array(words, dtype=dtype).take(codes)


def _arrow_strings(labels: Sequence[str], codes: np.ndarray) -> Any:
    """``labels[codes]`` as an Arrow ``large_string`` array: one label's bytes repeated
    (its offsets a multiple of its length), or Arrow's take of the labels."""
    import pandas as pd
    import pyarrow as pa
    import pyarrow.compute as pc

    if len(labels) == 1 and not codes.any():
        word = str(labels[0]).encode()
        n = len(codes)
        offsets = np.arange(n + 1, dtype=np.int64) * len(word)
        return pa.LargeStringArray.from_buffers(n, pa.py_buffer(offsets),
                                                pa.py_buffer(word * n))
    words = None
    if ((isinstance(labels, np.ndarray) and labels.dtype.kind == "U")
            or (isinstance(labels, pd.api.extensions.ExtensionArray)
                and pd.api.types.is_string_dtype(labels.dtype))):  # strings as they are
        words = pa.array(labels, pa.large_string())
    if words is None or words.null_count:
        words = pa.array([str(label) for label in labels], pa.large_string())
    return pc.take(words, pa.array(codes))


def flag_column(values: np.ndarray, missing: np.ndarray | None = None) -> Any:
    """A nullable boolean table column (pandas ``boolean``) of ``values`` (n,) bool, NA
    where ``missing`` (n,) bool is true (None: nowhere)."""
    import pandas as pd

    values = np.asarray(values, dtype=bool)
    mask = (np.zeros(len(values), dtype=bool) if missing is None else
        np.asarray(missing, dtype=bool))
    return pd.arrays.BooleanArray(np.where(mask, False, values), mask.copy())


def scenario_id(env: str, seed: int | None, episode: int = 0, policy: str | None = None) -> str:
    """The ``scenario_id`` of an episode: ``highway/idm/s3``, ``highway/s3`` without a policy,
    ``highway/s3/e2`` for the third episode after seeding with 3, ``highway/unseeded/e0``."""
    parts = [env] + ([policy] if policy else [])
    parts.append(f"s{seed}" if seed is not None else "unseeded")
    if episode or seed is None:
        parts.append(f"e{episode}")
    return "/".join(parts)


class TrajectoryRecorder:
    """Collects the vehicles of one episode, step by step, and builds its trajectory table.

    Call :meth:`start` at reset, :meth:`frame` after every simulated step (and once at the
    reset state), then :meth:`table`. With ``record=False`` it only keeps track of which
    vehicles it has seen (the scenario env needs that to set up new vehicles) and
    :meth:`table` is empty.
    """

    def __init__(self, *, record: bool = True) -> None:
        self.record = record
        self.env = ""
        self.seed: int | None = None
        self.episode = 0
        self._reset_buffers()

    def _reset_buffers(self) -> None:
        # A reference to every vehicle seen keeps id() unique for the whole episode.
        self._seen: dict[int, tuple[int, object]] = {}
        self._n_others = 0
        self._rows: list[tuple] = []

    def start(self, env: str, seed: int | None, episode: int) -> None:
        """Begin a new episode of ``env`` (a scenario name) reset with ``seed``."""
        self.env, self.seed, self.episode = env, seed, episode
        self._reset_buffers()

    @property
    def n_rows(self) -> int:
        """Rows recorded so far in this episode."""
        return len(self._rows)

    def frame(self, step: int, vehicles: Iterable[object], ego: object) -> list[object]:
        """Record the state after simulated step ``step`` (0 is the reset state).

        Args:
            step: simulated steps since reset; t = step * 0.1 s.
            vehicles: the road's vehicles (``env.unwrapped.road.vehicles``).
            ego: the controlled vehicle (``env.unwrapped.vehicle``).

        Returns:
            the vehicles seen for the first time, in road order.
        """
        new = []
        seen = self._seen
        rows = self._rows
        for vehicle in vehicles:
            key = id(vehicle)
            entry = seen.get(key)
            if entry is None:
                if vehicle is ego:
                    entry = (0, vehicle)
                else:
                    self._n_others += 1
                    entry = (self._n_others, vehicle)
                seen[key] = entry
                new.append(vehicle)
            if not self.record:
                continue
            code = 0 if vehicle is ego else entry[0]
            x, y = vehicle.position
            speed = vehicle.speed
            heading = vehicle.heading
            road_from, road_to, lane = vehicle.lane_index
            rows.append((step, code, x, y, heading, speed, vehicle.crashed,
                         f"{road_from}>{road_to}", lane))
        return new

    def table(self, **columns: object) -> pd.DataFrame:
        """The episode's trajectory table, ordered by track (ego first) and time.

        Args:
            **columns: constant columns to add (``policy="idm"``).
        """
        import pandas as pd

        names = ("step", "code", "x", "y", "heading", "speed", "crashed", "road", "lane")
        if not self._rows:
            data = {n: np.empty(0) for n in names}
        else:
            cols = list(zip(*self._rows, strict=True))
            data = {n: np.asarray(c) for n, c in zip(names, cols, strict=True)}
        step = data["step"].astype(np.int64)
        code = data["code"].astype(np.int64)
        order = np.lexsort((step, code))
        step, code = step[order], code[order]
        x = data["x"].astype(np.float64)[order]
        y = -data["y"].astype(np.float64)[order]
        heading = -data["heading"].astype(np.float64)[order]
        speed = data["speed"].astype(np.float64)[order]
        crashed = data["crashed"].astype(bool)[order]
        road = data["road"].astype(object)[order]
        lane = data["lane"].astype(np.int64)[order]
        track_names = np.array([EGO_TRACK_ID] + [str(i) for i in range(1, self._n_others + 1)],
                               dtype=object)
        policy = columns.pop("policy", None)
        n = len(step)
        seed = pd.array(np.full(n, 0 if self.seed is None else self.seed), dtype="Int64")
        if self.seed is None:
            seed[:] = pd.NA
        data = {
            "scenario_id": np.full(n, scenario_id(self.env, self.seed, self.episode, policy),
                                   dtype=object),
            "track_id": track_names[code] if n else np.empty(0, dtype=object),
            "t": step / HZ,
            "x": x,
            "y": y,
            # wrapped to (-pi, pi]: highway-env lets headings grow around a roundabout
            "heading": np.pi - np.mod(np.pi - heading, _TWO_PI),
            "speed": np.abs(speed),
            "valid": np.ones(n, dtype=bool),
            "vx": speed * np.cos(heading),
            "vy": speed * np.sin(heading),
            "object_type": np.full(n, "vehicle", dtype=object),
            "is_ego": code == 0,
            "source": np.full(n, "highway-env", dtype=object),
            "env": np.full(n, self.env, dtype=object),
            **({"policy": np.full(n, policy, dtype=object)} if policy is not None else {}),
            "seed": seed,
            "episode": np.full(n, self.episode, dtype=np.int64),
            "crashed": crashed,
            "road": road,
            "lane": lane,
            **{name: np.full(n, value, dtype=object) for name, value in columns.items()},
        }
        return pd.DataFrame(data, copy=False)
