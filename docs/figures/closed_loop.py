"""Draws docs/figures/closed_loop.png: one recorded WOMD scene driven by IDM beside the human.

Run it from anywhere: ``python docs/figures/closed_loop.py [SCENE_FILE] [-o OUT.png]`` (a
few seconds; default scene: ``womd_scenario_input.tfrecord`` of ``../shared/data/womd``
beside the project, the real sample files are not part of it; default output: next to this
script). The map (lane centre lines, road edges, crosswalks, signals at 1.0 s), the other
road users at 1.0 s and their logged paths, the human's path (the policy ``log``, dashed)
and the paths IDM/MOBIL and lane keeping drove in its place with the others replaying the
log (IDM wide and light under lane keeping, so both show where they coincide), each with its
TAP label. It prints what it drew, the facts the caption in docs/closed_loop.md states.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from tap_bench.labelling import label
from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_scene import CURRENT_STEP

ROOT = Path(__file__).resolve().parents[2]
DEFAULT = ROOT / ".." / "shared" / "data" / "womd" / "womd_scenario_input.tfrecord"
COLOURS = {"log": "black", "idm": "tab:blue", "lane-keeping": "tab:orange"}
SIGNAL = {1: "red", 4: "red", 2: "gold", 5: "gold", 3: "green", 6: "green"}


def drive(env, policy: str):
    p = load_policy(policy)
    obs, _ = env.reset(seed=0)
    p.reset(env, seed=0)
    done = False
    while not done:
        obs, _, term, trunc, _ = env.step(p.act(obs))
        done = term or trunc
    table = env.trajectories(policy=policy)
    ego = table[table["is_ego"].to_numpy(bool)]
    sdl = label(ego.drop(columns=["policy", "env", "seed", "source"]),
                level="maneuver")["sdl"].iloc[0]
    return ego, sdl, env.episode_info()


STYLE = {"log": {"ls": "--", "lw": 2.2, "alpha": 1.0, "zorder": 8},
         "idm": {"ls": "-", "lw": 5.0, "alpha": 0.45, "zorder": 6},
         "lane-keeping": {"ls": "-", "lw": 1.6, "alpha": 1.0, "zorder": 7}}


def main(argv: list[str] | None = None) -> dict[str, dict[str, Any]]:
    """Draw the figure; return per policy what it shows (label, mean distance to the human
    [m], route progress, crashed)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", nargs="?", type=Path, default=DEFAULT,
                        help="a WOMD file (its first scenario is drawn)")
    parser.add_argument("-o", "--output", type=Path, default=Path(__file__).with_suffix(".png"),
                        help="the PNG to write (default: docs/figures/closed_loop.png)")
    args = parser.parse_args(argv)
    path = args.scene
    if not path.is_file():
        raise SystemExit(f"{path}: no such file (the real WOMD samples live outside the "
                         "project, in ../shared/data/womd).")
    env = make_womd_env(str(path))
    runs = {policy: drive(env, policy) for policy in ("log", "idm", "lane-keeping")}
    scene = env.scene
    ego_xy = np.c_[scene.x[scene.ego], scene.y[scene.ego]]
    ego_xy = ego_xy[np.isfinite(ego_xy).all(axis=1)]
    centre = ego_xy.mean(axis=0)
    half = max(35.0, float(np.abs(ego_xy - centre).max()) + 15.0)

    fig, ax = plt.subplots(figsize=(8.5, 7.2))
    road = scene.road
    for lane in road.lanes.values():
        if len(lane.centre) >= 2:
            ax.plot(*lane.centre.T, color="0.82", lw=0.8, zorder=1)
    for edge in road.road_edges:
        ax.plot(*edge.T, color="0.25", lw=1.2, zorder=2)
    for polygon in road.crosswalks:
        closed = np.vstack([polygon, polygon[:1]])
        ax.fill(*closed.T, color="0.9", hatch="////", ec="0.6", lw=0.5, zorder=1)
    signals = road.signals
    if len(signals.lane):
        for (x, y), state in zip(signals.stop_point, signals.state[CURRENT_STEP],
                                 strict=True):
            ax.plot(x, y, "o", ms=6, color=SIGNAL.get(int(state), "0.6"), mec="k", zorder=5)
    for row in range(len(scene.track_ids)):
        if row == scene.ego:
            continue
        xy = np.c_[scene.x[row], scene.y[row]]
        ok = np.isfinite(xy).all(axis=1)
        if not ok.any():
            continue
        walker = scene.object_types[row] != "vehicle"
        ax.plot(*xy[ok].T, color="tab:green" if walker else "0.55", lw=0.6, alpha=0.6,
                zorder=3)
        if scene.valid[row, CURRENT_STEP]:
            ax.plot(*xy[CURRENT_STEP], "s" if not walker else "o", ms=4,
                    color="tab:green" if walker else "0.4", zorder=4)
    facts = {}
    for policy, (ego, sdl, info) in runs.items():
        xy = ego[["x", "y"]].to_numpy()
        future = ego["t"].to_numpy() >= CURRENT_STEP / 10 - 1e-9
        name = "human (log)" if policy == "log" else policy
        # the mean distance to the human over the steps it drove (the episode table's
        # log_ade is NaN for an episode that ended early: SPEC section 8)
        facts[policy] = {"sdl": sdl, "distance": float(ego["log_distance"].mean()),
                         "route_progress": info["route_progress"],
                         "crashed": bool(ego["crashed"].any()),
                         "off_road": bool(info["off_road"]),
                         "ended_early": bool(ego["ended_early"].fillna(False).any())}
        extra = "" if policy == "log" else (
            f"; {facts[policy]['distance']:.1f} m from the human's path, progress "
            f"{info['route_progress']:.2f}"
            + (", crashed" if facts[policy]["crashed"] else "")
            + (", off road" if facts[policy]["off_road"] else ""))
        style = STYLE[policy]
        ax.plot(*xy[future].T, style["ls"], color=COLOURS[policy], lw=style["lw"],
                alpha=style["alpha"], label=f"{name}: {sdl}{extra}", zorder=style["zorder"])
        ax.plot(*xy[future][-1], ">", color=COLOURS[policy], ms=7, zorder=9)
    ax.plot(*ego_xy[CURRENT_STEP], "o", color="crimson", ms=8, zorder=10,
            label="the ego at 1.0 s, where the policy takes over")
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"WOMD scenario {scene.scenario_id}, log traffic: a policy beside the human",
                 fontsize=10)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.09), fontsize=8, frameon=False)
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")
    for policy, fact in facts.items():
        print(f"{policy}: {fact['sdl']}; mean distance {fact['distance']:.1f} m, route "
              f"progress {fact['route_progress']:.2f}{', crashed' if fact['crashed'] else ''}"
              f"{', off road' if fact['off_road'] else ''}"
              f"{', ended early' if fact['ended_early'] else ''}")
    return facts


if __name__ == "__main__":
    main()
