"""TAP thresholds Theta: the frozen dataclass, the ``paper`` preset and versioned JSON files.

Partitions (SPEC section 3)::

    |w| <= w_str Straight, <= w_grad Gradual, <= w_med Medium, else Aggressive   [rad/s]
    a <= a_dec Decelerate, <= a_acc Maintain Speed, else Accelerate               [m/s^2]
    v <= v_stop Stopped, <= v_slow Slow, <= v_med Medium, else Fast               [m/s]
"""

from __future__ import annotations

import itertools
import json
import math
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from tap_bench.errors import ThresholdsError, did_you_mean
from tap_bench.tableio import atomic_path

__all__ = ["PRESETS", "Provenance", "Thresholds", "load_thresholds", "resolve_thresholds",
           "save_thresholds"]

FORMAT = "tap-bench-thresholds"
FORMAT_VERSION = 1

UNITS = {"w": "rad/s", "a": "m/s^2", "v": "m/s"}
"""Unit of each distribution's thresholds."""
NAMES = {"w": ("str", "grad", "med"), "a": ("dec", "acc"), "v": ("stop", "slow", "med")}
"""Threshold names per distribution, in increasing order."""


@dataclass(frozen=True)
class Provenance:
    """Where fitted thresholds come from.

    Attributes:
        dataset: a name for the data (usually the input file).
        n_samples: one-second samples per distribution, e.g. ``{"w": 233000, ...}``.
        objective: J(Theta) at the chosen thresholds per distribution [unit^2].
        method: how each distribution was fitted (``"descent"``, ``"cem"``, ``"grid"``,
            ``"preset"``, ...).
        details: anything else worth keeping (starts, epochs, step rule, versions).
    """

    dataset: str
    n_samples: dict[str, int] = field(default_factory=dict)
    objective: dict[str, float] = field(default_factory=dict)
    method: dict[str, str] = field(default_factory=dict)
    details: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Thresholds:
    """Separation thresholds Theta used by every TAP stage.

    Attributes:
        w_str, w_grad, w_med: yaw-rate thresholds on |w| [rad/s], 0 <= str < grad < med.
        a_dec, a_acc: acceleration thresholds [m/s^2], dec < acc.
        v_stop, v_slow, v_med: speed thresholds [m/s], 0 <= stop < slow < med.
        provenance: where the values come from (None for hand-made thresholds).
    """

    w_str: float
    w_grad: float
    w_med: float
    a_dec: float
    a_acc: float
    v_stop: float
    v_slow: float
    v_med: float
    provenance: Provenance | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "provenance":
                continue
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ThresholdsError(f"threshold {f.name} must be a finite number, got {value!r}")
            object.__setattr__(self, f.name, float(value))
        rules = {"w": "0 <= w_str < w_grad < w_med", "a": "a_dec < a_acc",
                 "v": "0 <= v_stop < v_slow < v_med"}
        for dist, rule in rules.items():
            values = self.of(dist)
            ordered = all(lo < hi for lo, hi in itertools.pairwise(values))
            if not ordered or (dist != "a" and values[0] < 0):
                raise ThresholdsError(f"thresholds out of order: need {rule}, got "
                                      f"{', '.join(f'{v:g}' for v in values)}")

    def of(self, dist: str) -> tuple[float, ...]:
        """The thresholds of one distribution (``"w"``, ``"a"`` or ``"v"``) in order."""
        if dist not in NAMES:
            raise did_you_mean("distribution", dist, NAMES)
        return tuple(getattr(self, f"{dist}_{n}") for n in NAMES[dist])

    def replace(self, dist: str, values: tuple[float, ...] | list[float],
                provenance: Provenance | None = None) -> Thresholds:
        """A copy with the thresholds of ``dist`` replaced (and new provenance)."""
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        for name, value in zip(NAMES[dist], values, strict=True):
            kw[f"{dist}_{name}"] = float(value)
        kw["provenance"] = provenance if provenance is not None else self.provenance
        return Thresholds(**kw)

    def to_dict(self) -> dict[str, Any]:
        """The versioned JSON document (see :func:`save_thresholds`)."""
        doc: dict[str, Any] = {"format": FORMAT, "version": FORMAT_VERSION, "thresholds": {},
                               "units": dict(UNITS)}
        for dist, names in NAMES.items():
            doc["thresholds"][dist] = {n: getattr(self, f"{dist}_{n}") for n in names}
        doc["provenance"] = asdict(self.provenance) if self.provenance else None
        return doc

    @classmethod
    def from_dict(cls, doc: dict[str, Any], *, source: str = "thresholds") -> Thresholds:
        """Read the JSON document written by :meth:`to_dict`, checking format and version."""
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            raise ThresholdsError(f"{source}: not a tap-bench thresholds file (expected "
                                  f"\"format\": \"{FORMAT}\").")
        version = doc.get("version")
        if version != FORMAT_VERSION:
            raise ThresholdsError(f"{source}: thresholds format version {version!r} is not "
                                  f"supported (this tap-bench reads version {FORMAT_VERSION}).")
        units = doc.get("units", UNITS)
        if units != UNITS:
            raise ThresholdsError(f"{source}: units {units!r} differ from {UNITS!r}; convert "
                                  "the values to rad/s, m/s^2 and m/s.")
        kw: dict[str, Any] = {}
        for dist, names in NAMES.items():
            block = doc.get("thresholds", {}).get(dist)
            if not isinstance(block, dict):
                raise ThresholdsError(f"{source}: missing field thresholds.{dist}")
            for n in names:
                if n not in block:
                    raise ThresholdsError(f"{source}: missing field thresholds.{dist}.{n} "
                                          f"[{UNITS[dist]}]")
                kw[f"{dist}_{n}"] = block[n]
        prov = doc.get("provenance")
        if prov is not None:
            try:
                kw["provenance"] = Provenance(**prov)
            except TypeError as err:
                raise ThresholdsError(f"{source}: malformed provenance: {err}") from err
        try:
            return cls(**kw)
        except ThresholdsError as err:
            raise ThresholdsError(f"{source}: {err}") from err


