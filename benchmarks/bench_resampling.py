"""SPEC 4.7: labels of input faster than 10 Hz, resampled on entry, against the same motion
at 10 Hz.

Each trajectory is one continuous motion (integrated at 1 kHz from random controls: a
speed profile with up to three constant accelerations, and straight driving, a turn or a
lane change of random size, timing and side, WOMD-like in their mix). It is sampled at
10 Hz, and at each faster rate (nuPlan's 20 Hz, highD's 25 Hz), with measurement noise
drawn afresh at each rate (heading 0.003 rad, position 0.02 m, speed 0.05 m/s: the size
of WOMD's); :func:`tap_bench.tap` resamples the faster tables on entry. The figure is the
share of trajectories whose SDL label (action level, all four levels reported) equals the
10 Hz one, noise-free and noisy. With noise, two 10 Hz draws of the same motion are the
ceiling (also printed): labels near a threshold flip with the noise whatever the rate; and
each noisy table's labels are compared with the motion's own (noise-free 10 Hz) labels,
where faster input must do no worse than 10 Hz input.

Usage: ``python benchmarks/bench_resampling.py [--n 1000] [--seed 0]``.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import pandas as pd
from machine import report

import tap_bench as tb

FINE = 1000  # [Hz] the continuous motion's integration rate
SECONDS = 9.0


def motions(n: int, rng: np.random.Generator) -> list[tuple[np.ndarray, ...]]:
    """``n`` continuous motions: (t, x, y, heading, speed) at FINE Hz."""
    t = np.arange(0, SECONDS + 1e-9, 1 / FINE)
    out = []
    for _ in range(n):
        v0 = rng.choice([rng.uniform(2, 10), rng.uniform(10, 25), rng.uniform(25, 32)])
        cuts = np.sort(rng.uniform(0, SECONDS, 2))
        acc = rng.normal(0, 1.2, 3) * (rng.random(3) < 0.6)
        a = np.select([t < cuts[0], t < cuts[1]], [acc[0], acc[1]], acc[2])
        speed = np.maximum(v0 + np.cumsum(a) / FINE, 0.0)
        kind = rng.choice(3, p=[0.5, 0.3, 0.2])
        start = rng.uniform(0.5, SECONDS - 3.5)
        yaw = np.zeros_like(t)
        if kind == 1:  # a turn
            dur = rng.uniform(1.5, 5.0)
            yaw = np.where((t >= start) & (t < start + dur),
                           rng.choice([-1, 1]) * rng.uniform(0.03, 0.4), 0.0)
        elif kind == 2:  # a lane change: out and back of the heading
            half = rng.uniform(1.0, 2.5)
            peak = rng.choice([-1, 1]) * rng.uniform(0.04, 0.15)
            yaw = np.where((t >= start) & (t < start + half), peak,
                           np.where((t >= start + half) & (t < start + 2 * half), -peak, 0.0))
        yaw = np.where(speed > 0.5, yaw, 0.0)
        heading = rng.uniform(-np.pi, np.pi) + np.cumsum(yaw) / FINE
        x = np.cumsum(speed * np.cos(heading)) / FINE
        y = np.cumsum(speed * np.sin(heading)) / FINE
        out.append((t, x, y, heading, speed))
    return out


def sample(motion, rate: float, rng: np.random.Generator | None, track: str) -> pd.DataFrame:
    t, x, y, heading, speed = motion
    k = np.round(np.arange(0, SECONDS + 1e-9, 1 / rate) * FINE).astype(int)
    frame = pd.DataFrame({"scenario_id": "s", "track_id": track, "t": t[k], "x": x[k],
                          "y": y[k], "heading": heading[k], "speed": speed[k]})
    if rng is not None:
        m = len(k)
        frame["x"] += rng.normal(0, 0.02, m)
        frame["y"] += rng.normal(0, 0.02, m)
        frame["heading"] += rng.normal(0, 0.003, m)
        frame["speed"] = np.abs(frame["speed"] + rng.normal(0, 0.05, m) * (frame["speed"] > 0))
    frame["heading"] = np.angle(np.exp(1j * frame["heading"]))
    return frame


def labels(frames: list[pd.DataFrame]) -> pd.DataFrame:
    table = pd.concat(frames, ignore_index=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = tb.tap(table, "paper").labels("all")
    return out.set_index(["track_id", "level"])["sdl"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rates", default="20,25")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    all_motions = motions(args.n, rng)
    figures: dict = {"trajectories": args.n}
    cpu0, wall0 = time.process_time(), time.perf_counter()
    clean = None
    for noisy in (False, True):
        noise = np.random.default_rng([args.seed, 1]) if noisy else None
        ref = labels([sample(m, 10.0, noise, f"{i}") for i, m in enumerate(all_motions)])
        clean = ref if clean is None else clean
        block, truth = {}, {}
        if noisy:  # the ceiling: another draw of the noise at 10 Hz
            again = labels([sample(m, 10.0, noise, f"{i}") for i, m in enumerate(all_motions)])
            block["10 Hz, another noise draw"] = _agreement(ref, again)
            truth["10 Hz"] = _agreement(clean, ref)
        for rate in (float(r) for r in args.rates.split(",")):
            got = labels([sample(m, rate, noise, f"{i}") for i, m in enumerate(all_motions)])
            block[f"{rate:g} Hz"] = _agreement(ref, got)
            if noisy:
                truth[f"{rate:g} Hz"] = _agreement(clean, got)
        figures["noisy" if noisy else "noise_free"] = block
        if noisy:
            figures["noisy_against_the_noise_free_10_hz_labels"] = truth
    figures["cpu_s"] = round(time.process_time() - cpu0, 1)
    figures["wall_s"] = round(time.perf_counter() - wall0, 1)
    report("resampling", figures, n=args.n, seed=args.seed, thresholds="paper")


def _agreement(ref: pd.Series, got: pd.Series) -> dict:
    both = pd.concat([ref.rename("ref"), got.rename("got")], axis=1)
    same = (both["ref"] == both["got"]).groupby(level="level").mean()
    return {level: round(float(same[level]), 4) for level in ("trace", "trend", "maneuver",
                                                              "action")}


if __name__ == "__main__":
    main()
