"""Similarity search over SDL labels, unique behaviours, and the ADE / DTW baselines.

The TAP paper's sections 4.2, 6.3 and 6.4 and the Scenario2Vector scenario distance
(SPEC section 5), one concept per module:

- :mod:`~tap_bench.similarity.sdl_distance`: g_SDL and Levenshtein distances over label tokens;
- :mod:`~tap_bench.similarity.search`: search within d_sim, all-against-all exact and
  Levenshtein neighbours;
- :mod:`~tap_bench.similarity.unique`: label counts and unique labels at any level;
- :mod:`~tap_bench.similarity.scenario_sdl`: scenario-level SDL and the weighted set distance;
- :mod:`~tap_bench.similarity.shape`: normalised trajectories, ADE and DTW;
- :mod:`~tap_bench.similarity.nearest`: exact ADE / DTW nearest neighbours, pruned;
- :mod:`~tap_bench.similarity.evaluate` and :mod:`~tap_bench.similarity.figures`: the
  paper's experiments on the user's data, as JSON, Markdown and PNG figures.
"""

from __future__ import annotations

from tap_bench.sdl import parse_sdl
from tap_bench.similarity.evaluate import Evaluation, evaluate
from tap_bench.similarity.figures import write_evaluation
from tap_bench.similarity.nearest import (
    Neighbours,
    ade_nearest,
    brute_force_nearest,
    compile_kernels,
    dtw_nearest,
    time_comparisons,
)
from tap_bench.similarity.scenario_sdl import (
    WEIGHTS,
    ScenarioDescription,
    ScenarioSet,
    distance_vector,
    rank_scenarios,
    scenario_distance,
    scenario_set,
)
from tap_bench.similarity.sdl_distance import (
    LabelSet,
    g_sdl,
    label_set,
    sdl_levenshtein,
)
from tap_bench.similarity.search import (
    ExactMatches,
    LabelNeighbours,
    exact_matches,
    levenshtein_nearest,
    search,
    search_like,
)
from tap_bench.similarity.shape import Shapes, ade, dtw, normalised_shapes
from tap_bench.similarity.unique import label_counts, unique_labels

__all__ = [
    # label distances and search
    "ExactMatches",
    "LabelNeighbours",
    "LabelSet",
    "exact_matches",
    "g_sdl",
    "label_set",
    "levenshtein_nearest",
    "parse_sdl",
    "sdl_levenshtein",
    "search",
    "search_like",
    # unique behaviours
    "label_counts",
    "unique_labels",
    # scenario-level SDL
    "WEIGHTS",
    "ScenarioDescription",
    "ScenarioSet",
    "distance_vector",
    "rank_scenarios",
    "scenario_distance",
    "scenario_set",
    # trajectory shapes: ADE and DTW
    "Neighbours",
    "Shapes",
    "ade",
    "ade_nearest",
    "brute_force_nearest",
    "compile_kernels",
    "dtw",
    "dtw_nearest",
    "normalised_shapes",
    "time_comparisons",
    # the paper's experiments
    "Evaluation",
    "evaluate",
    "write_evaluation",
]
