"""Draws docs/figures/interactions.png: the path frame on a curve and a cut-in labelled.

Run it from anywhere: ``python docs/figures/interactions.py [-o OUT.png]`` (a few seconds;
default: next to this script).
Left: on a 60 m circle the ego's path (blue) is the reference line and its corridor
(|d| <= 1.8 m, shaded) follows the curve; a car cuts in from the inner lane (red), a car on
the inner lane stays beside it (grey). Right: the cutter's s and d in the ego's path frame
and the relations TAP labels per step (Free Driving, Cut-in naming the cutter, Following).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from tap_bench.interactions import RELATIONS
from tap_bench.labelling import tap
from tap_bench.pathframe import CORRIDOR_HALF_WIDTH, Paths, path_frame

R = 60.0
T = np.round(np.arange(80) / 10, 10)


def vehicle(tid, s, off, ego=False):
    r = R - off
    x, y = r * np.cos(s / R), r * np.sin(s / R)
    dx, dy = np.gradient(x, T), np.gradient(y, T)
    return pd.DataFrame({"scenario_id": "fig", "track_id": tid, "t": T, "x": x, "y": y,
                         "heading": np.arctan2(dy, dx), "speed": np.hypot(dx, dy),
                         "object_type": "vehicle", "is_ego": ego})


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=Path(__file__).with_suffix(".png"),
                        help="the PNG to write (default: docs/figures/interactions.png)")
    out = parser.parse_args(argv).output
    u = np.clip((T - 2) / 3, 0, 1)
    scene = pd.concat([vehicle("ego", 15 * T, np.zeros_like(T), ego=True),
                       vehicle("cutter", 20 + 15 * T, 2 + 2 * np.cos(np.pi * u)),
                       vehicle("beside", 5 + 15 * T, np.full_like(T, 4.0))],
                      ignore_index=True)
    result = tap(scene, interactions="ego")
    steps = result.steps()
    ego = steps[steps["track_id"] == "ego"]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4.3))
    e = scene[scene["track_id"] == "ego"]
    phi = np.linspace(-0.1, 120 / R + 0.2, 200)
    for side in (-1, 1):
        r = R - side * CORRIDOR_HALF_WIDTH
        ax.plot(r * np.cos(phi), r * np.sin(phi), color="tab:blue", lw=0.6, alpha=0.5)
    ax.plot(e["x"], e["y"], color="tab:blue", lw=2, label="ego path (reference line)")
    for tid, colour in (("cutter", "tab:red"), ("beside", "0.5")):
        v = scene[scene["track_id"] == tid]
        ax.plot(v["x"], v["y"], color=colour, lw=1.5, label=tid)
    k = 45  # t = 4.5 s
    for tid, colour, mark in (("ego", "tab:blue", "o"), ("cutter", "tab:red", "s"),
                              ("beside", "0.5", "s")):
        v = scene[(scene["track_id"] == tid) & np.isclose(scene["t"], T[k])]
        ax.plot(v["x"], v["y"], mark, color=colour, ms=7)
    ax.set_aspect("equal")
    ax.set_title("path frame on a 60 m circle; corridor |d| <= 1.8 m (lines), t = 4.5 s")
    ax.legend(loc="lower left", fontsize=8)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")

    checked_paths = Paths(scene=np.zeros(len(scene), np.int64),
                          key=np.rint(scene["t"].to_numpy() * 10).astype(np.int64),
                          track=pd.factorize(scene["track_id"])[0].astype(np.int64),
                          x=scene["x"].to_numpy(), y=scene["y"].to_numpy(),
                          heading=scene["heading"].to_numpy(),
                          speed=scene["speed"].to_numpy(), start=np.array([0]),
                          stop=np.array([80]))
    frame = path_frame(checked_paths, ahead=60, behind=30, lateral=6)
    cut = checked_paths.track[frame.other] == 1
    t_cut = T[frame.step[cut]]
    bx.plot(t_cut, frame.s[cut], color="tab:red", label="cutter s [m] (ahead)")
    bx.plot(t_cut, frame.d[cut] * 5, color="tab:red", ls="--", label="cutter d x 5 [m]")
    bx.axhline(CORRIDOR_HALF_WIDTH * 5, color="tab:blue", lw=0.6)
    bx.axhline(-CORRIDOR_HALF_WIDTH * 5, color="tab:blue", lw=0.6)
    colours = dict(zip(RELATIONS, plt.cm.Set2(np.arange(len(RELATIONS))), strict=True))
    rel = ego["interaction"].astype(str).to_numpy()
    for start in np.flatnonzero(np.r_[True, rel[1:] != rel[:-1]]):
        stop = start + 1
        while stop < len(rel) and rel[stop] == rel[start]:
            stop += 1
        bx.axvspan(T[start], T[stop - 1] + 0.1, color=colours[rel[start]], alpha=0.5)
        other = ego["other_track_id"].iloc[start]
        text = rel[start] + (f"\n({other})" if pd.notna(other) else "")
        bx.text((T[start] + T[stop - 1]) / 2, 26, text, ha="center", fontsize=8)
    bx.set_ylim(-12, 30)
    bx.set_xlabel("t [s]")
    bx.set_title("the ego's relations per step (runs >= 1 s)")
    bx.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
