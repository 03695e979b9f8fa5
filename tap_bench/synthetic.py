"""Synthetic trajectories: hand-shaped behaviours and large random sets, with no data to fetch.

Used by ``tap-bench sample``, the tests (behaviour fixtures) and the benchmarks. A trajectory
is built from controls: a speed profile and a yaw-rate profile at 10 Hz, integrated into
position and heading on WOMD axes (y to the left, heading counter-clockwise).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tap_bench.errors import ParameterError, did_you_mean
from tap_bench.trajectories import DT

__all__ = ["BEHAVIOURS", "behaviour", "from_controls", "on_road", "random_trajectories",
           "road_scene", "sample_table"]


def from_controls(speed: np.ndarray, yaw_rate: np.ndarray, *, scenario_id: str = "synthetic",
                  track_id: str = "0", t0: float = 0.0, x0: float = 0.0, y0: float = 0.0,
                  heading0: float = 0.0) -> pd.DataFrame:
    """A trajectory table of one track from its controls.

    Args:
        speed: (n,) speed at each step [m/s], >= 0.
        yaw_rate: (n,) yaw rate at each step [rad/s]; positive turns left.
        scenario_id, track_id: identifiers of the track.
        t0, x0, y0, heading0: initial time [s], position [m] and heading [rad].

    Returns:
        n rows: scenario_id, track_id, t, x, y, heading (wrapped to (-pi, pi]), speed.
        Heading integrates the yaw rate so that heading[k+1] - heading[k] = yaw_rate[k]*DT;
        central differences then recover yaw_rate exactly wherever it is constant.
    """
    speed = np.asarray(speed, dtype=np.float64)
    yaw_rate = np.asarray(yaw_rate, dtype=np.float64)
    n = len(speed)
    if len(yaw_rate) != n:
        raise ParameterError("yaw_rate", len(yaw_rate), "",
            message=f"speed has {n} steps but yaw_rate has {len(yaw_rate)}")
    heading = heading0 + np.concatenate([[0.0], np.cumsum(yaw_rate[:-1]) * DT])
    x = x0 + np.concatenate([[0.0], np.cumsum(speed[:-1] * np.cos(heading[:-1])) * DT])
    y = y0 + np.concatenate([[0.0], np.cumsum(speed[:-1] * np.sin(heading[:-1])) * DT])
    return pd.DataFrame({
        "scenario_id": scenario_id, "track_id": str(track_id),
        "t": t0 + np.arange(n) * DT, "x": x, "y": y,
        "heading": np.angle(np.exp(1j * heading)), "speed": speed,
    })


def _steps(seconds: float) -> int:
    return round(seconds / DT)


def _profile(*pieces: tuple[float, float]) -> np.ndarray:
    """Concatenate (duration [s], value) pieces into a per-step profile."""
    return np.concatenate([np.full(_steps(d), v, dtype=np.float64) for d, v in pieces])


def _ramp(v0: float, accel: float, seconds: float) -> np.ndarray:
    """Speed rising (or falling) at a constant rate from v0, per step [m/s]."""
    return np.maximum(v0 + accel * DT * np.arange(_steps(seconds)), 0.0)


def _cruise(v: float, seconds: float = 9.1) -> tuple[np.ndarray, np.ndarray]:
    n = _steps(seconds)
    return np.full(n, v), np.zeros(n)


def _turn(w: float, v: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    """3 s straight, 3 s turning at yaw rate w, 3.1 s straight."""
    yaw = _profile((3.0, 0.0), (3.0, w), (3.1, 0.0))
    return np.full(len(yaw), v), yaw


def _lane_change(side: int, pause: float = 0.0, w: float = 0.12,
                 v: float = 15.0) -> tuple[np.ndarray, np.ndarray]:
    """Straight, turn towards ``side`` (+1 left) for 1.5 s, a straight pause, turn back."""
    yaw = _profile((2.0, 0.0), (1.5, side * w), (pause, 0.0), (1.5, -side * w),
                   (4.1 - pause, 0.0))
    return np.full(len(yaw), v), yaw


def _two_turns() -> tuple[np.ndarray, np.ndarray]:
    """Left turn, 4.5 s straight, right turn: too far apart to be a merge (10.5 s)."""
    yaw = _profile((1.5, 0.0), (1.5, 0.1), (4.5, 0.0), (1.5, -0.1), (1.5, 0.0))
    return np.full(len(yaw), 8.0), yaw


def _stop_and_go() -> tuple[np.ndarray, np.ndarray]:
    """Cruise at 8 m/s, brake at -2.5 m/s^2 to a stop, wait, pull away at +2 m/s^2."""
    speed = np.concatenate([np.full(10, 8.0), _ramp(8.0, -2.5, 3.2), np.zeros(25),
                            _ramp(0.0, 2.0, 2.4)])
    speed = np.concatenate([speed, np.full(91 - len(speed), speed[-1])])
    return speed, np.zeros(len(speed))


def _accelerate_through_bands() -> tuple[np.ndarray, np.ndarray]:
    """From 5 m/s at +3 m/s^2 for 8 s, then 1.1 s at constant speed: Slow, Medium, Fast."""
    speed = np.concatenate([_ramp(5.0, 3.0, 8.0), np.full(11, 5.0 + 3.0 * 7.9)])
    return speed, np.zeros(len(speed))


def _hard_brake() -> tuple[np.ndarray, np.ndarray]:
    """Cruise at 26 m/s, brake at -4 m/s^2 for 2 s (0.5 s of it still Fast), then cruise."""
    speed = np.concatenate([np.full(30, 26.0), _ramp(26.0, -4.0, 2.0), np.full(41, 18.0)])
    return speed, np.zeros(len(speed))


def _flicker() -> tuple[np.ndarray, np.ndarray]:
    """Straight cruise with a 0.4 s yaw-rate blip of 0.05 rad/s: the low-pass removes it."""
    yaw = _profile((4.0, 0.0), (0.4, 0.05), (4.7, 0.0))
    return np.full(len(yaw), 12.0), yaw


def _u_turn() -> tuple[np.ndarray, np.ndarray]:
    """1.5 s straight, a U-turn at 0.5 rad/s for 6.3 s (3.15 rad, radius 8 m), 1.3 s
    straight, at 4 m/s."""
    yaw = _profile((1.5, 0.0), (6.3, 0.5), (1.3, 0.0))
    return np.full(len(yaw), 4.0), yaw


def _turn_exit_overshoot() -> tuple[np.ndarray, np.ndarray]:
    """A 2 rad left turn (0.5 rad/s for 4 s) with a counter-steer of -0.1 rad/s for 1.2 s
    at its exit, at 6 m/s: a turn, not a merge (the heading does not come back)."""
    yaw = _profile((1.5, 0.0), (4.0, 0.5), (1.2, -0.1), (2.4, 0.0))
    return np.full(len(yaw), 6.0), yaw


def _s_curve() -> tuple[np.ndarray, np.ndarray]:
    """Left 0.8 rad (0.4 rad/s for 2 s), at once right 0.8 rad, at 8 m/s: the heading comes
    back and the road moves sideways by 8 m, but it turned farther than a lane change
    (pi/6): two turns."""
    yaw = _profile((1.5, 0.0), (2.0, 0.4), (2.0, -0.4), (3.6, 0.0))
    return np.full(len(yaw), 8.0), yaw


def _two_lane_changes() -> tuple[np.ndarray, np.ndarray]:
    """A right lane change, then at once one back to the left (each 3 s, yaw 0.12 rad/s,
    about 4 m sideways), at 15 m/s: the middle 3 s turn left without a break."""
    yaw = _profile((2.0, 0.0), (1.5, -0.12), (3.0, 0.12), (1.5, -0.12), (1.1, 0.0))
    return np.full(len(yaw), 15.0), yaw


BEHAVIOURS = {
    "cruise_slow": lambda: _cruise(5.0),
    "cruise_medium": lambda: _cruise(15.0),
    "cruise_fast": lambda: _cruise(28.0),
    "parked": lambda: _cruise(0.0),
    "gradual_left_turn": lambda: _turn(0.05),
    "medium_left_turn": lambda: _turn(0.12),
    "aggressive_left_turn": lambda: _turn(0.3),
    "gradual_right_turn": lambda: _turn(-0.05),
    "medium_right_turn": lambda: _turn(-0.12),
    "aggressive_right_turn": lambda: _turn(-0.3),
    "left_lane_change": lambda: _lane_change(+1),
    "right_lane_change": lambda: _lane_change(-1),
    "left_lane_change_with_pause": lambda: _lane_change(+1, pause=2.0),
    "two_turns_apart": _two_turns,
    "stop_and_go": _stop_and_go,
    "accelerate_through_bands": _accelerate_through_bands,
    "hard_brake": _hard_brake,
    "flicker": _flicker,
    "u_turn": _u_turn,
    "turn_exit_overshoot": _turn_exit_overshoot,
    "s_curve": _s_curve,
    "two_lane_changes": _two_lane_changes,
}
"""Named hand-shaped behaviours (each 9.1 s at 10 Hz unless noted in its builder)."""


def behaviour(name: str, *, scenario_id: str = "behaviours", track_id: str | None = None,
              **kw) -> pd.DataFrame:
    """One named behaviour of :data:`BEHAVIOURS` as a trajectory table."""
    if name not in BEHAVIOURS:
        raise did_you_mean("behaviour", name, BEHAVIOURS)
    speed, yaw = BEHAVIOURS[name]()
    return from_controls(speed, yaw, scenario_id=scenario_id, track_id=track_id or name, **kw)


def random_trajectories(n: int, steps: int = 91, *, seed: int = 0,
                        scenarios: int | None = None) -> pd.DataFrame:
    """``n`` random vehicle trajectories of ``steps`` steps, WOMD-like in their mix.

    Each trajectory has a piecewise-constant acceleration (1 to 3 pieces), an initial speed
    from a stopped/slow/medium/fast mixture, at most one turn or lane change, and
    measurement noise on heading (0.003 rad) and speed (0.05 m/s). Deterministic per seed.

    Args:
        n: number of trajectories.
        steps: steps per trajectory (10 Hz).
        seed: random seed.
        scenarios: number of scenarios to spread them over (default: n // 50 + 1).

    Returns:
        A trajectory table of n * steps rows (source = "synthetic").
    """
    rng = np.random.default_rng(seed)
    k = np.arange(steps)[None, :]
    # Speed: mixture of start speeds, piecewise-constant acceleration.
    band = rng.choice(4, size=n, p=[0.1, 0.35, 0.35, 0.2])
    v0 = np.select([band == 0, band == 1, band == 2],
                   [0.0, rng.uniform(1, 10, n), rng.uniform(10, 24, n)], rng.uniform(24, 32, n))
    cuts = np.sort(rng.integers(0, steps, size=(n, 2)), axis=1)
    acc = rng.normal(0.0, 1.2, size=(n, 3)) * (rng.random((n, 3)) < 0.6)
    acc[band == 0, 0] = 0.0
    piece = (k >= cuts[:, :1]).astype(int) + (k >= cuts[:, 1:]).astype(int)
    a = np.take_along_axis(acc, piece, axis=1)
    speed = np.maximum(v0[:, None] + np.cumsum(a, axis=1) * DT - a * DT, 0.0)
    # Yaw rate: straight, a turn, or a lane change.
    kind = rng.choice(3, size=n, p=[0.6, 0.25, 0.15])
    start = rng.integers(0, steps - 30, size=n)[:, None]
    dur = rng.integers(15, 50, size=n)[:, None]
    peak = rng.uniform(0.03, 0.4, size=n)[:, None] * rng.choice([-1.0, 1.0], size=n)[:, None]
    turn = np.where((k >= start) & (k < start + dur), peak, 0.0)
    half = rng.integers(10, 25, size=n)[:, None]
    lc_peak = rng.uniform(0.04, 0.15, size=n)[:, None] * rng.choice([-1.0, 1.0], size=n)[:, None]
    lane = np.where((k >= start) & (k < start + half), lc_peak,
                    np.where((k >= start + half) & (k < start + 2 * half), -lc_peak, 0.0))
    yaw = np.where(kind[:, None] == 1, turn, np.where(kind[:, None] == 2, lane, 0.0))
    yaw = np.where(speed > 0.5, yaw, 0.0)

    heading0 = rng.uniform(-np.pi, np.pi, size=(n, 1))
    heading = heading0 + np.cumsum(yaw, axis=1) * DT - yaw * DT
    x = np.cumsum(speed * np.cos(heading), axis=1) * DT
    y = np.cumsum(speed * np.sin(heading), axis=1) * DT
    x = x - x[:, :1] + rng.uniform(-500, 500, size=(n, 1))
    y = y - y[:, :1] + rng.uniform(-500, 500, size=(n, 1))
    heading = heading + rng.normal(0.0, 0.003, size=heading.shape)
    speed = np.abs(speed + rng.normal(0.0, 0.05, size=speed.shape) * (speed > 0))

    scenarios = scenarios or n // 50 + 1
    scenario_names = np.array([f"syn{i:05d}" for i in range(scenarios)], dtype=object)
    track_names = np.array([f"{i:06d}" for i in range(n)], dtype=object)
    return pd.DataFrame({
        "scenario_id": pd.array(np.repeat(scenario_names[np.arange(n) * scenarios // n], steps),
                                dtype="str"),
        "track_id": pd.array(np.repeat(track_names, steps), dtype="str"),
        "t": np.tile(np.arange(steps) * DT, n),
        "x": x.ravel(), "y": y.ravel(),
        "heading": np.angle(np.exp(1j * heading)).ravel(),
        "speed": speed.ravel(),
        "object_type": "vehicle",
        "source": "synthetic",
    })


def sample_table(n_random: int = 200, seed: int = 0) -> pd.DataFrame:
    """The built-in sample: every named behaviour plus ``n_random`` random trajectories."""
    named = [behaviour(name) for name in BEHAVIOURS]
    for frame in named:
        frame["object_type"] = "vehicle"
        frame["source"] = "synthetic"
    frames = [*named, random_trajectories(n_random, seed=seed)] if n_random else named
    return pd.concat(frames, ignore_index=True)


def on_road(arc: np.ndarray, radius: float, side: int = 1, *, lateral: float = 0.0
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions and headings at arc lengths ``arc`` along a road that starts at the origin
    heading +x: straight (``radius`` inf) or a circle of ``radius`` [m] turning left
    (``side`` +1) or right (-1); ``lateral`` [m] to the left of its centre line.

    Returns:
        (x, y, heading) [m, m, rad], each shaped like ``arc``; the heading is unwrapped.
    """
    arc = np.asarray(arc, dtype=np.float64)
    if not np.isfinite(radius):
        return arc.copy(), np.full(arc.shape, lateral), np.zeros(arc.shape)
    theta = arc / radius  # the angle turned, about the centre (0, side * radius)
    r = radius - side * lateral  # a lane to the left of a left curve is its inner lane
    return r * np.sin(theta), side * (radius - r * np.cos(theta)), side * theta


def road_scene(radius: float, side: int = 1, *, ego_speed: np.ndarray,
               others: dict[str, tuple[float, np.ndarray, float]] | None = None,
               scenario_id: str = "road") -> pd.DataFrame:
    """A scene on one road (:func:`on_road`): the ego and other vehicles by their speed
    profiles, all at 10 Hz.

    Args:
        radius, side: the road (inf: straight).
        ego_speed: (n,) the ego's speed [m/s] at each step; it starts at arc length 0.
        others: track id -> (arc length at the first step [m], (n,) speed [m/s], lateral
            offset [m], positive to the left of the road's centre line).
        scenario_id: the scene's id.

    Returns:
        A trajectory table with ``is_ego`` and ``object_type`` (the ego's track id is
        ``ego``), speeds as given and positions integrated from them.
    """
    ego_speed = np.asarray(ego_speed, dtype=np.float64)
    n = len(ego_speed)
    t = np.arange(n) * DT
    tracks = {"ego": (0.0, ego_speed, 0.0), **(others or {})}
    frames = []
    for track, (s0, speed, lateral) in tracks.items():
        speed = np.asarray(speed, dtype=np.float64)
        if len(speed) != n:
            raise ParameterError(f"others[{track!r}]", len(speed), f"{n} speeds, one per step")
        arc = s0 + np.concatenate([[0.0], np.cumsum(speed[:-1]) * DT])
        x, y, heading = on_road(arc, radius, side, lateral=lateral)
        frames.append(pd.DataFrame({
            "scenario_id": scenario_id, "track_id": track, "t": t, "x": x, "y": y,
            "heading": np.angle(np.exp(1j * heading)), "speed": speed,
            "object_type": "vehicle", "is_ego": track == "ego"}))
    return pd.concat(frames, ignore_index=True)
