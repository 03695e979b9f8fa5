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

import importlib
import sys
import types
from typing import Any

from tap_bench.sdl import parse_sdl
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
from tap_bench.similarity.unique import label_counts, unique_labels

_LAZY = {  # name: module. These need numba and are imported when first used: the runner's
    # workers and the scoring, which need only the label distances, do not load it
    "Evaluation": "evaluate", "evaluate": "evaluate", "write_evaluation": "figures",
    "Neighbours": "nearest", "ade_nearest": "nearest", "brute_force_nearest": "nearest",
    "compile_kernels": "nearest", "dtw_nearest": "nearest", "time_comparisons": "nearest",
    "Shapes": "shape", "ade": "shape", "dtw": "shape", "normalised_shapes": "shape",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(f"tap_bench.similarity.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'tap_bench.similarity' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


class _Package(types.ModuleType):
    """``tap_bench.similarity.evaluate`` is the function that ``from tap_bench.similarity
    import evaluate`` promises, also after its submodule has been imported (the import
    system then sets the package's attribute to the submodule, which is refused here; the
    submodule stays in ``sys.modules``)."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in _LAZY and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

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
