"""tap-bench: a scenario benchmark toolkit built on TAP, the Trajectory-to-Action Pipeline.

Trajectory table -> kinematics -> TAP labels (four stages) -> similarity, metrics,
comparisons -> report. Each stage has its own module; the names below are the public API.
"""

from __future__ import annotations

from tap_bench._version import __version__ as __version__
from tap_bench.bench import (
    BootstrapConfig,
    check,
    corpus_reference,
    coverage,
    load_suite,
    matched_by_label,
    novelty,
    paired_comparison,
    run_suite,
    vocabulary_reference,
)
from tap_bench.errors import (
    FileFormatError,
    FitWarning,
    LabelTableError,
    ShortSegmentWarning,
    TapBenchError,
    ThresholdsError,
    TrajectoryTableError,
    UnknownNameError,
)
from tap_bench.fitting import FitReport, fit_report, fit_thresholds
from tap_bench.kinematics import Plausibility, compute_kinematics, one_second_samples
from tap_bench.labelling import TapResult, label, tap
from tap_bench.resampling import resample_to_10hz
from tap_bench.sdl import LEVELS, vocabulary
from tap_bench.sim import (
    Policy,
    Rollout,
    available_policies,
    load_policy,
    register_policy,
    rollout,
)
from tap_bench.sim.registration import register_suite as _register_suite
from tap_bench.similarity import (
    ade_nearest,
    dtw_nearest,
    evaluate,
    label_set,
    normalised_shapes,
    rank_scenarios,
    scenario_set,
    search,
    search_like,
    unique_labels,
)
from tap_bench.sources import IngestReport, ingest_womd, iter_womd, read_womd, register_reader
from tap_bench.stages import StageConfig
from tap_bench.synthetic import behaviour, random_trajectories, sample_table
from tap_bench.tableio import read_table, write_table
from tap_bench.thresholds import (
    PRESETS,
    Provenance,
    Thresholds,
    load_thresholds,
    save_thresholds,
)
from tap_bench.trajectories import validate_trajectories
from tap_bench.womd import WomdRecordError, classify_trajectories, write_womd
from tap_bench.womd.validation import validate_womd

# The scenario suite's Gymnasium ids (tap_bench/highway-v0 ...); reads envs/ only, fast.
_register_suite()

__all__ = [
    # errors
    "FileFormatError",
    "FitWarning",
    "LabelTableError",
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
    # Waymo Open Motion Dataset (tap_bench.womd)
    "IngestReport",
    "WomdRecordError",
    "classify_trajectories",
    "ingest_womd",
    "iter_womd",
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
