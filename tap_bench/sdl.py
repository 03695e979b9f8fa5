"""The SDL vocabulary and text: levels, label names, the integer codes the stages work with,
and the one place an SDL label is built (:func:`format_sdl`, :func:`join`) or taken apart
(:func:`parse_sdl`, :func:`split`).

Lateral and longitudinal labels are kept apart (SPEC section 4). Each level has its own
vocabulary; a per-step label is a small integer code indexing the level's name list. An SDL
label is ``lateral + " | " + longitudinal``, each side its chronologically ordered labels
joined by ``" > "``.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence

from tap_bench.errors import LabelTableError, did_you_mean

__all__ = ["AXES", "INTERACTION_NAMES", "LABEL_AXES", "LEVELS", "SDL_SEPARATOR", "SEPARATOR",
           "anonymous_others", "check_axes", "check_level", "format_sdl", "join", "levels",
           "parse_sdl", "split", "tokens", "vocabulary", "with_other"]

LEVELS = ("trace", "trend", "maneuver", "action")
"""Levels from the most abstract to the most detailed."""
AXES = ("lateral", "longitudinal")
"""TAP's two axes of a vehicle's own motion: the ``sdl`` label is ``lateral | longitudinal``."""
LABEL_AXES = ("lateral", "longitudinal", "interaction")
"""Every axis a label can be compared on (SPEC 7 adds the interaction axis)."""
INTERACTION_NAMES = ("Free Driving", "Following", "Cut-in", "Cut-out", "Overtaking",
                     "Being Overtaken", "Lead Braking")
"""The interaction vocabulary (:mod:`tap_bench.interactions`), the same at every level."""
_OTHER = re.compile(r" \(([^()]*)\)(?=\s*(?:>|$|\|))")
"""The other agent's name after an interaction relation: ``" (12)"``."""
SEPARATOR = " > "
"""Joins the chronologically ordered labels of one axis."""
SDL_SEPARATOR = " | "
"""Joins the lateral and the longitudinal sequence into an SDL label."""

# Codes of the trace, trend and maneuver stages (one name list serves all three).
STRAIGHT, LEFT, RIGHT, LEFT_MERGE, RIGHT_MERGE = range(5)
LATERAL_NAMES = ("Straight", "Left Turn", "Right Turn", "Left Merge", "Right Merge")
MAINTAIN, ACCELERATE, DECELERATE, STOPPED, REVERSING = range(5)
LONGITUDINAL_NAMES = ("Maintain Speed", "Accelerate", "Decelerate", "Stopped", "Reversing")

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
    # code = 3*base + speed class for Maintain/Accelerate/Decelerate; 9 Stopped; 10 Reversing
    names = []
    for base in ("Maintain", "Accelerate", "Decelerate"):
        names += [f"{base} {s} Speed" for s in SPEEDS]
    return (*names, "Stopped", "Reversing")


ACTION_LATERAL_NAMES = _action_lateral()
ACTION_LONGITUDINAL_NAMES = _action_longitudinal()
ACTION_STRAIGHT, ACTION_LEFT_MERGE, ACTION_RIGHT_MERGE = 0, 7, 8
ACTION_STOPPED = 9
ACTION_REVERSING = 10

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


def check_level(level: str, *, allow_all: bool = False) -> str:
    """``level`` when it is an SDL level (or ``"all"`` with ``allow_all``), else an
    :class:`~tap_bench.errors.UnknownNameError` with the closest names."""
    known = (*LEVELS, "all") if allow_all else LEVELS
    if level not in known:
        raise did_you_mean("level", level, known)
    return level


def levels(level: str) -> tuple[str, ...]:
    """The levels ``level`` names: itself, or every level for ``"all"``."""
    return LEVELS if check_level(level, allow_all=True) == "all" else (level,)


def vocabulary(level: str, axis: str) -> tuple[str, ...]:
    """Every label that can appear at ``level`` on ``axis`` (:data:`LABEL_AXES`)."""
    check_level(level)
    if axis not in LABEL_AXES:
        raise did_you_mean("axis", axis, LABEL_AXES)
    if axis == "interaction":
        return INTERACTION_NAMES
    return _VOCABULARY[(level, axis)]


def tokens(axis: str) -> tuple[str, ...]:
    """Every label of ``axis`` at any level, in a fixed order."""
    if axis not in LABEL_AXES:
        raise did_you_mean("axis", axis, LABEL_AXES)
    return _TOKENS[axis]


