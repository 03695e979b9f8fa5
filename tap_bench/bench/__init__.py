"""The benchmark: which driving policy behaves better, and how (SPEC section 6, issue 6).

Modules, by what they do:

- :mod:`~tap_bench.bench.episodes`: the episode table every score reads (one row per env,
  policy and seed: the ego's SDL label and measures);
- :mod:`~tap_bench.bench.measures`: the ego's safety and efficiency measures (collision,
  mean speed, minimum time headway and time to collision, jerk);
- :mod:`~tap_bench.bench.bootstrap`: seeded, vectorised bootstrap intervals;
- :mod:`~tap_bench.bench.compare`: matched comparison, paired by seed and matched by label;
- :mod:`~tap_bench.bench.scenarios`: scenarios matched across data sets (highway-env to WOMD);
- :mod:`~tap_bench.bench.coverage`, :mod:`~tap_bench.bench.novelty`: behaviour coverage and
  unique manoeuvres against a reference;
- :mod:`~tap_bench.bench.suite`, :mod:`~tap_bench.bench.scoring`: suites as data, a run's
  tables;
- :mod:`~tap_bench.bench.runner`: ``bench run``, in four jobs:
  :mod:`~tap_bench.bench.run_plan` (what the run will do, and how long it takes),
  :mod:`~tap_bench.bench.run_tasks` (episodes as tasks of the execution layer, the cache),
  :mod:`~tap_bench.bench.run_scores` (references, gaps, headline figures),
  :mod:`~tap_bench.bench.run_folder` (write, read, provenance);
- :mod:`~tap_bench.bench.report`: the report page, with
  :mod:`~tap_bench.bench.report_figures` (the SVG figures) and
  :mod:`~tap_bench.bench.report_tables` (the tables, numbers and HTML tables);
- :mod:`~tap_bench.bench.gate`: ``bench check``, the regression gate;
- :mod:`~tap_bench.bench.demo`: ``tap-bench demo``.
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import Any

# Names resolve on first use (PEP 562), so a worker of ``bench run`` that imports
# ``tap_bench.bench.run_tasks`` loads the task modules, not the runner, the gate, the
# scoring and the report; ``from tap_bench.bench import Suite`` works as before.
_LAZY_MODULES = {
    "tap_bench.bench.bootstrap": ("BootstrapConfig",),
    "tap_bench.bench.compare": ("PairedComparison", "matched_by_label", "paired_comparison"),
    "tap_bench.bench.coverage": ("CoverageResult", "Reference", "corpus_reference", "coverage",
                                 "vocabulary_reference"),
    "tap_bench.bench.episodes": ("episode_table", "episodes_from_table"),
    "tap_bench.bench.gate": ("GateResult", "check", "read_baseline", "write_baseline"),
    "tap_bench.bench.measures": ("MEASURES", "Measure", "ego_measures"),
    "tap_bench.bench.novelty": ("NoveltyResult", "novelty"),
    "tap_bench.bench.runner": ("RunResult", "read_run", "run_suite"),
    "tap_bench.bench.scenarios": ("match_scenarios",),
    "tap_bench.bench.scoring": ("Scores", "score"),
    "tap_bench.bench.suite": ("GateConfig", "Suite", "available_suites", "load_suite"),
}
_LAZY = {name: module for module, names in _LAZY_MODULES.items() for name in names}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'tap_bench.bench' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # the next access is a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


class _Package(types.ModuleType):
    """``tap_bench.bench.coverage`` (and ``novelty``) is the function ``from tap_bench.bench
    import coverage`` promises, also after its submodule has been imported: the import
    system then sets the package's attribute of that name to the submodule, which is
    refused here, as in :mod:`tap_bench.sim` (the submodule stays in ``sys.modules``)."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _LAZY and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


__all__ = [
    # the episode table and its measures
    "MEASURES",
    "Measure",
    "ego_measures",
    "episode_table",
    "episodes_from_table",
    # statistics
    "BootstrapConfig",
    # matched comparison
    "PairedComparison",
    "match_scenarios",
    "matched_by_label",
    "paired_comparison",
    # coverage and unique manoeuvres
    "CoverageResult",
    "NoveltyResult",
    "Reference",
    "corpus_reference",
    "coverage",
    "novelty",
    "vocabulary_reference",
    # suites, runs, scores, the gate
    "GateConfig",
    "GateResult",
    "RunResult",
    "Scores",
    "Suite",
    "available_suites",
    "check",
    "load_suite",
    "read_baseline",
    "read_run",
    "run_suite",
    "score",
    "write_baseline",
]
