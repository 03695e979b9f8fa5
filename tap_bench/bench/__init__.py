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

from tap_bench.bench.bootstrap import BootstrapConfig
from tap_bench.bench.compare import PairedComparison, matched_by_label, paired_comparison
from tap_bench.bench.coverage import (
    CoverageResult,
    Reference,
    corpus_reference,
    coverage,
    vocabulary_reference,
)
from tap_bench.bench.episodes import episode_table, episodes_from_table
from tap_bench.bench.gate import GateResult, check, read_baseline, write_baseline
from tap_bench.bench.measures import MEASURES, Measure, ego_measures
from tap_bench.bench.novelty import NoveltyResult, novelty
from tap_bench.bench.runner import RunResult, read_run, run_suite
from tap_bench.bench.scenarios import match_scenarios
from tap_bench.bench.scoring import Scores, score
from tap_bench.bench.suite import GateConfig, Suite, available_suites, load_suite

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
