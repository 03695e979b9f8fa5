"""tap-bench: a scenario benchmark toolkit built on TAP, the Trajectory-to-Action Pipeline.

Trajectory table -> kinematics -> TAP labels (four stages) -> similarity, metrics,
comparisons -> report. Each stage has its own module; the names below are the public API.
"""

from __future__ import annotations

import importlib
import importlib.util
from typing import Any

from tap_bench._version import __version__ as __version__
from tap_bench.errors import (
    FileFormatError,
    FitWarning,
    LabelTableError,
    ResampledWarning,
    ShortSegmentWarning,
    TapBenchError,
    ThresholdsError,
    TrajectoryTableError,
    UnknownNameError,
)
from tap_bench.sim.registration import register_on_import as _register_on_import

# The public API by module, imported on first use: `import tap_bench` (and so every
# `tap-bench` command) pays only for what it touches, not for pandas, highway-env and numba
# at once. `from tap_bench import X` and `tap_bench.X` work as with eager imports.
_LAZY_MODULES = {
    "tap_bench.bench": ("BootstrapConfig", "check", "corpus_reference", "coverage",
                        "load_suite", "matched_by_label", "novelty", "paired_comparison",
                        "run_suite", "vocabulary_reference"),
    "tap_bench.fitting": ("FitReport", "fit_report", "fit_thresholds"),
    "tap_bench.kinematics": ("Plausibility", "compute_kinematics", "one_second_samples"),
    "tap_bench.labelling": ("TapResult", "label", "tap"),
    "tap_bench.resampling": ("resample_to_10hz",),
    "tap_bench.sdl": ("LEVELS", "vocabulary"),
    # the defining modules, not tap_bench.sim, whose attribute "rollout" is also a submodule
    "tap_bench.sim.policies": ("Policy", "available_policies", "load_policy",
                               "register_policy"),
    "tap_bench.sim.rollout": ("Rollout", "rollout"),
    "tap_bench.similarity": ("ade_nearest", "dtw_nearest", "evaluate", "label_set",
                             "normalised_shapes", "rank_scenarios", "scenario_set", "search",
                             "search_like", "unique_labels"),
    "tap_bench.sources": ("IngestReport", "check_reader", "ingest_driving_data", "ingest_womd",
                          "iter_driving_data", "iter_womd", "read_driving_data", "read_womd",
                          "register_reader"),
    "tap_bench.plugins": ("load_plugins",),
    "tap_bench.stages": ("StageConfig",),
    "tap_bench.synthetic": ("behaviour", "random_trajectories", "sample_table"),
    "tap_bench.tableio": ("read_table", "write_table"),
    "tap_bench.thresholds": ("PRESETS", "Provenance", "Thresholds", "load_thresholds",
                             "save_thresholds"),
    "tap_bench.trajectories": ("validate_trajectories",),
    "tap_bench.womd": ("WomdRecordError", "classify_trajectories", "write_womd"),
    "tap_bench.womd.validation": ("validate_womd",),
}
_LAZY = {name: module for module, names in _LAZY_MODULES.items() for name in names}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        if not name.startswith("_") and importlib.util.find_spec(f"tap_bench.{name}"):
            return importlib.import_module(f"tap_bench.{name}")  # tap_bench.bench.Suite
        raise AttributeError(f"module 'tap_bench' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # the next access is a plain attribute
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


# The scenario suite's Gymnasium ids (tap_bench/highway-v0 ...): now if Gymnasium is
# imported, else when it is (so a command that needs no env never imports it); reads envs/
# only, fast.
_register_on_import()

__all__ = [
    # errors
    "FileFormatError",
    "FitWarning",
    "LabelTableError",
    "ResampledWarning",
    "ShortSegmentWarning",
    "TapBenchError",
    "ThresholdsError",
    "TrajectoryTableError",
    "UnknownNameError",
    # data contracts and files
    "read_table",
    "resample_to_10hz",
    "validate_trajectories",
    "write_table",
    # kinematics
    "Plausibility",
    "compute_kinematics",
    "one_second_samples",
    # TAP labelling
    "LEVELS",
    "StageConfig",
    "TapResult",
    "label",
    "tap",
    "vocabulary",
    # thresholds
    "PRESETS",
    "FitReport",
    "Provenance",
    "Thresholds",
    "fit_report",
    "fit_thresholds",
    "load_thresholds",
    "save_thresholds",
    # synthetic data
    "behaviour",
    "random_trajectories",
    "sample_table",
    # simulation: highway-env scenarios (gymnasium.make("tap_bench/highway-v0")), policies,
    # rollouts; more in tap_bench.sim
    "Policy",
    "Rollout",
    "available_policies",
    "load_policy",
    "register_policy",
    "rollout",
    # driving data of any registered format (tap_bench.sources), WOMD (tap_bench.womd)
    "IngestReport",
    "WomdRecordError",
    "check_reader",
    "classify_trajectories",
    "ingest_driving_data",
    "ingest_womd",
    "iter_driving_data",
    "iter_womd",
    "load_plugins",
    "read_driving_data",
    "read_womd",
    "register_reader",
    "validate_womd",
    "write_womd",
    # similarity: SDL search, unique behaviours, scenario-level SDL, the ADE / DTW baselines
    # and the paper's experiments; more in tap_bench.similarity
    "ade_nearest",
    "dtw_nearest",
    "evaluate",
    "label_set",
    "normalised_shapes",
    "rank_scenarios",
    "scenario_set",
    "search",
    "search_like",
    "unique_labels",
    # the benchmark (tap_bench.bench): matched comparison, coverage, unique manoeuvres,
    # suite runs and the regression gate; more in tap_bench.bench
    "BootstrapConfig",
    "check",
    "corpus_reference",
    "coverage",
    "load_suite",
    "matched_by_label",
    "novelty",
    "paired_comparison",
    "run_suite",
    "vocabulary_reference",
]
