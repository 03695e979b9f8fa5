"""Draws docs/figures/realism_histograms.png: the realism score's histogram features of the
log against idm traffic (and constant velocity), pooled over the traffic of every real scene
we have, on WOSAC 2025's bins.

Run from the project root: ``python docs/figures/realism_histograms.py [--rollouts 4]``
(a few minutes; the real scene files are read from ../shared/data, never copied into the
project). The human drives the ego; every agent valid at 1.0 s but the ego is pooled, over
the simulated window (after 1.0 s).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

from traffic_realism import real_files  # noqa: E402

from tap_bench.realism.rollouts import log_states, scene_features, scene_rollouts  # noqa: E402
from tap_bench.realism.score import HISTOGRAM_FEATURES, WOSAC_2025  # noqa: E402
from tap_bench.sim.policies import load_policy  # noqa: E402
from tap_bench.sim.road_edges import RoadEdges  # noqa: E402
from tap_bench.sim.womd_env import make_womd_env  # noqa: E402
from tap_bench.sim.womd_scene import CURRENT_STEP  # noqa: E402

MODELS = {"log": ("log", "black"), "idm": ("idm", "tab:blue"),
          "constant-velocity": ("constant velocity", "tab:orange")}


def pooled_features(traffic: str, rollouts: int) -> dict[str, np.ndarray]:
    env = make_womd_env(real_files(), traffic=traffic)
    policy = load_policy("log")
    out: dict[str, list] = {f: [] for f in HISTOGRAM_FEATURES}
    for index in range(len(env.catalog)):
        states = scene_rollouts(env, index, policy, rollouts if traffic == "idm" else 1)
        scene = env.scene
        rows = np.flatnonzero(scene.valid[:, CURRENT_STEP] & (np.arange(len(scene.valid))
                                                              != scene.ego))
        edges = RoadEdges.from_polylines(scene.road.road_edges)
        runs = [log_states(scene)] if traffic == "log" else [states]
        for run in runs:
            for k in range(run.rollouts):
                f = scene_features(scene, run.x[k], run.y[k], run.heading[k], run.valid[k],
                                   edges=edges, first=CURRENT_STEP + 1, selves=rows)
                for name in HISTOGRAM_FEATURES:
                    values = f[name][rows, CURRENT_STEP + 1:].ravel()
                    out[name].append(values[np.isfinite(values)])
    return {name: np.concatenate(v) for name, v in out.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rollouts", type=int, default=4)
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" /
                                                      "realism_histograms.png"))
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    data = {m: pooled_features(m, args.rollouts) for m in MODELS}
    fig, axes = plt.subplots(2, 4, figsize=(15, 6.5))
    for ax, name in zip(axes.ravel(), HISTOGRAM_FEATURES, strict=False):
        spec = WOSAC_2025[name]
        edges = np.linspace(spec.low, spec.high, spec.bins + 1)
        for model, (label, colour) in MODELS.items():
            values = np.clip(data[model][name], spec.low, spec.high)
            share, _ = np.histogram(values, edges)
            ax.stairs(share / max(share.sum(), 1), edges, color=colour, label=label,
                      linewidth=2 if model == "log" else 1.4)
        ax.set_title(name.replace("_", " "), fontsize=10)
        ax.set_ylabel("share of steps", fontsize=8)
    axes.ravel()[-1].axis("off")
    axes.ravel()[0].legend(fontsize=8)
    fig.suptitle("Realism features on WOSAC 2025's bins: the log against idm and constant-"
                 "velocity traffic (every real scene, the human as the ego)", fontsize=11)
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
