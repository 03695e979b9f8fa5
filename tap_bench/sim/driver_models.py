"""The driver models of the traffic core, as array functions (every vehicle at once) and as
one-vehicle functions of plain floats (``*_one``, for small roads, where numpy's fixed cost
per call outweighs its speed per element).

- IDM, the Intelligent Driver Model (Treiber, Hennecke and Helbing 2000): the acceleration
  ``a = a_max [1 - (v / v0)^delta - (s* / s)^2]`` with the desired gap
  ``s* = s0 + v T + v dv / (2 sqrt(a_max b))`` (:func:`desired_gap`, :func:`idm_acceleration`).
  highway-env measures ``s`` between the vehicles' reference points (front to front), so its
  ``s0`` (``DISTANCE_WANTED``) holds a vehicle length; ``b`` is its ``-COMFORT_ACC_MIN``.
- MOBIL (Kesting, Treiber and Helbing 2007): a lane change is safe when the new follower
  would brake by less than ``b_safe`` and worth it when the driver's own gain plus the
  politeness ``p`` times its followers' gains exceeds the threshold ``delta_a_threshold``
  (:func:`mobil_incentive`).
- Lane keeping: a cascade of proportional controllers, lateral offset to lateral speed
  (gain ``kp_lateral``), lateral speed to a heading, heading to yaw rate (``kp_heading``),
  yaw rate to front-wheel angle through the bicycle model (:func:`steering_angle`).
- The kinematic bicycle model with the reference point at the centre of a vehicle of
  length ``L``: slip ``beta = arctan(tan(delta_f) / 2)``, velocity along
  ``heading + beta``, yaw rate ``v sin(beta) / (L / 2)`` (:func:`bicycle_step`).

Arrays are float64, one entry per vehicle (or per vehicle pair); units SI: m, m/s, m/s^2,
rad, s. The two forms of each model are the same equations; they agree within float
rounding (numpy's and the C library's trigonometric functions may differ in the last bit).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["MIN_DIVISOR", "bicycle_one", "bicycle_step", "desired_gap", "desired_gap_one",
           "idm_acceleration", "idm_one", "mobil_incentive", "safe_divisor", "safe_divisor_one",
           "steering_angle", "steering_one", "wrap_angle", "wrap_one"]

MIN_DIVISOR = 1e-2
"""Smallest magnitude a speed or gap takes as a divisor (smaller ones become +-0.01, the
sign kept, zero counted positive), so standing vehicles and touching gaps stay finite."""


def safe_divisor(x: np.ndarray) -> np.ndarray:
    """``x`` with entries of magnitude at most :data:`MIN_DIVISOR` replaced by
    ``+-MIN_DIVISOR`` (the sign of ``x``, +1 for zero)."""
    return np.where(np.abs(x) > MIN_DIVISOR, x,
                    np.where(x >= 0, MIN_DIVISOR, -MIN_DIVISOR))


def wrap_angle(x: np.ndarray) -> np.ndarray:
    """Angles [rad] wrapped to [-pi, pi)."""
    return np.remainder(x + np.pi, 2 * np.pi) - np.pi


def desired_gap(speed: np.ndarray, approach: np.ndarray, s0: np.ndarray, time_gap: np.ndarray,
                a_max: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IDM's desired gap ``s* = s0 + v T + v dv / (2 sqrt(a_max b))`` [m].

    Args:
        speed: (n,) the follower's speed v [m/s].
        approach: (n,) dv, the rate [m/s] at which the follower closes on its leader (its
            velocity minus the leader's, along the follower's heading).
        s0: (n,) jam distance [m]; time_gap: (n,) T [s]; a_max: (n,) maximum
            acceleration [m/s^2]; b: (n,) comfortable deceleration [m/s^2], positive.
    """
    return s0 + speed * time_gap + speed * approach / (2 * np.sqrt(a_max * b))


def idm_acceleration(speed: np.ndarray, desired_speed: np.ndarray, delta: np.ndarray,
                     a_max: np.ndarray, gap: np.ndarray | None = None,
                     s_star: np.ndarray | None = None,
                     has_leader: np.ndarray | None = None) -> np.ndarray:
    """IDM's acceleration ``a_max [1 - (v / v0)^delta - (s* / s)^2]`` [m/s^2].

    Args:
        speed: (n,) v [m/s] (a negative speed counts as 0 in the free-road term).
        desired_speed: (n,) v0 [m/s] (its magnitude, at least :data:`MIN_DIVISOR`).
        delta: (n,) the free-road exponent; a_max: (n,) maximum acceleration [m/s^2].
        gap: (n,) s, the distance to the leader [m] (a divisor: :func:`safe_divisor`).
        s_star: (n,) the desired gap [m] (:func:`desired_gap`).
        has_leader: (n,) bool, where there is a leader (elsewhere the interaction term is
            left out); None: nowhere.
    """
    free = a_max * (1 - np.power(np.maximum(speed, 0) / np.abs(safe_divisor(desired_speed)),
                                 delta))
    if has_leader is None or not has_leader.any():
        return free
    ratio = np.where(has_leader, s_star / safe_divisor(np.where(has_leader, gap, 1.0)), 0.0)
    return free - np.where(has_leader, a_max * ratio * ratio, 0.0)


