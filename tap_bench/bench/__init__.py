"""The benchmark: which driving policy behaves better, and how (SPEC section 6).

The data a run's jobs share stand at this package's root; each job is a sub-package:

- :mod:`~tap_bench.bench.measures`: the ego's safety and efficiency measures (collision,
  mean speed, minimum time headway and time to collision, jerk), a registry;
- :mod:`~tap_bench.bench.episodes`: the episode table every score reads (one row per env,
  policy and seed: the ego's SDL label and measures);
- :mod:`~tap_bench.bench.suite`: suites as data (envs, policies, seeds, scoring, gate);
- :mod:`~tap_bench.bench.cache`: the episode cache, rollouts stored by what made them;
- :mod:`tap_bench.bench.scores`: a run's scores from the episode table (comparison,
  coverage, novelty, diversity, null, gap, contexts, agreement, verdict);
- :mod:`tap_bench.bench.gate`: ``bench check``, the regression gate and its power;
- :mod:`tap_bench.bench.report`: the report page, its figures and tables, the viewer;
- :mod:`tap_bench.bench.run`: ``bench run`` (plan, tasks, scoring, run folder, a run served
  from the cache) and ``tap-bench demo``.

The statistics (bootstrap, intervals) are :mod:`tap_bench.stats`. Module paths that moved
when ``bench/`` was split (``tap_bench.bench.runner``, ``tap_bench.bench.bootstrap``, ...)
are refused on import with their new path (:data:`MOVED`; docs/benchmark.md, "Module
paths"); the names this package exports are unchanged.
"""

from __future__ import annotations

import importlib
import importlib.abc
import sys
from typing import Any

# Names resolve on first use (PEP 562), so a worker of ``bench run`` that imports
# ``tap_bench.bench.run.tasks`` loads the task modules, not the runner, the gate, the
# scoring and the report; ``from tap_bench.bench import Suite`` works as before.
_LAZY_MODULES = {
    "tap_bench.stats.bootstrap": ("BootstrapConfig",),
    "tap_bench.bench.scores.compare": ("PairedComparison", "matched_by_label", "paired_comparison"),
    "tap_bench.bench.scores.coverage": ("CoverageResult", "Reference", "corpus_reference",
                                        "coverage", "vocabulary_reference"),
    "tap_bench.bench.episodes": ("episode_table", "episodes_from_table"),
    "tap_bench.bench.gate.regression": ("GateResult", "check", "read_baseline", "write_baseline"),
    "tap_bench.bench.measures": ("MEASURES", "Measure", "ego_measures"),
    "tap_bench.bench.scores.novelty": ("NoveltyResult", "novelty"),
    "tap_bench.bench.run.runner": ("RunResult", "read_run", "run_suite"),
    "tap_bench.bench.scores.scenarios": ("match_scenarios",),
    "tap_bench.bench.scores.scoring": ("Scores", "score"),
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


# Module paths of the flat ``bench/`` (before its split into sub-packages), and of modules
# renamed since, and where each module is now: importing an old path raises
# ModuleNotFoundError naming the new one.
MOVED = {
    "tap_bench.bench.agreement": "tap_bench.bench.scores.agreement",
    "tap_bench.bench.bootstrap": "tap_bench.stats.bootstrap",
    "tap_bench.bench.compare": "tap_bench.bench.scores.compare",
    "tap_bench.bench.contexts": "tap_bench.bench.scores.contexts",
    "tap_bench.bench.coverage": "tap_bench.bench.scores.coverage",
    "tap_bench.bench.demo": "tap_bench.bench.run.demo",
    "tap_bench.bench.diversity": "tap_bench.bench.scores.diversity",
    "tap_bench.bench.gap": "tap_bench.bench.scores.gap",
    "tap_bench.bench.gate_stats": "tap_bench.bench.gate.statistics",
    "tap_bench.bench.intervals": "tap_bench.stats.intervals",
    "tap_bench.bench.novelty": "tap_bench.bench.scores.novelty",
    "tap_bench.bench.null": "tap_bench.bench.scores.null",
    "tap_bench.bench.power": "tap_bench.bench.gate.power",
    "tap_bench.bench.report_figures": "tap_bench.bench.report.figures",
    "tap_bench.bench.report_tables": "tap_bench.bench.report.tables",
    "tap_bench.bench.run.summary": "tap_bench.bench.run.scoring",
    "tap_bench.bench.run_cache": "tap_bench.bench.run.served",
    "tap_bench.bench.run_folder": "tap_bench.bench.run.folder",
    "tap_bench.bench.run_pages": "tap_bench.bench.report.pages",
    "tap_bench.bench.run_plan": "tap_bench.bench.run.plan",
    "tap_bench.bench.run_scores": "tap_bench.bench.run.scoring",
    "tap_bench.bench.run_tasks": "tap_bench.bench.run.tasks",
    "tap_bench.bench.runner": "tap_bench.bench.run.runner",
    "tap_bench.bench.scenarios": "tap_bench.bench.scores.scenarios",
    "tap_bench.bench.scoring": "tap_bench.bench.scores.scoring",
    "tap_bench.bench.spill": "tap_bench.bench.run.spill",
    "tap_bench.bench.verdict": "tap_bench.bench.scores.verdict",
    "tap_bench.bench.viewer": "tap_bench.bench.report.viewer",
}


class _MovedFinder(importlib.abc.MetaPathFinder):
    """Answers an import of a moved module path with the path to import instead, rather
    than Python's bare "No module named ..." (a module under a moved package, such as
    ``tap_bench.bench.viewer.build``, is answered for its package, imported first)."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> None:
        new = MOVED.get(fullname)
        if new is None:
            return None
        raise ModuleNotFoundError(
            f"{fullname} moved to {new} (tap_bench.bench is in sub-packages by job): "
            f"import {new} instead (the names of tap_bench.bench itself, e.g. "
            f"'from tap_bench.bench import run_suite', are unchanged)", name=fullname)


if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
    sys.meta_path.append(_MovedFinder())


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