PAPER = Thresholds(
    w_str=0.0283, w_grad=0.0754, w_med=0.1541,
    a_dec=-1.3715, a_acc=1.5557,
    v_stop=0.1, v_slow=10.2140, v_med=24.4046,
    provenance=Provenance(
        dataset="WOMD, 492 scenarios, 25,889 vehicle trajectories (Harder and Behl, TAP)",
        method={"w": "preset", "a": "preset", "v": "preset"},
        details={"reference": "TAP paper, Section 6.2 and Appendix C"},
    ),
)
PRESETS: dict[str, Thresholds] = {"paper": PAPER}
"""Named threshold sets: ``paper`` is the paper's converged values on WOMD."""


def save_thresholds(thresholds: Thresholds, path: str | os.PathLike) -> Path:
    """Write thresholds as versioned JSON (atomically)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(thresholds.to_dict(), indent=2) + "\n")
    return path


def load_thresholds(path: str | os.PathLike) -> Thresholds:
    """Read thresholds written by :func:`save_thresholds`."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError as err:
        raise ThresholdsError(f"{path}: no such thresholds file.") from err
    except json.JSONDecodeError as err:
        raise ThresholdsError(f"{path}: not valid JSON ({err}).") from err
    return Thresholds.from_dict(doc, source=str(path))


def resolve_thresholds(spec: Thresholds | str | os.PathLike) -> Thresholds:
    """Thresholds from an instance, a preset name (``"paper"``) or a JSON file path."""
    if isinstance(spec, Thresholds):
        return spec
    name = str(spec)
    if name in PRESETS:
        return PRESETS[name]
    if Path(name).suffix.lower() == ".json" or Path(name).exists():
        return load_thresholds(name)
    raise did_you_mean("thresholds preset", name, PRESETS)
