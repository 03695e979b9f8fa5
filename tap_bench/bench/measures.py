"""Safety and efficiency measures of the ego vehicle, one row per episode (scenario).

Every measure is one entry of the registry :data:`MEASURES`: a name (the column of the
measures table), its unit, which direction is better, the default margin of the regression
gate and a function of the ego's steps (:class:`EgoSteps`) giving one value per episode.
Adding a measure is one function and one :func:`register_measure` decorator::

    @register_measure("max_decel", unit="m/s^2", higher_is_better=True, margin=0.5,
                      description="hardest braking of the ego (most negative acceleration)")
    def max_decel(steps: EgoSteps) -> np.ndarray:
        return steps.minimum(steps.accel)

The registry refuses a name registered twice and a measure without a margin: a measure the
gate cannot check is an error, never silently ungated.

The built-in measures:

==================  ======  ================================================================
column              unit    what
==================  ======  ================================================================
``crashed``         bool    the ego collided (any ego row with ``crashed`` true)
``mean_speed``      m/s     mean ego speed over its valid steps
``min_headway_s``   s       smallest time headway to the leader: bumper gap / ego speed,
                            over scored steps with a leader and ego speed >= 1 m/s; capped
                            at :data:`HEADWAY_CAP_S`; NaN without a leader
``min_ttc_s``       s       smallest time to collision with the leader: gap / closing speed
                            over scored steps with a leader where the ego closes in; capped
                            at :data:`TTC_CAP_S` (a leader never closed in on gives the cap);
                            NaN without a leader
``rms_jerk``        m/s^3   root mean square of the ego's longitudinal jerk: the second
                            derivative of the Savitzky-Golay smoothed speed
                            (:data:`JERK_WINDOW_S`, order :data:`JERK_POLYORDER`)
==================  ======  ================================================================

and ``duration_s`` (s), the time the ego was recorded, beside them.

**Along the ego's path** (SPEC sections 6 and 7). The leader at a step is the nearest other
road user ahead on the ego's own path, within its reach (:func:`~tap_bench.pathframe.
leader_reach`: 60 m, or 4 s at the ego's speed where that is farther; SPEC 7's range),
inside its corridor (``|d| <=`` :data:`~tap_bench.pathframe.CORRIDOR_HALF_WIDTH`) and
driving along it (heading within :data:`~tap_bench.pathframe.SAME_DIRECTION` of the path),
on straight roads, curves, merges, roundabouts and intersections alike: the agent the
interaction axis says the ego is Following (one rule, :func:`~tap_bench.pathframe.
nearest_leader`, for both). A headway is then at most max(60 m / v, 4 s) less the bumper
lengths: a car farther ahead is free driving, not a leader. The gap is ``s`` less half of
each vehicle's length (the ``length`` column where the table has one, else
:data:`VEHICLE_LENGTH`); the closing speed is the ego's speed less the leader's velocity
along the path.

**Collisions and the burn-in.** A step at which the ego is crashed has a TTC and a headway of
0, so a crashed episode can never look safer than one without a conflict. The first
:data:`BURN_IN_S` of an episode are not scored (the scenario sets those gaps, not the
policy), except a conflict that leads to a crash: the run of steps, ending at the crash,
in which the ego closes in on a leader is always scored.

**No leader is not an observation.** An episode with no leader on any scored step (after
the burn-in; or, for the headway, none while the ego moved at 1 m/s or more) has no minimum
headway and no minimum TTC: NaN, never the 10 s cap (a 10 s "no leader" value averaged in
turned aggressive IDM's lower headways into a higher mean). Means and intervals are taken
over the episodes that have one, and the episodes without are counted
(:func:`leader_counts`; the benchmark's measures table has ``n_missing``). A leader that
the ego never closes in on still gives a TTC: the cap.

**Jerk.** Differentiating a 10 Hz speed twice amplifies its noise 100-fold (dt^-2): by
second differences a smooth real drive shows several times the RMS jerk it has after 0.5 s
of smoothing (docs/benchmark.md). As nuPlan's comfort metrics do (``ego_jerk``: a
Savitzky-Golay filter before each derivative), the acceleration is the Savitzky-Golay
derivative of the speed and the jerk the Savitzky-Golay derivative of that acceleration,
each a fit of order :data:`JERK_POLYORDER` over :data:`JERK_WINDOW_S` (nuPlan's 15 steps
and order 2 at its 10 Hz), over each run of consecutive steps (a run shorter than the
window gives no jerk).
nuPlan's comfort bound is |longitudinal jerk| <= :data:`JERK_COMFORT_BOUND` m/s^3
(``max_abs_lon_jerk``); the RMS here is a mean over time, so compare it with the bound as a
typical, not a peak, value.

Surrounding vehicles are only known where the table records them (highway-env rollouts
record every vehicle; WOMD every tracked agent): without any, headway and TTC are NaN.
Beyond the end of the ego's record the path goes on along its lane (``map_table``) or along
an arc of its last curvature (:mod:`tap_bench.pathframe`): a leader stopped ahead on a curve
is found as on a straight road.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from typing import TYPE_CHECKING, Any

from tap_bench.errors import RegistrationError, TrajectoryTableError
from tap_bench.pathframe import (
    CORRIDOR_HALF_WIDTH,
    LEADER_RANGE_M,
    LaneMap,
    Paths,
    leader_reach,
    nearest_leader,
    path_frame,
    scene_lanes,
)
from tap_bench.registry import Registry
from tap_bench.trajectories import HZ

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd

__all__ = [
    "BURN_IN_S",
    "CONTEXT_REDUCTIONS",
    "HEADWAY_CAP_S",
    "JERK_COMFORT_BOUND",
    "JERK_POLYORDER",
    "JERK_WINDOW_S",
    "LOOKAHEAD",
    "MEASURES",
    "MEASURE_KINDS",
    "MEASURE_ROLES",
    "SCENE_MEASURES",
    "SCENE_STANDS_IN",
    "SCENE_STEP_COLUMNS",
    "MIN_SPEED_FOR_HEADWAY",
    "TTC_CAP_S",
    "VEHICLE_LENGTH",
    "EgoSteps",
    "Measure",
    "MeasureRegistry",
    "ego_measures",
    "ego_step_measures",
    "check_measure",
    "ego_steps",
    "leader_counts",
    "measure_entry",
    "measures_with_role",
    "register_measure",
    "run_measures",
    "savgol_derivative",
    "smoothed_jerk",
]

VEHICLE_LENGTH = 5.0  # [m] highway-env's vehicle length, used where no `length` column is
LOOKAHEAD = LEADER_RANGE_M
"""[m] kept for old imports: the leader's reach is :func:`tap_bench.pathframe.leader_reach`,
``LEADER_RANGE_M`` or ``LEADER_RANGE_S`` at the ego's speed, whichever is farther (it was a
flat 100 m)."""
MIN_SPEED_FOR_HEADWAY = 1.0  # [m/s] below this a time headway is not meaningful
HEADWAY_CAP_S = 10.0  # [s] headways above this count as free driving
BURN_IN_S = 2.0  # [s] headway and TTC skip the first steps: the scenario sets those gaps
TTC_CAP_S = 10.0  # [s] times to collision above this count as no conflict
JERK_WINDOW_S = 1.5
"""[s] the Savitzky-Golay window of the jerk: 15 steps at 10 Hz, nuPlan's ``window_length``
of its comfort metrics (``extract_ego_jerk``) at its 10 Hz simulation rate."""
JERK_WINDOW_STEPS = round(JERK_WINDOW_S * HZ)
JERK_POLYORDER = 2
"""The polynomial order of the Savitzky-Golay fit (nuPlan's: 2)."""
JERK_COMFORT_BOUND = 4.13
"""[m/s^3] nuPlan's comfort bound on the ego's longitudinal |jerk| (``max_abs_lon_jerk``;
its bound on the magnitude, ``max_abs_mag_jerk``, is 8.37)."""

_KEEP = ("env", "policy", "seed", "source")


@dataclass(frozen=True)
class EgoSteps:
    """The ego's steps of every episode, sorted by episode and time: what measures read.

    Per-step arrays are (m,) over the ego's valid steps; per-episode arrays (S,).

    Attributes:
        scenario_id: (S,) the episode's scenario id.
        starts: (S,) first step of each episode; ``counts``: (S,) its steps.
        step: (m,) int time step (round(t * 10)); consecutive steps differ by 1.
        t: (m,) [s]; speed: (m,) [m/s]; accel: (m,) [m/s^2] (first difference of speed).
        crashed: (m,) bool, the ego is crashed at that step.
        leader_row: (m,) row of the leader in the input table, -1 where there is none.
        gap: (m,) [m] bumper gap to the leader (NaN: no leader).
        closing: (m,) [m/s] the ego's speed less the leader's velocity along the path.
        headway: (m,) [s] time headway on scored steps (NaN elsewhere; 0 when crashed).
        ttc: (m,) [s] time to collision on scored steps (inf: not closing in; NaN: not
            scored or no leader; 0 when crashed).
        has_others: (S,) bool, the episode records other road users.
        first_row: (S,) the input row of each episode's first ego step.
        scored: (m,) bool, the step counts in the episode's minima (after the burn-in, or
            in the closing-in run that ends in a crash).
        columns: the ego's (m,) values (float; NaN where missing) of the per-step columns
            of :data:`SCENE_STEP_COLUMNS` the table has (recorded scenes write them).
    """

    scenario_id: np.ndarray
    starts: np.ndarray
    counts: np.ndarray
    step: np.ndarray
    t: np.ndarray
    speed: np.ndarray
    accel: np.ndarray
    crashed: np.ndarray
    leader_row: np.ndarray
    gap: np.ndarray
    closing: np.ndarray
    headway: np.ndarray
    ttc: np.ndarray
    has_others: np.ndarray
    first_row: np.ndarray
    scored: np.ndarray
    columns: Mapping[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_episodes(self) -> int:
        return len(self.starts)

    @property
    def episode(self) -> np.ndarray:
        """(m,) the episode of each step."""
        import numpy as np

        return np.repeat(np.arange(self.n_episodes), self.counts)

    def mean(self, values: np.ndarray) -> np.ndarray:
        """(S,) per-episode mean of (m,) ``values`` (NaN ignored; NaN when none)."""
        import numpy as np

        ok = ~np.isnan(values)
        total = np.bincount(self.episode[ok], weights=values[ok], minlength=self.n_episodes)
        n = np.bincount(self.episode[ok], minlength=self.n_episodes)
        with np.errstate(invalid="ignore", divide="ignore"):
            return total / n

    def minimum(self, values: np.ndarray, cap: float = math.inf) -> np.ndarray:
        """(S,) per-episode minimum of (m,) ``values`` (NaN ignored), capped at ``cap``;
        an episode with no value gets the cap."""
        import numpy as np

        if not self.n_episodes:
            return np.zeros(0)
        filled = np.where(np.isnan(values), np.inf, values)
        return np.minimum(np.minimum.reduceat(filled, self.starts), cap)

    def any(self, values: np.ndarray) -> np.ndarray:
        """(S,) bool: the episode has a true step."""
        import numpy as np

        if not self.n_episodes:
            return np.zeros(0, bool)
        return np.logical_or.reduceat(values.astype(bool), self.starts)

    def last(self, values: np.ndarray) -> np.ndarray:
        """(S,) per-episode last non-NaN value of (m,) ``values`` (NaN when none)."""
        import numpy as np

        out = np.full(self.n_episodes, np.nan)
        ok = np.flatnonzero(~np.isnan(values))
        if len(ok):
            ep = self.episode[ok]
            out[ep] = values[ok]  # later steps overwrite earlier ones
        return out

    def consecutive(self, lag: int = 1) -> np.ndarray:
        """(m - lag,) bool: steps i and i + lag are ``lag`` steps apart in one episode."""
        ep = self.episode
        return (ep[lag:] == ep[:-lag]) & (self.step[lag:] - self.step[:-lag] == lag)


MeasureFunction = Callable[[EgoSteps], "np.ndarray"]


MEASURE_ROLES = ("safety", "progress", "comfort", "")
"""What a measure stands for (:attr:`Measure.role`): the verdict reads its safety family
and its efficiency (progress and comfort) family by role, the report's trade-off view
draws each safety rate against each progress measure, never a measure picked by name."""
CONTEXT_REDUCTIONS = ("min", "max", "mean", "first", "")
"""How an episode's occurrences of one interaction context are reduced for a measure taken
inside contexts (:attr:`Measure.in_context`); ``""``: the measure is not taken there."""
MEASURE_KINDS = ("mean", "rate")
"""What a measure's per-episode value is: ``"mean"`` (a number; its mean over episodes gets
Student's t interval, bounded by :attr:`Measure.bounds` where the measure has them) or
``"rate"`` (0 or 1 per episode; its mean is a proportion: Wilson's interval, Tango's for a
paired difference, Newcombe's for an unpaired one, and the report shows it in %)."""


@dataclass(frozen=True)
class Measure:
    """A per-episode measure: everything tap-bench needs to know about it, in one entry.

    Every consumer (the episode table, the intervals, the comparison, power, the gate, the
    report, the viewer) reads these fields; none looks at the name.

    Attributes:
        name: column of the measures table.
        unit: its unit (``"m/s"``; ``"share"`` for a rate).
        higher_is_better: True for speed, headway, TTC; False for crashes and jerk.
        description: one line for reports.
        margin: the regression gate's default margin: the largest change of the mean
            (absolute, in ``unit``) that is not a regression.
        function: :class:`EgoSteps` -> (S,) values, one per episode (None only for an
            entry that describes values computed elsewhere, such as the measures inside
            an interaction context; the registry refuses it).
        label: the name people read (``"min TTC"``; default: ``name`` with spaces).
        kind: ``"mean"`` or ``"rate"`` (:data:`MEASURE_KINDS`).
        bounds: (low, high) the values can take, where bounded (a cap), else None; a rate
            is bounded by (0, 1).
        decimals: decimals shown in tables and the viewer (a rate is shown in whole %).
        role: what the measure stands for where consumers pick measures by what they are,
            never by name (:data:`MEASURE_ROLES`): ``"safety"`` (the verdict's safety
            family; a safety *rate* is the trade-off view's vertical axis), ``"progress"``
            (efficiency; the trade-off view's horizontal axis), ``"comfort"``
            (efficiency), or ``""`` (none of these).
        words: (better, worse): how the verdict says a policy differs on it (``("faster",
            "slower")``); default ``higher <label>`` / ``lower <label>`` by direction.
        gate_weight: the regression gate's share of alpha within an (env, policy) cell,
            where the measure has one of its own (the crash rate most of it: see
            :func:`tap_bench.bench.suite.default_weights`); None: it shares the rest.
        in_context: how the measure is taken inside interaction contexts
            (:mod:`tap_bench.bench.scores.contexts`, :data:`CONTEXT_REDUCTIONS`): its function is
            evaluated on the ego's steps of each occurrence of a context as if the
            occurrence were an episode, and an episode's occurrences of one context are
            reduced by this (``"min"``, ``"max"``, ``"mean"``, ``"first"``); ``""``: not
            measured inside contexts.
    """

    name: str
    unit: str
    higher_is_better: bool
    description: str
    margin: float
    function: MeasureFunction | None
    label: str = ""
    kind: str = "mean"
    bounds: tuple[float, float] | None = None
    decimals: int = 2
    role: str = ""
    words: tuple[str, str] = ()
    gate_weight: float | None = None
    in_context: str = ""

    def __post_init__(self) -> None:
        if not self.label:
            object.__setattr__(self, "label", str(self.name).replace("_", " "))
        if not self.words:
            high, low = f"higher {self.label}", f"lower {self.label}"
            object.__setattr__(self, "words", (high, low) if self.higher_is_better
                               else (low, high))
        object.__setattr__(self, "words", tuple(self.words))
        if self.kind == "rate" and self.bounds is None:
            object.__setattr__(self, "bounds", (0.0, 1.0))
        if self.bounds is not None:
            object.__setattr__(self, "bounds", (float(self.bounds[0]), float(self.bounds[1])))

    @property
    def is_rate(self) -> bool:
        """The per-episode value is 0 or 1 and its mean a proportion."""
        return self.kind == "rate"

    @property
    def interval_method(self) -> str:
        """How the interval of its mean is computed, in words."""
        if self.is_rate:
            return "Wilson score interval"
        if self.bounds is not None:
            return (f"Student's t interval (bounded by [{self.bounds[0]:g}, "
                    f"{self.bounds[1]:g}] {self.unit} when every value is equal)")
        return "Student's t interval"

    @property
    def scale(self) -> float:
        """Factor from the value to what is shown (100 for a rate, shown in %)."""
        return 100.0 if self.is_rate else 1.0

    @property
    def display_unit(self) -> str:
        """The unit as shown: ``%`` for a rate, ``m/s³`` for ``m/s^3``."""
        if self.is_rate:
            return "%"
        return self.unit.replace("^2", "²").replace("^3", "³")

    @property
    def cap(self) -> float | None:
        """The largest value the measure takes (its upper bound), None when unbounded."""
        return None if self.bounds is None else self.bounds[1]

    def to_dict(self) -> dict[str, object]:
        """The entry without its function, as JSON data (run folders, the viewer)."""
        return {"name": self.name, "label": self.label, "unit": self.unit,
                "display_unit": self.display_unit, "higher_is_better": self.higher_is_better,
                "description": self.description, "margin": self.margin, "kind": self.kind,
                "bounds": None if self.bounds is None else list(self.bounds),
                "decimals": self.decimals, "interval": self.interval_method,
                "role": self.role, "words": list(self.words),
                "gate_weight": self.gate_weight, "in_context": self.in_context}


BOUND_TOLERANCE = 1e-9
"""How far beyond its bounds a measure's value may fall by floating-point rounding and still
be one the measure can take (its registration check and ``bench check`` use the same)."""


def run_measures(summary: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The measure entries a run recorded (``summary.json``'s ``measures``: what the report
    and the viewer describe), else the registry's (a run folder older than the field)."""
    recorded = summary.get("measures")
    if isinstance(recorded, list) and recorded:
        return [dict(e) for e in recorded]
    return [m.to_dict() for m in MEASURES]


def check_measure(measure: Measure) -> None:
    """Check a measure entry as the registry does, and its function on a hand-built episode.

    The function is called on the ego steps of two short episodes (one of them crashed,
    with a leader ahead) and must return one finite-or-NaN float per episode, inside the
    measure's bounds. Like Gymnasium's ``check_env``: run it on your measure in a test.

    Raises:
        RegistrationError: naming the measure and what is wrong.
    """
    import numpy as np

    _check_entry(measure)
    steps = ego_steps(_check_table())
    try:
        values = np.asarray(measure.function(steps), dtype=float)
    except Exception as err:  # a measure's own bug, reported with its name
        raise RegistrationError(f"measure {measure.name!r}: its function failed on two "
                                f"hand-built episodes: {type(err).__name__}: {err}") from err
    if values.shape != (steps.n_episodes,):
        raise RegistrationError(f"measure {measure.name!r}: its function must return one value "
                                f"per episode, shape ({steps.n_episodes},); got "
                                f"{values.shape}.")
    finite = values[np.isfinite(values)]
    if measure.bounds is not None and len(finite) and (
            finite.min() < measure.bounds[0] - BOUND_TOLERANCE
            or finite.max() > measure.bounds[1] + BOUND_TOLERANCE):
        raise RegistrationError(f"measure {measure.name!r}: values {finite.tolist()} fall "
                                f"outside its bounds {list(measure.bounds)}.")
    if measure.is_rate and len(finite) and not np.isin(finite, (0.0, 1.0)).all():
        raise RegistrationError(f"measure {measure.name!r} is a rate: each episode's value "
                                f"must be 0 or 1, got {finite.tolist()}.")


def _check_table() -> pd.DataFrame:
    """Two hand-built 5 s episodes at 10 Hz for :func:`check_measure`: ``closing`` (the ego
    at 20 m/s closes in on a leader at 15 m/s, 30 m ahead, and is crashed at its last step)
    and ``alone`` (the ego at 10 m/s, braking gently, no one else)."""
    import numpy as np
    import pandas as pd

    t = np.arange(50) / HZ
    rows = []
    for sid, track, x0, v0, dv, ego, crash in (
            ("closing", "ego", 0.0, 20.0, 0.0, True, True),
            ("closing", "lead", 30.0, 15.0, 0.0, False, False),
            ("alone", "ego", 0.0, 10.0, -0.5, True, False)):
        v = v0 + dv * t
        x = x0 + v0 * t + 0.5 * dv * t * t
        crashed = np.zeros(len(t), bool)
        crashed[-1] = crash
        rows.append(pd.DataFrame({"scenario_id": sid, "track_id": track, "t": t, "x": x,
                                  "y": 0.0, "heading": 0.0, "speed": v, "is_ego": ego,
                                  "crashed": crashed}))
    return pd.concat(rows, ignore_index=True)


def _check_entry(measure: Measure) -> None:
    """The registry's checks of an entry (raises RegistrationError)."""
    if not isinstance(measure.name, str) or not measure.name.isidentifier():
        raise RegistrationError(f"measure name {measure.name!r} must be an identifier "
                                "(it becomes a column name).")
    margin = measure.margin
    if (margin is None or isinstance(margin, bool) or not isinstance(margin, int | float)
            or not math.isfinite(margin) or margin < 0):
        raise RegistrationError(
            f"measure {measure.name!r} needs a gate margin: a finite number >= 0 in "
            f"{measure.unit} (the largest change that is not a regression), got "
            f"{margin!r}.")
    if not callable(measure.function):
        raise RegistrationError(f"measure {measure.name!r}: function must be callable.")
    if measure.kind not in MEASURE_KINDS:
        raise RegistrationError(f"measure {measure.name!r}: kind {measure.kind!r} is not one "
                                f"of {MEASURE_KINDS}.")
    if measure.bounds is not None and not (
            len(measure.bounds) == 2 and measure.bounds[0] < measure.bounds[1]):
        raise RegistrationError(f"measure {measure.name!r}: bounds {measure.bounds!r} must be "
                                "(low, high) with low < high, or None.")
    if (isinstance(measure.decimals, bool) or not isinstance(measure.decimals, int)
            or not 0 <= measure.decimals <= 6):
        raise RegistrationError(f"measure {measure.name!r}: decimals {measure.decimals!r} "
                                "must be an integer from 0 to 6.")
    if measure.role not in MEASURE_ROLES:
        raise RegistrationError(f"measure {measure.name!r}: role {measure.role!r} is not one "
                                f"of {', '.join(repr(r) for r in MEASURE_ROLES)}.")
    if len(measure.words) != 2 or not all(isinstance(w, str) and w for w in measure.words):
        raise RegistrationError(f"measure {measure.name!r}: words {measure.words!r} must be "
                                "two words, (better, worse).")
    if measure.in_context not in CONTEXT_REDUCTIONS:
        raise RegistrationError(f"measure {measure.name!r}: in_context {measure.in_context!r} "
                                f"is not one of {', '.join(map(repr, CONTEXT_REDUCTIONS))} "
                                "(how an episode's occurrences of a context are reduced).")
    weight = measure.gate_weight
    if weight is not None and (isinstance(weight, bool) or not isinstance(weight, int | float)
                               or not 0 < weight < 1):
        raise RegistrationError(f"measure {measure.name!r}: gate_weight {weight!r} must be "
                                "a share of alpha between 0 and 1, or None.")


class MeasureRegistry(Registry[Measure]):
    """The measures, in registration (report) order; refuses duplicates, missing margins
    and entries that do not check (:func:`_check_entry`).

    Iterating gives the :class:`Measure` entries; ``registry["min_ttc_s"]`` one of them.
    """

    def __init__(self) -> None:
        super().__init__("measure", check=_check_entry)

    def margins(self) -> dict[str, float]:
        """name -> default gate margin."""
        return {m.name: float(m.margin) for m in self}


MEASURES = MeasureRegistry()
"""The measures scored in comparisons and checked by the gate, in report order."""


def register_measure(name: str, *, unit: str, higher_is_better: bool, margin: float,
                     description: str, label: str = "", kind: str = "mean",
                     bounds: tuple[float, float] | None = None, decimals: int = 2,
                     role: str = "", words: tuple[str, str] = (),
                     gate_weight: float | None = None, in_context: str = "",
                     registry: MeasureRegistry = MEASURES
                     ) -> Callable[[MeasureFunction], MeasureFunction]:
    """Decorator: register ``function(steps: EgoSteps) -> (S,) values`` as a measure (the
    fields are :class:`Measure`'s)."""

    def decorate(function: MeasureFunction) -> MeasureFunction:
        registry.register(Measure(name, unit, higher_is_better, description, margin,
                                  function, label=label, kind=kind, bounds=bounds,
                                  decimals=decimals, role=role, words=words,
                                  gate_weight=gate_weight, in_context=in_context))
        return function

    return decorate


def measures_with_role(role: str, entries: Iterable[Measure] | None = None
                       ) -> tuple[Measure, ...]:
    """The entries of ``role`` (:data:`MEASURE_ROLES`) in registration order: those given,
    else every registered measure and scene measure (:data:`MEASURES`,
    :data:`SCENE_MEASURES`)."""
    if role not in MEASURE_ROLES:
        raise RegistrationError(f"unknown measure role {role!r}; the roles are "
                                f"{', '.join(repr(r) for r in MEASURE_ROLES)}.")
    entries = (*MEASURES, *SCENE_MEASURES) if entries is None else entries
    return tuple(m for m in entries if m.role == role)


def measure_entry(name: str) -> Measure | None:
    """The registered entry of ``name`` (a measure or a scene measure), None if none."""
    for registry in (MEASURES, SCENE_MEASURES):
        if name in registry:
            return registry[name]
    return None


@register_measure("crashed", unit="share", higher_is_better=False, margin=0.10,
                  description="collision rate of the ego", label="crash rate", kind="rate",
                  role="safety", words=("safer", "less safe"), gate_weight=0.65)
def _crashed(steps: EgoSteps) -> np.ndarray:
    return steps.any(steps.crashed)


@register_measure("mean_speed", unit="m/s", higher_is_better=True, margin=1.0,
                  description="mean ego speed", label="mean speed", decimals=1,
                  role="progress", words=("faster", "slower"))
def _mean_speed(steps: EgoSteps) -> np.ndarray:
    return steps.mean(steps.speed)


@register_measure("min_headway_s", unit="s", higher_is_better=True, margin=0.3,
                  description="smallest time headway to the leader along the path (capped "
                  "10 s; 0 on a crash)", label="min headway", bounds=(0.0, HEADWAY_CAP_S),
                  role="safety", gate_weight=0.1, in_context="min")
def _min_headway(steps: EgoSteps) -> np.ndarray:
    return _leader_minimum(steps, steps.headway, HEADWAY_CAP_S)


@register_measure("min_ttc_s", unit="s", higher_is_better=True, margin=1.0,
                  description="smallest time to collision with the leader along the path "
                  "(capped 10 s; 0 on a crash)", label="min TTC", bounds=(0.0, TTC_CAP_S),
                  role="safety", gate_weight=0.1, in_context="min")
def _min_ttc(steps: EgoSteps) -> np.ndarray:
    return _leader_minimum(steps, steps.ttc, TTC_CAP_S)


def _leader_minimum(steps: EgoSteps, values: np.ndarray, cap: float) -> np.ndarray:
    """Per episode, the smallest of a measure to the leader, capped at ``cap``; NaN in an
    episode with no value on any scored step (no leader after the burn-in, or none while
    the ego moved, and no crash): "no leader" has no minimum, it is not a 10 s
    observation. Such episodes are counted apart (:func:`leader_counts`)."""
    import numpy as np

    out = steps.minimum(values, cap)
    out[~steps.any(~np.isnan(values))] = np.nan
    return out


def leader_counts(steps: EgoSteps) -> pd.DataFrame:
    """Per episode: ``scenario_id``, ``leader_steps`` (scored steps with a leader) and
    ``no_leader`` (True: min headway and min TTC are NaN, not the cap)."""
    import numpy as np
    import pandas as pd

    has = (steps.leader_row >= 0) & steps.scored
    n = np.bincount(steps.episode[has], minlength=steps.n_episodes)
    return pd.DataFrame({"scenario_id": steps.scenario_id, "leader_steps": n,
                         "no_leader": (n == 0) & ~steps.any(steps.crashed)})


@register_measure("rms_jerk", unit="m/s^3", higher_is_better=False, margin=1.0,
                  description="RMS longitudinal jerk of the ego (Savitzky-Golay, 1.5 s, as "
                  "nuPlan)", label="RMS jerk", role="comfort", words=("smoother", "harsher"),
                  in_context="mean")
def _rms_jerk(steps: EgoSteps) -> np.ndarray:
    import numpy as np

    jerk = smoothed_jerk(steps)
    ok = ~np.isnan(jerk)
    sq = np.bincount(steps.episode[ok], weights=jerk[ok] ** 2, minlength=steps.n_episodes)
    n = np.bincount(steps.episode[ok], minlength=steps.n_episodes)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.sqrt(sq / n)


def smoothed_jerk(steps: EgoSteps) -> np.ndarray:
    """(m,) [m/s^3] the ego's longitudinal jerk at each step: the Savitzky-Golay derivative
    (window :data:`JERK_WINDOW_S`, order :data:`JERK_POLYORDER`) of the Savitzky-Golay
    derivative of the speed, as nuPlan's ``extract_ego_jerk``, over each run of consecutive
    steps; NaN in runs shorter than the window."""
    import numpy as np

    m = len(steps.speed)
    out = np.full(m, np.nan)
    if not m:
        return out
    run_start = np.ones(m, bool)
    run_start[1:] = ~steps.consecutive(1)
    starts = np.flatnonzero(run_start)
    stops = np.r_[starts[1:], m]
    for a, b in zip(starts.tolist(), stops.tolist(), strict=False):
        if b - a >= JERK_WINDOW_STEPS:
            accel = savgol_derivative(steps.speed[a:b], JERK_WINDOW_STEPS, JERK_POLYORDER,
                                      1.0 / HZ)
            out[a:b] = savgol_derivative(accel, JERK_WINDOW_STEPS, JERK_POLYORDER, 1.0 / HZ)
    return out


def savgol_derivative(y: np.ndarray, window: int, order: int, delta: float) -> np.ndarray:
    """(n,) the first derivative of ``y`` (n,) by a Savitzky-Golay filter: a least-squares
    polynomial of ``order`` over each ``window`` (odd) samples ``delta`` apart, its slope at
    the centre; the first and last ``window // 2`` samples take the slope of the first and
    last window's polynomial at their place (scipy's ``savgol_filter(deriv=1,
    mode="interp")``, without needing scipy)."""
    import numpy as np

    y = np.asarray(y, dtype=np.float64)
    n = len(y)
    if window % 2 != 1 or window <= order or n < window:
        raise ValueError(f"savgol_derivative: window {window} must be odd, above the order "
                         f"{order} and at most the {n} samples.")
    half = window // 2
    x, fit = _savgol_fit(window, order)
    out = np.empty(n)
    out[half:n - half] = np.lib.stride_tricks.sliding_window_view(y, window) @ fit[1]
    powers = np.arange(1, order + 1)
    for rows, coef in ((slice(0, half), fit @ y[:window]),
                       (slice(n - half, n), fit @ y[n - window:])):
        at = x[:half] if rows.start == 0 else x[half + 1:]
        out[rows] = (powers[None, :] * coef[1:][None, :]
                     * at[:, None] ** (powers - 1)[None, :]).sum(axis=1)
    return out / delta


@lru_cache(maxsize=16)
def _savgol_fit(window: int, order: int) -> tuple[np.ndarray, np.ndarray]:
    """(window,) the sample offsets -half..half and (order + 1, window) the least-squares
    fit of a polynomial of ``order`` to them, computed once per process (an SVD each call
    cost more than the filter on an episode's few hundred steps); read-only."""
    import numpy as np

    half = window // 2
    x = np.arange(-half, half + 1, dtype=np.float64)
    fit = np.linalg.pinv(np.vander(x, order + 1, increasing=True))
    x.flags.writeable = fit.flags.writeable = False
    return x, fit


SCENE_MEASURES = MeasureRegistry()
"""Measures of closed-loop episodes on recorded scenes (``tap_bench/womd-v0``, SPEC section
8), from the per-step columns the env writes on the ego's rows
(:data:`SCENE_STEP_COLUMNS`); :func:`ego_measures` adds them when a table has those
columns (a synthetic scenario has no lanes of record, no signals and no human to compare
with)."""
SCENE_STEP_COLUMNS = ("off_road", "crash_at_fault", "ran_red_light", "route_progress",
                      "log_distance", "ended_early")
"""Per-step ego columns of recorded-scene rollouts: off road (bool), crashed and at fault
(bool, SPEC 8's rules: :mod:`tap_bench.sim.collisions`), crossed a red stop point
at that step (bool), share of the logged path covered so far (0-1), distance to the logged
ego at the same step [m] (NaN before the current time), the episode ended (a collision,
off the road) before the log's end (bool); ``ran_red_light`` is NA on a scene without
signal states."""


SCENE_STANDS_IN = {"crashed": "crashed_at_fault"}
"""measure -> the scene measure that stands in for it on recorded scenes (SPEC section 8): the
regression gate's crash check counts at-fault collisions there (an episode whose
``crashed_at_fault`` is not NA), and the report shows all collisions beside them."""


def _scene_column(steps: EgoSteps, name: str) -> np.ndarray:
    import numpy as np

    values = steps.columns.get(name)
    return np.full(len(steps.t), np.nan) if values is None else values


@register_measure("crashed_at_fault", unit="share", higher_is_better=False, margin=0.10,
                  description="the ego collided and was at fault (not when it was stopped "
                  "and hit, hit from behind, or entered by a pedestrian or cyclist while "
                  "stopped)", label="at-fault crash rate", kind="rate", role="safety",
                  words=("safer", "less safe"), registry=SCENE_MEASURES)
def _crashed_at_fault(steps: EgoSteps) -> np.ndarray:
    import numpy as np

    values = steps.columns.get("crash_at_fault")
    if values is None:  # a table without the column: every crash counts
        return steps.any(steps.crashed).astype(float)
    return steps.any(np.nan_to_num(values) > 0.5).astype(float)


@register_measure("off_road", unit="share", higher_is_better=False, margin=0.10,
                  description="the ego left the road: a corner of its box beyond the road "
                  "edges (lane centres where no edge is near), not where it started",
                  label="off road",
                  kind="rate", role="safety", registry=SCENE_MEASURES)
def _off_road(steps: EgoSteps) -> np.ndarray:
    import numpy as np

    values = _scene_column(steps, "off_road")
    out = steps.any(np.nan_to_num(values) > 0.5).astype(float)
    out[np.isnan(steps.mean(values))] = np.nan
    return out


@register_measure("route_progress", unit="share", higher_is_better=True, margin=0.10,
                  description="share of the logged ego's path covered along its route (0-1)",
                  label="route progress", bounds=(0.0, 1.0), role="progress",
                  registry=SCENE_MEASURES)
def _route_progress(steps: EgoSteps) -> np.ndarray:
    return steps.last(_scene_column(steps, "route_progress"))


@register_measure("ran_red_light", unit="share", higher_is_better=False, margin=0.10,
                  description="the ego crossed a stop point while its signal was red",
                  label="ran a red light", kind="rate", role="safety",
                  registry=SCENE_MEASURES)
def _ran_red_light(steps: EgoSteps) -> np.ndarray:
    import numpy as np

    values = _scene_column(steps, "ran_red_light")
    out = steps.any(np.nan_to_num(values) > 0.5).astype(float)
    out[np.isnan(steps.mean(values))] = np.nan
    return out


def _full_episodes(steps: EgoSteps, values: np.ndarray) -> np.ndarray:
    """Per-episode ``values`` where the episode ran to the log's end, NaN where it ended
    early: ADE and FDE over the same horizon for every episode (an episode that crashed at
    1.5 s would otherwise average its distance over 0.5 s and look closer to the human)."""
    import numpy as np

    early = steps.columns.get("ended_early")
    if early is None:
        return values
    return np.where(steps.any(np.nan_to_num(early) > 0.5), np.nan, values)


@register_measure("log_ade", unit="m", higher_is_better=False, margin=1.0,
                  description="mean distance to the logged ego over the simulated steps, "
                  "over full episodes (NaN where the episode ended early)",
                  label="log ADE", registry=SCENE_MEASURES)
def _log_ade(steps: EgoSteps) -> np.ndarray:
    return _full_episodes(steps, steps.mean(_scene_column(steps, "log_distance")))


@register_measure("log_fde", unit="m", higher_is_better=False, margin=2.0,
                  description="distance to the logged ego at the log's last step, over "
                  "full episodes (NaN where the episode ended early)",
                  label="log FDE", registry=SCENE_MEASURES)
def _log_fde(steps: EgoSteps) -> np.ndarray:
    return _full_episodes(steps, steps.last(_scene_column(steps, "log_distance")))


def _require(table: pd.DataFrame) -> None:
    for col in ("scenario_id", "track_id", "t", "x", "y", "heading", "speed", "is_ego"):
        if col not in table.columns:
            fix = (" Mark the ego (the policy's vehicle, WOMD's self-driving car) with a "
                   "boolean is_ego column." if col == "is_ego" else "")
            raise TrajectoryTableError(f"ego measures need column {col!r}; the table has "
                                       f"{', '.join(map(str, table.columns))}.{fix}",
                                       column=col)


def ego_steps(table: pd.DataFrame, map_table: pd.DataFrame | LaneMap | None = None
              ) -> EgoSteps:
    """The ego's steps of every scenario with the leader, headway and TTC along its path.

    Args:
        table: trajectory table with ``scenario_id``, ``track_id``, ``t``, ``x``, ``y``,
            ``heading``, ``speed`` and ``is_ego``; optional ``valid``, ``crashed`` and
            ``length`` [m]. Rows of one track must be at distinct 0.1 s steps.
        map_table: lane centre lines (:mod:`tap_bench.maps`; a scenario's map is the one
            whose ``map_id`` is its ``scenario_id``, else its ``env``): the ego's path goes
            on along its lane beyond the record; or a :class:`~tap_bench.pathframe.LaneMap`
            of them shared with ``tap()``'s call (:func:`~tap_bench.pathframe.scene_lanes`).
            None: along an arc of its last curvature.

    Raises:
        TrajectoryTableError: ``is_ego`` is missing, a scenario has two ego tracks, or an
            ego has two rows at one step.
    """
    import numpy as np
    import pandas as pd

    _require(table)
    valid = np.ones(len(table), bool)
    if "valid" in table.columns:
        valid = table["valid"].fillna(False).to_numpy(bool, copy=True)
    for col in ("x", "y", "heading", "speed"):
        valid &= np.isfinite(table[col].to_numpy(float))
    t = table["t"].to_numpy(float)
    step = np.rint(t * HZ).astype(np.int64)
    sid_codes, sids = pd.factorize(table["scenario_id"], sort=False)
    is_ego = table["is_ego"].fillna(False).to_numpy(bool)
    ego_rows = np.flatnonzero(is_ego & valid)

    n_steps = int(step.max() - step.min() + 1) if len(step) else 1
    step0 = int(step.min()) if len(step) else 0
    key = sid_codes.astype(np.int64) * n_steps + (step - step0)

    ego_track = table["track_id"].take(ego_rows).to_numpy()  # not the whole string column
    ego_sid = sid_codes[ego_rows]
    _check_one_ego(ego_sid, ego_track, sids)
    order = np.argsort(key[ego_rows], kind="stable")
    ego_rows = ego_rows[order]
    ego_key = key[ego_rows]
    if len(ego_key) > 1 and np.any(ego_key[1:] == ego_key[:-1]):
        dup = ego_rows[1:][ego_key[1:] == ego_key[:-1]][0]
        raise TrajectoryTableError(
            f"row {dup}: the ego of scenario {table['scenario_id'].iloc[dup]!r} has two rows at "
            f"t = {t[dup]:g} s; each track has one row per 0.1 s step.", column="t", row=int(dup))
    seg_sid = ego_sid[order]
    m = len(ego_rows)
    starts = (np.flatnonzero(np.r_[True, seg_sid[1:] != seg_sid[:-1]]) if m else
        np.zeros(0, np.int64))
    counts = np.diff(np.r_[starts, m]).astype(np.int64)
    scen = seg_sid[starts]

    x = table["x"].to_numpy(float)
    y = table["y"].to_numpy(float)
    heading = table["heading"].to_numpy(float)
    speed = table["speed"].to_numpy(float)
    length = np.full(len(table), VEHICLE_LENGTH)
    if "length" in table.columns:
        given = pd.to_numeric(table["length"], errors="coerce").to_numpy(float)
        length = np.where(np.isfinite(given) & (given > 0), given, VEHICLE_LENGTH)
    crashed_all = (table["crashed"].fillna(False).to_numpy(bool) if "crashed" in table.columns
                   else np.zeros(len(table), bool))

    lanes = None if map_table is None else scene_lanes(table, sid_codes, sids, map_table)
    gap, closing, leader = _leaders(key, sid_codes.astype(np.int64), valid & ~is_ego,
                                    ego_rows, ego_key, seg_sid, x, y, heading, speed, length,
                                    lanes)
    v_ego = speed[ego_rows]
    crashed = crashed_all[ego_rows]
    with np.errstate(divide="ignore", invalid="ignore"):
        headway = np.where(v_ego >= MIN_SPEED_FOR_HEADWAY, gap / v_ego, np.nan)
        ttc = np.where(closing > 0, gap / closing, np.inf)
    ttc = np.where(np.isnan(gap), np.nan, ttc)
    episode = np.repeat(np.arange(len(starts)), counts)
    ego_step = step[ego_rows]
    consecutive = np.ones(m, bool)
    consecutive[1:] = (episode[1:] == episode[:-1]) & (ego_step[1:] - ego_step[:-1] == 1)
    consecutive[starts] = False
    # the initial gaps are the scenario's, not the policy's: the first BURN_IN_S are not
    # scored, except a conflict that leads to a crash (the closing-in run ending at it)
    t_ego = t[ego_rows]
    t_rel = t_ego - np.repeat(t_ego[starts], counts) if m else t_ego
    conflict = np.isfinite(ttc) | crashed
    run_start = ~consecutive | ~np.r_[False, conflict[:-1]] if m else np.zeros(0, bool)
    run_id = np.cumsum(run_start) - 1
    to_crash = np.zeros(m, bool)
    if m:
        run_crash = np.logical_or.reduceat(crashed, np.flatnonzero(run_start))
        to_crash = conflict & run_crash[run_id]
    scored = (t_rel >= BURN_IN_S - 1e-9) | to_crash
    headway = np.where(scored, headway, np.nan)
    ttc = np.where(scored, ttc, np.nan)
    headway[crashed] = 0.0
    ttc[crashed] = 0.0
    accel = np.full(m, np.nan)
    if m > 1:
        ok = consecutive[1:]
        accel[1:][ok] = (v_ego[1:] - v_ego[:-1])[ok] * HZ

    has_others = np.bincount(sid_codes[~is_ego & valid], minlength=len(sids))[scen] > 0
    columns = {name: pd.to_numeric(table[name].take(ego_rows).astype("Float64"),
                                   errors="coerce").to_numpy(float, na_value=np.nan)
               for name in SCENE_STEP_COLUMNS if name in table.columns}
    return EgoSteps(scenario_id=np.asarray(sids)[scen], starts=starts, counts=counts,
                    step=ego_step, t=t_ego, speed=v_ego, accel=accel, crashed=crashed,
                    leader_row=leader, gap=gap, closing=closing, headway=headway, ttc=ttc,
                    has_others=has_others, first_row=ego_rows[starts], scored=scored,
                    columns=columns)


def ego_step_measures(table: pd.DataFrame, map_table: pd.DataFrame | LaneMap | None = None
                      ) -> pd.DataFrame:
    """The ego's safety measures at every valid step of every scenario (what
    :func:`ego_measures` reduces to one row per episode), for viewers and plots.

    Args:
        table: a trajectory table, as for :func:`ego_steps`.

    Returns:
        one row per valid ego step, sorted by scenario (in order of first appearance) and
        time: ``scenario_id``, ``t`` [s], ``speed`` [m/s], ``gap_m`` (bumper gap to the
        leader along the path [m]), ``headway_s`` and ``ttc_s`` [s] (capped at
        :data:`HEADWAY_CAP_S` and :data:`TTC_CAP_S`; NaN without a leader, and the headway
        below :data:`MIN_SPEED_FOR_HEADWAY`; 0 while crashed), ``scored`` (False where the
        burn-in leaves the step out of the episode minima).
    """
    import numpy as np
    import pandas as pd

    steps = ego_steps(table, map_table)
    headway, ttc = _unscored(steps)
    return pd.DataFrame({
        "scenario_id": np.repeat(steps.scenario_id, steps.counts), "t": steps.t,
        "speed": steps.speed, "gap_m": steps.gap,
        "headway_s": np.minimum(headway, HEADWAY_CAP_S), "ttc_s": np.minimum(ttc, TTC_CAP_S),
        "scored": steps.scored})


def _unscored(steps: EgoSteps) -> tuple[np.ndarray, np.ndarray]:
    """(headway, ttc) at every step, the burn-in not applied (0 while crashed)."""
    import numpy as np

    with np.errstate(divide="ignore", invalid="ignore"):
        headway = np.where(steps.speed >= MIN_SPEED_FOR_HEADWAY, steps.gap / steps.speed,
                           np.nan)
        ttc = np.where(steps.closing > 0, steps.gap / steps.closing, np.inf)
    ttc = np.where(np.isnan(steps.gap), np.nan, ttc)
    headway[steps.crashed] = 0.0
    ttc[steps.crashed] = 0.0
    return headway, ttc


def ego_measures(table: pd.DataFrame, map_table: pd.DataFrame | LaneMap | None = None, *,
                 steps: EgoSteps | None = None) -> pd.DataFrame:
    """Safety and efficiency measures of the ego of every scenario of a trajectory table.

    Args:
        table: as :func:`ego_steps`; the identifying ``env``, ``policy``, ``seed``,
            ``source`` are carried over.
        map_table: lane centre lines (:func:`ego_steps`).
        steps: :func:`ego_steps` of ``table`` (and ``map_table``) where the caller has them
            already (the runner shares them with the interaction contexts).

    Returns:
        one row per scenario with an ego: ``scenario_id``, the identifying columns present,
        one column per registered measure (:data:`MEASURES`, and :data:`SCENE_MEASURES`
        when the table carries :data:`SCENE_STEP_COLUMNS`) and ``duration_s``.
    """
    import numpy as np
    import pandas as pd

    steps = ego_steps(table, map_table) if steps is None else steps
    # the columns gathered first and made a frame once (a frame insert per column costs
    # more than the measures of a small batch)
    columns: dict[str, Any] = {"scenario_id": steps.scenario_id}
    for col in _KEEP:
        if col in table.columns:
            columns[col] = table[col].take(steps.first_row).to_numpy()
    scene = [m for m in SCENE_MEASURES if steps.columns]  # recorded scenes only
    for measure in (*MEASURES, *scene):
        values = np.asarray(measure.function(steps))
        if values.shape != (steps.n_episodes,):
            raise RegistrationError(f"measure {measure.name!r} returned shape {values.shape}, "
                                    f"expected ({steps.n_episodes},): one value per episode.")
        columns[measure.name] = values
    if steps.n_episodes:
        last = steps.starts + steps.counts - 1
        columns["duration_s"] = steps.t[last] - steps.t[steps.starts] + 1.0 / HZ
    else:
        columns["duration_s"] = np.zeros(0)
    return pd.DataFrame(columns)


def _check_one_ego(ego_sid: np.ndarray, ego_track: np.ndarray, sids) -> None:
    import numpy as np
    import pandas as pd

    if not len(ego_sid):
        return
    order = np.argsort(ego_sid, kind="stable")
    s, k = ego_sid[order], np.asarray(ego_track, dtype=object)[order]
    if not ((s[1:] == s[:-1]) & (k[1:] != k[:-1])).any():  # one track in every scenario
        return
    pairs = pd.DataFrame({"s": ego_sid, "k": ego_track}).drop_duplicates()
    many = pairs["s"].duplicated(keep=False)
    if many.any():
        s = int(pairs.loc[many, "s"].iloc[0])
        tracks = sorted(map(str, pairs.loc[pairs["s"] == s, "k"]))
        raise TrajectoryTableError(
            f"scenario {sids[s]!r} has {len(tracks)} ego tracks ({', '.join(tracks[:5])}); "
            "is_ego must mark one track per scenario.", column="is_ego")


def _leaders(key, scene, other_mask, ego_rows, ego_key, ego_sid, x, y, heading, speed,
             length, lanes=None):
    """(m,) bumper gap, closing speed and row of the leader along the ego's path at each ego
    step (NaN, NaN, -1: no leader)."""
    import numpy as np

    m = len(ego_rows)
    gap = np.full(m, np.nan)
    closing = np.full(m, np.nan)
    leader = np.full(m, -1, np.int64)
    others = np.flatnonzero(other_mask)
    if not m or not len(others):
        return gap, closing, leader
    # the ego's rows (by key) then the others: each run of consecutive ego steps is a path
    rows = np.r_[ego_rows, others]
    new_path = np.ones(m, bool)
    new_path[1:] = (ego_key[1:] - ego_key[:-1] != 1) | (ego_sid[1:] != ego_sid[:-1])
    start = np.flatnonzero(new_path)
    stop = np.r_[start[1:], m]
    track = np.r_[np.ones(m, np.int64), np.zeros(len(others), np.int64)]
    paths = Paths(scene=scene[rows], key=key[rows], track=track, x=x[rows], y=y[rows],
                  heading=heading[rows], speed=speed[rows], start=start, stop=stop)
    reach = leader_reach(speed[ego_rows])  # ego_rows() of these paths is 0 .. m - 1
    frame = path_frame(paths, np.r_[np.zeros(m, bool), np.ones(len(others), bool)],
                       ahead=reach, behind=1.0, lateral=CORRIDOR_HALF_WIDTH, lanes=lanes)
    pair = nearest_leader(frame, reach)
    p = np.flatnonzero(pair >= 0)
    o, e = rows[frame.other[pair[p]]], ego_rows[p]
    gap[p] = np.maximum(frame.s[pair[p]] - 0.5 * (length[e] + length[o]), 0.0)
    closing[p] = speed[e] - frame.v_along[pair[p]]
    leader[p] = o
    return gap, closing, leader