def check_axes(axes: str | Sequence[str] | None) -> tuple[str, ...]:
    """The axes to compare labels on, checked: a sequence (or a comma-separated string) of
    distinct names of :data:`LABEL_AXES`, in that order; None gives TAP's two (:data:`AXES`).
    """
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


def join(labels: Iterable[str]) -> str:
    """One axis's chronologically ordered labels as text: ``"Straight > Left Turn"``."""
    return SEPARATOR.join(labels)


def split(text: str) -> tuple[str, ...]:
    """The labels of one axis's text, in order (spacing around ``>`` tolerated). An
    interaction label's other agent (``"Following (12)"``) is left out: ``"Following"``."""
    return tuple(_OTHER.sub("", tok).strip() for tok in text.split(SEPARATOR.strip()))


def with_other(relation: str, other: str | None) -> str:
    """An interaction label naming its other agent: ``"Following (12)"``; Free Driving
    (no other agent) stays ``"Free Driving"``."""
    return relation if other is None else f"{relation} ({other})"


def anonymous_others(text: str | None) -> str | None:
    """An interaction sequence with its other agents renamed A, B, ... in order of first
    appearance: ``"Following (12) > Cut-in (7) > Following (7)"`` becomes ``"Following (A)
    > Cut-in (B) > Following (B)"``. Sequences of different scenes then compare by what
    happened (a change of leader stays a change) rather than by track ids."""
    if text is None or not isinstance(text, str):
        return text
    names: dict[str, str] = {}

    def rename(match) -> str:
        other = match.group(1)
        if other not in names:
            k = len(names)
            names[other] = chr(0x41 + k % 26) + (str(k // 26) if k >= 26 else "")
        return f" ({names[other]})"

    return _OTHER.sub(rename, text)


def format_sdl(lateral: str | Sequence[str], longitudinal: str | Sequence[str]) -> str:
    """The SDL label of a lateral and a longitudinal side (text, or label sequences)."""
    lat = lateral if isinstance(lateral, str) else join(lateral)
    lon = longitudinal if isinstance(longitudinal, str) else join(longitudinal)
    return lat + SDL_SEPARATOR + lon


def parse_sdl(text: str, *, level: str | None = None,
              axes: str | Sequence[str] | None = None) -> tuple[tuple[str, ...], ...]:
    """Split a label into its label sequences, one per axis.

    Args:
        text: ``"<lateral> > <lateral> ... | <longitudinal> > ..."`` (the SDL label), or with
            other ``axes`` their sequences joined by ``" | "`` in the order of
            :data:`LABEL_AXES` (e.g. ``"Straight | Following > Cut-in"``).
        level: when given, every label must belong to that level's vocabulary.
        axes: the axes the label holds (default lateral and longitudinal).

    Returns:
        one tuple of labels per axis ((lateral, longitudinal) by default), each in
        chronological order.

    Raises:
        LabelTableError: not one ``" | "`` between consecutive axes, an empty side, or an
            unknown label (with the closest known labels).
    """
    axes = check_axes(axes)
    bar = SDL_SEPARATOR.strip()
    if not isinstance(text, str) or text.count(bar) != len(axes) - 1:
        if axes == AXES:
            raise LabelTableError(
                f"SDL label {text!r} must hold exactly one {SDL_SEPARATOR!r} between the "
                f"lateral and the longitudinal labels, e.g. 'Straight > Gradual Left Turn"
                f"{SDL_SEPARATOR}Maintain Medium Speed'.")
        raise LabelTableError(f"label {text!r} must hold {len(axes)} sequence(s) "
                              f"({', '.join(axes)}) joined by {SDL_SEPARATOR!r}.")
    return tuple(_checked(part, axis, level, text)
                 for part, axis in zip(text.split(bar), axes, strict=True))


def _checked(seq: str, axis: str, level: str | None, where: str) -> tuple[str, ...]:
    labels = split(seq)
    known = vocabulary(level, axis) if level else _TOKENS[axis]
    for tok in labels:
        if not tok:
            raise LabelTableError(f"SDL label {where!r}: an empty {axis} label; labels are "
                                  f"joined by {SEPARATOR!r} with one on each side.")
        if tok not in known:
            scope = f"{level}-level {axis} label" if level else f"{axis} label"
            raise LabelTableError(f"SDL label {where!r}: {did_you_mean(scope, tok, known)}")
    return labels


# Every label of each axis over all levels, in a fixed order.
_TOKENS = {
    axis: tuple(dict.fromkeys(name for level in LEVELS for name in _VOCABULARY[(level, axis)]))
    for axis in AXES
}
_TOKENS["interaction"] = INTERACTION_NAMES
