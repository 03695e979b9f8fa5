"""A safety layer for an agent's ego on ``tap_bench/womd-v0``: its acceleration capped by the
braking an IDM driver needs for the road user in the ego's own swept box.

Shielding (Alshiekh et al. 2018, "Safe Reinforcement Learning via Shielding") and the safety
layer of Dalal et al. 2018 ("Safe Exploration in Continuous Action Spaces") put a correction
between a learned policy and the plant: the policy decides, the layer lets through what is
safe. Here the policy keeps its meta-actions (lane, target speed); at every simulated step
(10 Hz) the longitudinal acceleration its controller asks for is capped by IDM's
interaction term (Treiber, Hennecke & Helbing 2000) for the nearest road user in the ego's
swept box (:func:`~tap_bench.sim.womd_observation.swept_leader`: where the ego's box goes
over the next 3 s from its heading, speed and steering, not where the route is):

    cap = a * (1 - (s* / s)^2),  s* = s0 + max(0, v T + v dv / (2 sqrt(a b))),

with s the gap [m], v the ego's speed and dv the closing speed [m/s]; IDM's free-road term
is left to the policy. The cap never asks for more braking than ``emergency_braking``. With
no road user in the swept box the policy's acceleration goes through.

With ``predicted`` (off by default: the fifth ``ppo-womd`` trained without it) the layer
also caps for the road users whose own predicted motion meets the ego's way
(:func:`~tap_bench.sim.womd_observation.predicted_conflict`: the ego's box along its swept
poses at the speed the policy's acceleration gives, each crossing or oncoming road user's
box at its velocity and heading, compared at matched times within ``tolerance`` s over the
same 3 s): the same IDM term for a standing obstacle at the edge of that road user's zone
(a car turning across the ego's lane, or the ego turning across oncoming traffic). The
smaller of the two caps applies.

It is part of an agent's action space, chosen by the agent's own action config
(``{"type": "DiscreteMetaAction", ..., "safety_layer": true}``, or a mapping of
:class:`SafetyLayer`'s fields), trained and evaluated with it; the env's default action has
none, and no other policy's ego gets one. :attr:`SafetyLayer.capped` and
:attr:`SafetyLayer.braked` count the simulated steps in which it changed the policy's
acceleration (and made it brake where the policy did not).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from tap_bench.errors import ParameterError
from tap_bench.sim.womd_observation import PREDICT_TOLERANCE

__all__ = ["SafetyLayer", "safety_layer"]


@dataclasses.dataclass
class SafetyLayer:
    """IDM's interaction term as a cap on the ego's acceleration (see the module docstring).

    Attributes:
        max_acceleration: IDM's a [m/s^2].
        comfortable_braking: IDM's b [m/s^2] (positive).
        emergency_braking: the most braking the cap asks for [m/s^2] (positive).
        time_gap: IDM's T [s].
        min_gap: IDM's s0, bumper to bumper [m].
        predicted: also cap for the road users whose predicted motion meets the ego's way.
        tolerance: with ``predicted``, how much earlier or later [s] a road user may reach
            the place the ego is at and still count.
        steps: simulated steps the layer judged (an episode's, since :meth:`reset`).
        capped: steps in which it lowered the policy's acceleration.
        braked: steps in which it made the ego brake (the cap < 0) where the policy asked
            for no braking (an acceleration >= 0).
    """

    max_acceleration: float = 3.0
    comfortable_braking: float = 3.0
    emergency_braking: float = 8.0
    time_gap: float = 1.0
    min_gap: float = 2.0
    predicted: bool = False
    tolerance: float = PREDICT_TOLERANCE
    steps: int = dataclasses.field(default=0, compare=False)
    capped: int = dataclasses.field(default=0, compare=False)
    braked: int = dataclasses.field(default=0, compare=False)
    foreseen: int = dataclasses.field(default=0, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.predicted, bool):
            raise ParameterError("safety_layer.predicted", self.predicted, "true or false")
        for field in ("max_acceleration", "comfortable_braking", "emergency_braking",
                      "time_gap", "min_gap", "tolerance"):
            value = getattr(self, field)
            if (isinstance(value, bool) or not isinstance(value, int | float)
                    or not math.isfinite(value) or value <= 0):
                raise ParameterError(f"safety_layer.{field}", value, "a number > 0")
        self._last = None  # the simulated step last judged (a decision acts twice in it)

    def reset(self) -> None:
        """Zero the counts (a new episode)."""
        self.steps = self.capped = self.braked = self.foreseen = 0
        self._last = None

    def cap(self, speed: float, gap: float, closing: float) -> float:
        """The most acceleration [m/s^2] allowed at ``speed`` [m/s] with a road user
        ``gap`` m ahead closing at ``closing`` m/s (inf: no road user, gap inf)."""
        if not math.isfinite(gap):
            return math.inf
        a, b = self.max_acceleration, self.comfortable_braking
        v = max(speed, 0.0)
        wanted = self.min_gap + max(0.0, v * self.time_gap + v * closing / (2 * math.sqrt(a * b)))
        return max(a * (1.0 - (wanted / max(gap, 0.1)) ** 2), -self.emergency_braking)

    def apply(self, ego: Any, others: list[Any], step: int | None = None) -> None:
        """Cap ``ego.action["acceleration"]`` (set by its controller this step) for the
        nearest of ``others`` in its swept box (and, with :attr:`predicted`, for the nearest
        predicted conflict); count the step once (``step``: the road's clock, a decision's
        two acts in one step count once)."""
        from tap_bench.sim.womd_observation import predicted_conflict, swept_leader

        lead = swept_leader(ego, others)
        limit = self.cap(float(ego.speed), lead.gap, lead.closing)
        wanted = float(ego.action["acceleration"])
        foreseen = False
        if self.predicted:
            conflict = predicted_conflict(ego, others, wanted, self.tolerance,
                                          max_acceleration=self.max_acceleration)
            ahead = self.cap(float(ego.speed), conflict.gap, conflict.closing)
            foreseen = ahead < min(limit, wanted)
            limit = min(limit, ahead)
        new = step is None or step != self._last
        self._last = step
        if new:
            self.steps += 1
        if limit < wanted:
            ego.action["acceleration"] = limit
            if new:
                self.capped += 1
                self.braked += bool(limit < 0 <= wanted)
                self.foreseen += foreseen


def safety_layer(setting: Any) -> SafetyLayer | None:
    """The layer an action config's ``safety_layer`` asks for: None for false or missing,
    the defaults for true, a mapping of :class:`SafetyLayer`'s fields for others.

    Raises:
        ParameterError: neither a flag nor a mapping of known fields (names them).
    """
    if setting is None or setting is False:
        return None
    if setting is True:
        return SafetyLayer()
    fields = [f.name for f in dataclasses.fields(SafetyLayer)
              if f.name not in ("steps", "capped", "braked", "foreseen")]
    if not isinstance(setting, Mapping) or any(key not in fields for key in setting):
        raise ParameterError("action.safety_layer", setting,
                             f"true, false or a mapping of {', '.join(fields)}")
    return SafetyLayer(**dict(setting))
