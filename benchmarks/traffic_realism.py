"""Does idm traffic drive like the people it replaces? (issue 33's before/after figures)

On every real scene we have (../shared/data/womd/*.tfrecord and *.pkl,
../shared/data/womd-dev/dev.tfrecord; absent files are skipped) this runs idm traffic with
the human as the ego (policy ``log``) and with an IDM ego (policy ``idm``), ``--rollouts``
rollouts each (reset option ``rollout=k``), and measures over the simulated window (after
the current time, 1.0 s) on the vehicles idm drives, against the same vehicles over the
same steps in the log:

- **collision share**: vehicles whose box overlaps another valid agent's box at some step,
  pairs already overlapping at the current time (the record's own boxes) aside;
- **hard braking**: share of steps with the acceleration (speed difference per step,
  smoothed over 5 steps) below -4 m/s^2;
- **zero acceleration**: share of steps whose speed did not change at all (the log's speeds
  are measured, so exactly zero is rare there);
- **KS** of speed and of acceleration (two-sample Kolmogorov-Smirnov statistic, pooled over
  vehicles and steps).

Usage: ``python benchmarks/traffic_realism.py [--rollouts K] [--out FILE.json]``
"""

from __future__ import annotations

import argparse
import glob
import os
import time
import warnings
from pathlib import Path

import numpy as np
from machine import report

from tap_bench.realism.features import overlapping_pairs
from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_scene import CURRENT_STEP

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
HARD_BRAKING = -4.0  # [m/s^2]
SMOOTHING = 5  # steps


def real_files() -> list[str]:
    """Every real scene file we have (absent ones skipped)."""
    files = sorted(glob.glob(str(DATA / "womd" / "*.tfrecord")))
    files += sorted(glob.glob(str(DATA / "womd" / "*.pkl")))
    dev = DATA / "womd-dev" / "dev.tfrecord"
    if dev.exists():
        files.append(str(dev))
    return files