def mobil_incentive(own_gain: np.ndarray, new_follower_gain: np.ndarray,
                    old_follower_gain: np.ndarray, politeness: np.ndarray) -> np.ndarray:
    """MOBIL's incentive [m/s^2]: the driver's acceleration gain plus ``politeness`` times
    the gains of its new and old followers (each: acceleration after the change minus
    before). A change is worth it when this reaches the threshold ``delta_a_threshold``."""
    return own_gain + politeness * (new_follower_gain + old_follower_gain)


def steering_angle(lateral_offset: np.ndarray, heading: np.ndarray, lane_heading: np.ndarray,
                   speed: np.ndarray, length: np.ndarray, kp_lateral: np.ndarray,
                   kp_heading: np.ndarray, max_angle: np.ndarray) -> np.ndarray:
    """Front-wheel angle [rad] that steers each vehicle onto its target lane.

    Lateral offset ``r`` [m] to a lateral speed ``-kp_lateral r``, that speed to a heading
    offset ``arcsin(v_lat / v)`` (within +-pi/4) from the lane's heading ahead
    (``lane_heading``), the heading error to a yaw rate ``kp_heading (psi_ref - psi)``, and
    that yaw rate to a wheel angle by the bicycle model (slip ``arcsin(L/2 * rate / v)``,
    ``delta_f = arctan(2 tan(slip))``), within ``+-max_angle``.
    """
    divisor = safe_divisor(speed)
    heading_offset = np.clip(np.arcsin(np.clip(-kp_lateral * lateral_offset / divisor, -1, 1)),
                             -np.pi / 4, np.pi / 4)
    yaw_rate = kp_heading * wrap_angle(lane_heading + heading_offset - heading)
    slip = np.arcsin(np.clip(length / 2 / divisor * yaw_rate, -1, 1))
    return np.clip(np.arctan(2 * np.tan(slip)), -max_angle, max_angle)


def bicycle_step(x: np.ndarray, y: np.ndarray, heading: np.ndarray, speed: np.ndarray,
                 steering: np.ndarray, acceleration: np.ndarray, length: np.ndarray,
                 dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One explicit Euler step of ``dt`` [s] of the kinematic bicycle model: the new
    (x, y) [m], heading [rad] and speed [m/s], each (n,)."""
    slip = np.arctan(0.5 * np.tan(steering))
    course = heading + slip
    step = speed * dt
    return (x + step * np.cos(course), y + step * np.sin(course),
            heading + speed * np.sin(slip) / (length / 2) * dt, speed + acceleration * dt)


# -- one vehicle, plain floats ---------------------------------------------------------------
_TURN = 2 * math.pi  # [rad]


def wrap_one(x: float) -> float:
    """:func:`wrap_angle` of one angle [rad]."""
    return x - _TURN * math.floor((x + math.pi) / _TURN)


def safe_divisor_one(x: float) -> float:
    """:func:`safe_divisor` of one number."""
    return x if abs(x) > MIN_DIVISOR else math.copysign(MIN_DIVISOR, 1.0 if x >= 0 else -1.0)


def _clip(x: float, low: float, high: float) -> float:
    return min(max(x, low), high)


def desired_gap_one(speed: float, approach: float, s0: float, time_gap: float, a_max: float,
                    b: float) -> float:
    """:func:`desired_gap` of one follower [m] (arguments as there, floats)."""
    return s0 + speed * time_gap + speed * approach / (2 * math.sqrt(a_max * b))


def idm_one(speed: float, desired_speed: float, delta: float, a_max: float,
            gap: float | None = None, s_star: float = 0.0) -> float:
    """:func:`idm_acceleration` of one follower [m/s^2]; ``gap`` None: no leader."""
    free = a_max * (1 - (max(speed, 0.0) / abs(safe_divisor_one(desired_speed))) ** delta)
    if gap is None:
        return free
    ratio = s_star / safe_divisor_one(gap)
    return free - a_max * ratio * ratio


def steering_one(lateral_offset: float, heading: float, lane_heading: float, speed: float,
                 length: float, kp_lateral: float, kp_heading: float,
                 max_angle: float) -> float:
    """:func:`steering_angle` of one vehicle [rad] (arguments as there, floats)."""
    divisor = safe_divisor_one(speed)
    heading_offset = _clip(math.asin(_clip(-kp_lateral * lateral_offset / divisor, -1, 1)),
                           -math.pi / 4, math.pi / 4)
    yaw_rate = kp_heading * wrap_one(lane_heading + heading_offset - heading)
    slip = math.asin(_clip(length / 2 / divisor * yaw_rate, -1, 1))
    return _clip(math.atan(2 * math.tan(slip)), -max_angle, max_angle)


def bicycle_one(x: float, y: float, heading: float, speed: float, steering: float,
                acceleration: float, length: float,
                dt: float) -> tuple[float, float, float, float]:
    """:func:`bicycle_step` of one vehicle: the new x, y [m], heading [rad], speed [m/s]."""
    slip = math.atan(0.5 * math.tan(steering))
    course = heading + slip
    step = speed * dt
    return (x + step * math.cos(course), y + step * math.sin(course),
            heading + speed * math.sin(slip) / (length / 2) * dt, speed + acceleration * dt)
