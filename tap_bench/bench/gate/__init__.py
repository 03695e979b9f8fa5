"""``bench check``, the regression gate of a run against a stored baseline.

- :mod:`~tap_bench.bench.gate.regression`: the gate, its baseline file and its result;
- :mod:`~tap_bench.bench.gate.statistics`: the gate's test statistics;
- :mod:`~tap_bench.bench.gate.power`: how often the gate's rule catches a given worsening.

``tap_bench.bench.gate`` was the module of the regression gate before ``bench/`` was split:
its names (``from tap_bench.bench.gate import ...``) still resolve, from
:mod:`tap_bench.bench.gate.regression`.
"""

from __future__ import annotations

import importlib
from typing import Any


def __getattr__(name: str) -> Any:
    module = importlib.import_module("tap_bench.bench.gate.regression")
    if name in module.__all__:
        return getattr(module, name)
    raise AttributeError(f"module 'tap_bench.bench.gate' has no attribute {name!r}")