def acceleration(speed: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(raw, smoothed) acceleration per step [m/s^2], (n, T), NaN where undefined: the raw
    one is (v[k] - v[k-1]) / dt, the smoothed one its centred mean over SMOOTHING steps."""
    raw = np.full(speed.shape, np.nan)
    raw[:, 1:] = np.diff(speed, axis=1) / dt
    smooth = np.full(speed.shape, np.nan)
    h = SMOOTHING // 2
    for k in range(h, speed.shape[1] - h):
        smooth[:, k] = raw[:, k - h:k + h + 1].mean(axis=1)  # NaN when any step is
    return raw, smooth


def ks(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sample Kolmogorov-Smirnov statistic (NaN dropped)."""
    a = np.sort(a[np.isfinite(a)])
    b = np.sort(b[np.isfinite(b)])
    if not len(a) or not len(b):
        return float("nan")
    grid = np.concatenate([a, b])
    fa = np.searchsorted(a, grid, side="right") / len(a)
    fb = np.searchsorted(b, grid, side="right") / len(b)
    return float(np.abs(fa - fb).max())


def collided(scene, x, y, heading, valid, rows) -> np.ndarray:
    """Whether each of ``rows`` overlaps another agent after the current time, pairs that
    overlap in the log at the current time aside."""
    length, width = np.asarray(scene.length, float), np.asarray(scene.width, float)
    start = overlapping_pairs(scene.x[:, CURRENT_STEP:CURRENT_STEP + 1],
                              scene.y[:, CURRENT_STEP:CURRENT_STEP + 1],
                              scene.heading[:, CURRENT_STEP:CURRENT_STEP + 1],
                              scene.valid[:, CURRENT_STEP:CURRENT_STEP + 1], length, width)
    exempt = {(int(i), int(j)) for _, i, j in start}
    w = slice(CURRENT_STEP + 1, x.shape[1])
    pairs = overlapping_pairs(x[:, w], y[:, w], heading[:, w], valid[:, w], length, width)
    hit = set()
    for _, i, j in pairs:
        if (int(i), int(j)) not in exempt:
            hit.update((int(i), int(j)))
    return np.array([r in hit for r in rows], bool)


def measure(files: list[str], ego: str, rollouts: int) -> dict:
    env = make_womd_env(files, traffic="idm")
    policy = load_policy(ego)
    sim = {"collided": [], "hard": [], "zero": [], "speed": [], "acc": [], "n_steps": 0}
    log = {"collided": [], "hard": [], "zero": [], "speed": [], "acc": []}
    cpu = 0.0
    per_scene = []
    for index in range(len(env.catalog)):
        for k in range(rollouts):
            t0 = os.times()
            try:
                obs, _ = env.reset(seed=index, options={"rollout": k})
            except Exception as err:  # a scene that cannot be driven is reported, not fatal
                per_scene.append({"scene": str(env.catalog[index]), "error": str(err)})
                break
            policy.reset(env, seed=index)
            done = False
            while not done:
                obs, _, terminated, truncated, _ = env.step(policy.act(obs))
                done = terminated or truncated
            t1 = os.times()
            cpu += t1.user + t1.system - t0.user - t0.system
            scene = env.scene
            rows = np.array(sorted(env.unwrapped.simulated), np.int64)
            if not len(rows):
                continue
            rec = env.recorded_states()
            dt = float(np.median(np.diff(scene.times)))
            w = slice(CURRENT_STEP + 1, scene.n_steps)
            for where, (x, y, h, v, speed) in (
                    (sim, (rec["x"], rec["y"], rec["heading"], rec["valid"], rec["speed"])),
                    (log, (scene.x, scene.y, scene.heading, scene.valid, scene.speed))):
                if where is log and k > 0:
                    continue  # the log is the same in every rollout
                where["collided"].append(collided(scene, x, y, h, v, rows))
                raw, smooth = acceleration(np.where(v, speed, np.nan)[rows], dt)
                where["hard"].append((smooth[:, w] < HARD_BRAKING)[np.isfinite(smooth[:, w])])
                where["zero"].append((raw[:, w] == 0)[np.isfinite(raw[:, w])])
                where["speed"].append(np.where(v, speed, np.nan)[rows][:, w].ravel())
                where["acc"].append(raw[:, w].ravel())
            per_scene.append({"scene": scene.scenario_id, "rollout": k,
                              "simulated": len(rows),
                              "collided": int(sim["collided"][-1].sum()),
                              "collided_log": int(collided(scene, scene.x, scene.y,
                                                           scene.heading, scene.valid,
                                                           rows).sum())})
    out = {}
    for name, where in (("sim", sim), ("log", log)):
        c = np.concatenate(where["collided"])
        out[f"{name}_vehicles"] = len(c)
        out[f"{name}_collision_share"] = float(c.mean())
        out[f"{name}_hard_braking_share"] = float(np.concatenate(where["hard"]).mean())
        out[f"{name}_zero_acceleration_share"] = float(np.concatenate(where["zero"]).mean())
    out["speed_ks"] = ks(np.concatenate(sim["speed"]), np.concatenate(log["speed"]))
    out["acceleration_ks"] = ks(np.concatenate(sim["acc"]), np.concatenate(log["acc"]))
    out["cpu_seconds"] = cpu
    out["scenes"] = per_scene
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rollouts", type=int, default=1)
    parser.add_argument("--name", default="traffic_realism")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    files = real_files()
    wall = time.perf_counter()
    figures = {"files": files, "rollouts": args.rollouts}
    for ego in ("log", "idm"):
        figures[f"ego_{ego}"] = measure(files, ego, args.rollouts)
    figures["wall_seconds"] = time.perf_counter() - wall
    for ego in ("log", "idm"):
        f = figures[f"ego_{ego}"]
        print(f"ego {ego}: {f['sim_vehicles']} simulated vehicle-rollouts; collide "
              f"{f['sim_collision_share']:.1%} (log {f['log_collision_share']:.1%}); hard "
              f"braking {f['sim_hard_braking_share']:.2%} of steps (log "
              f"{f['log_hard_braking_share']:.2%}); zero acceleration "
              f"{f['sim_zero_acceleration_share']:.1%} (log "
              f"{f['log_zero_acceleration_share']:.1%}); KS speed {f['speed_ks']:.3f}, "
              f"acceleration {f['acceleration_ks']:.3f}; {f['cpu_seconds']:.1f} CPU s")
    report(args.name, figures, seed=0)


if __name__ == "__main__":
    main()
