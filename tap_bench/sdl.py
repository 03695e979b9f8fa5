"""The SDL vocabulary: levels, label names and the integer codes the stages work with.

Lateral and longitudinal labels are kept apart (SPEC section 4). Each level has its own
vocabulary; a per-step label is a small integer code indexing the level's name list.
"""

from __future__ import annotations

__all__ = ["AXES", "INTERACTION_NAMES", "LABEL_AXES", "LEVELS", "SDL_SEPARATOR", "SEPARATOR",
           "check_axes", "vocabulary"]

LEVELS = ("trace", "trend", "maneuver", "action")
"""Levels from the most abstract to the most detailed."""
AXES = ("lateral", "longitudinal")
"""TAP's two axes of a vehicle's own motion: the ``sdl`` label is ``lateral | longitudinal``."""
LABEL_AXES = ("lateral", "longitudinal", "interaction")
"""Every axis a label can be compared on (SPEC 7 adds the interaction axis)."""
INTERACTION_NAMES = ("Free Driving", "Following", "Cut-in", "Cut-out", "Overtaking",
                     "Being Overtaken", "Lead Braking")
"""The interaction vocabulary (:mod:`tap_bench.interactions`), the same at every level."""
SEPARATOR = " > "
"""Joins the chronologically ordered labels of one axis."""
SDL_SEPARATOR = " | "
"""Joins the lateral and the longitudinal sequence into an SDL label."""

# Codes of the trace, trend and maneuver stages (one name list serves all three).
STRAIGHT, LEFT, RIGHT, LEFT_MERGE, RIGHT_MERGE = range(5)
LATERAL_NAMES = ("Straight", "Left Turn", "Right Turn", "Left Merge", "Right Merge")
MAINTAIN, ACCELERATE, DECELERATE, STOPPED = range(4)
LONGITUDINAL_NAMES = ("Maintain Speed", "Accelerate", "Decelerate", "Stopped")

INTENSITIES = ("Gradual", "Medium", "Aggressive")
"""Turn classes by |w| at the action level."""
SPEEDS = ("Slow", "Medium", "Fast")
"""Speed classes by v at the action level."""


def _action_lateral() -> tuple[str, ...]:
    # code = 0 Straight; 1 + 3*side + intensity for turns; 7, 8 the merges
    names = ["Straight"]
    for side in ("Left", "Right"):
        names += [f"{i} {side} Turn" for i in INTENSITIES]
    return (*names, "Left Merge", "Right Merge")


def _action_longitudinal() -> tuple[str, ...]:
    # code = 3*base + speed class for Maintain/Accelerate/Decelerate; 9 Stopped
    names = []
    for base in ("Maintain", "Accelerate", "Decelerate"):
        names += [f"{base} {s} Speed" for s in SPEEDS]
    return (*names, "Stopped")


ACTION_LATERAL_NAMES = _action_lateral()
ACTION_LONGITUDINAL_NAMES = _action_longitudinal()
ACTION_STRAIGHT, ACTION_LEFT_MERGE, ACTION_RIGHT_MERGE = 0, 7, 8
ACTION_STOPPED = 9

_VOCABULARY = {
    ("trace", "lateral"): LATERAL_NAMES[:3],
    ("trace", "longitudinal"): LONGITUDINAL_NAMES[:3],
    ("trend", "lateral"): LATERAL_NAMES[:3],
    ("trend", "longitudinal"): LONGITUDINAL_NAMES,
    ("maneuver", "lateral"): LATERAL_NAMES,
    ("maneuver", "longitudinal"): LONGITUDINAL_NAMES,
    ("action", "lateral"): ACTION_LATERAL_NAMES,
    ("action", "longitudinal"): ACTION_LONGITUDINAL_NAMES,
}


def code_names(level: str, axis: str) -> tuple[str, ...]:
    """Names indexed by the integer codes the stages emit at ``level`` on ``axis``."""
    if level == "action":
        return _VOCABULARY[(level, axis)]
    return LATERAL_NAMES if axis == "lateral" else LONGITUDINAL_NAMES


def vocabulary(level: str, axis: str) -> tuple[str, ...]:
    """Every label that can appear at ``level`` on ``axis`` (:data:`LABEL_AXES`)."""
    from tap_bench.errors import did_you_mean

    if level not in LEVELS:
        raise did_you_mean("level", level, LEVELS)
    if axis not in LABEL_AXES:
        raise did_you_mean("axis", axis, LABEL_AXES)
    if axis == "interaction":
        return INTERACTION_NAMES
    return _VOCABULARY[(level, axis)]


def check_axes(axes: str | tuple[str, ...] | list[str] | None) -> tuple[str, ...]:
    """The axes to compare labels on, checked: a sequence (or a comma-separated string) of
    distinct names of :data:`LABEL_AXES`, in that order; None gives TAP's two (:data:`AXES`).
    """
    from tap_bench.errors import LabelTableError, did_you_mean

    if axes is None:
        return AXES
    names = [a.strip() for a in axes.split(",")] if isinstance(axes, str) else list(axes)
    for name in names:
        if name not in LABEL_AXES:
            raise did_you_mean("axis", name, LABEL_AXES)
    if not names or len(set(names)) != len(names):
        raise LabelTableError(f"axes {axes!r}: give one or more distinct axes of "
                              f"{', '.join(LABEL_AXES)}.")
    return tuple(a for a in LABEL_AXES if a in names)
