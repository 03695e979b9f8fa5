"""The learning curves of an agent trained on real scenes (``tap-bench train --env womd
--log-dir DIR``), on the scenes it trained on and on those it never saw.

Every saved checkpoint (``DIR/weights_<steps>_steps.zip``, ``--every``-th of them, and the
final model) of every training seed drives every scene of the files once, in the traffic it
trained in (its definition's ``traffic``, log or idm); per checkpoint, the route progress
(mean over the scenes where the human moved), the at-fault collision rate and the off-road
rate, on the training scenes and on the held-out ones (read from the model's definition).
Beside them, the training return per update from SB3's log (``DIR/progress.csv``). Writes
``<name>.curve.csv`` and ``<name>.curve.png`` beside the group's definition.

Usage: python benchmarks/agents_learning_curve.py policies/ppo-womd.json --log-dirs
       /tmp/log-seed0 /tmp/log-seed1 /tmp/log-seed2 [--every 2]
"""

from __future__ import annotations

import argparse
import json
import re
import time
import warnings
from pathlib import Path

import pandas as pd
from machine import report

from tap_bench.sim.rollout import rollout
from tap_bench.sim.womd_scene import WomdScenes


def checkpoints(log_dir: Path, every: int) -> list[tuple[int, Path]]:
    """(steps, file) of the saved checkpoints, every ``every``-th, in order."""
    found = sorted((int(re.search(r"weights_(\d+)_steps", p.name).group(1)), p)
                   for p in log_dir.glob("weights_*_steps.zip"))
    return found[every - 1::every]


def describe_checkpoint(model: Path, definition: Path) -> None:
    """Write the checkpoint's definition beside it: the final model's (its observation
    config above all), naming the checkpoint, unless one is there."""
    beside = model.with_suffix(".json")
    if beside.exists():
        return
    doc = json.loads(definition.read_text())
    doc["name"] = model.stem
    doc["params"]["model"] = model.name
    beside.write_text(json.dumps(doc, indent=2) + "\n")


def evaluate(model: Path, scenes: WomdScenes, held_out: set[int]) -> dict[str, float]:
    """The checkpoint's figures on the training and held-out scenes."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        eps = rollout(scenes, str(model), "all", record=False).episodes
    eps = eps[eps["status"] == "ok"]
    out = {}
    for part, mask in (("train", ~eps["seed"].isin(held_out)),
                       ("held_out", eps["seed"].isin(held_out))):
        rows = eps[mask]
        out[f"{part}_route_progress"] = float(rows["route_progress"].mean())
        # the episode table's crash_fault: "at fault", or why not (SPEC section 8)
        out[f"{part}_at_fault"] = float((rows["crash_fault"] == "at fault").mean())
        out[f"{part}_off_road"] = float(rows["off_road"].astype(float).mean())
        out[f"{part}_scenes"] = len(rows)
    return out


def plot(curve: pd.DataFrame, training: pd.DataFrame, path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), dpi=100)
    for seed, rows in training.groupby("seed"):
        axes[0].plot(rows["timesteps"], rows["return"], label=f"seed {seed}")
    axes[0].set_title("training return (per update)")
    for k, (measure, name) in enumerate((("route_progress", "route progress"),
                                         ("at_fault", "at-fault collision rate")), start=1):
        for seed, rows in curve.groupby("seed"):
            line, = axes[k].plot(rows["timesteps"], rows[f"train_{measure}"], marker="o",
                                 label=f"seed {seed}, training scenes")
            axes[k].plot(rows["timesteps"], rows[f"held_out_{measure}"], marker="s",
                         linestyle="--", color=line.get_color(),
                         label=f"seed {seed}, held-out scenes")
        axes[k].set_title(name)
        axes[k].set_ylim(-0.02, 1.02)
    for ax in axes:
        ax.set_xlabel("training steps")
    axes[2].legend(fontsize=7)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, format="png")
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("group", help="the seed group's definition (policies/ppo-womd.json)")
    parser.add_argument("--log-dirs", nargs="+", required=True,
                        help="the --log-dir of each seed, in the group's seed order")
    parser.add_argument("--every", type=int, default=2, help="every n-th checkpoint")
    parser.add_argument("--root", help="the folder the training ran in, which its relative "
                        "--womd paths start from (default: the group's folder's parent, the "
                        "project root for policies/)")
    args = parser.parse_args()
    group = Path(args.group)
    seeds = json.loads(group.read_text())["params"]["seeds"]
    rows, training, traffics = [], [], set()
    start = time.process_time()
    for name, log_dir in zip(seeds, args.log_dirs, strict=True):
        final = group.parent / f"{name}.zip"
        params = json.loads(final.with_suffix(".json").read_text())["params"]
        root = Path(args.root) if args.root else group.parent.parent
        files = [f if Path(f).is_absolute() else str(root / f) for f in params["womd"]]
        scenes = WomdScenes(tuple(files), traffic=params["traffic"])
        traffics.add(params["traffic"])
        held_out = set(params.get("held_out_scenes", []))
        points = [*checkpoints(Path(log_dir), args.every), (params["timesteps"], final)]
        for _, model in points[:-1]:  # a checkpoint reads what the model reads
            describe_checkpoint(model, final.with_suffix(".json"))
        for steps, model in points:
            figures = evaluate(model, scenes, held_out)
            rows.append({"seed": params["seed"], "policy": name, "timesteps": steps,
                         **figures})
            print(f"{name} at {steps} steps: " + ", ".join(
                f"{k} {v:.3f}" for k, v in figures.items() if not k.endswith("scenes")),
                flush=True)
        log = pd.read_csv(Path(log_dir) / "progress.csv")
        training.append(pd.DataFrame({"seed": params["seed"],
                                      "timesteps": log["time/total_timesteps"],
                                      "return": log["rollout/ep_rew_mean"],
                                      "episode_length": log["rollout/ep_len_mean"]}))
    curve = pd.DataFrame(rows)
    stem = group.with_suffix("")
    curve.to_csv(f"{stem}.curve.csv", index=False)
    pd.concat(training).to_csv(f"{stem}.training.csv", index=False)
    plot(curve, pd.concat(training), Path(f"{stem}.curve.png"),
         f"{group.stem}: {len(seeds)} training seeds; solid: training scenes, dashed: "
         f"held-out scenes ({' and '.join(sorted(traffics))} traffic)")
    last = curve.groupby("seed").tail(1)
    report("agents_learning_curve", {
        **{f"{r['policy']}_{k}": round(v, 4) for r in last.to_dict("records")
           for k, v in r.items() if k.startswith(("train_", "held_out_"))},
        "cpu_seconds": round(time.process_time() - start, 1)}, seed=0)


if __name__ == "__main__":
    main()
