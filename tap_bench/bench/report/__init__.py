"""What a run shows a reader: the report page and the replay viewer.

- :mod:`~tap_bench.bench.report.page`: ``report.html``, one static page;
- :mod:`~tap_bench.bench.report.figures`: its SVG figures;
- :mod:`~tap_bench.bench.report.tables`: its numbers and HTML tables;
- :mod:`~tap_bench.bench.report.pages`: the page templates that name the run;
- :mod:`~tap_bench.bench.report.viewer`: the replay viewer's folder.

``tap_bench.bench.report`` was the module of the report page before ``bench/`` was split: its names
(``from tap_bench.bench.report import ...``) still resolve, from
:mod:`tap_bench.bench.report.page`.
"""

from __future__ import annotations

import importlib
from typing import Any


def __getattr__(name: str) -> Any:
    module = importlib.import_module("tap_bench.bench.report.page")
    if name in module.__all__:
        return getattr(module, name)
    raise AttributeError(f"module 'tap_bench.bench.report' has no attribute {name!r}")
