"""The road of a recorded WOMD scene in highway-env: its network, its vehicles, its routes.

- :class:`WomdNetwork`: one :class:`~tap_bench.sim.womd_lanes.FastPolyLane` per WOMD lane,
  the exits and neighbours of the map (:class:`~tap_bench.womd.roadmap.RoadMap`) as the
  lane graph, and the compiled lane lookup;
- :class:`LogVehicle` (an agent replaying its log), :class:`WomdMDPVehicle` (the
  meta-action ego: lane changes to the map's neighbours), :class:`WomdIDMVehicle` (IDM/MOBIL
  along a route, stopping at red stop points: the IDM ego), :class:`WomdPathVehicle` (idm
  traffic: along its logged path, IDM deciding its speed; :class:`LoggedPath`);
- :class:`WomdRoad`: the step counter the replays read, the neighbour search (all positions
  projected on a lane at once, once per step), the ego's collisions, signals, off-road;
- :func:`logged_route`: the lanes a logged path follows.

Everything is in highway-env's mirrored frame (``y`` and headings negated, :func:`sim_frame`);
:mod:`tap_bench.sim.womd_env` records back in WOMD's axes.
"""

from __future__ import annotations

import bisect
import contextlib
import functools
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from highway_env import utils
from highway_env.road.lane import LineType
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle, MDPVehicle
from highway_env.vehicle.kinematics import Vehicle

from tap_bench.errors import ParameterError
from tap_bench.sim.driver_models import bicycle_one, steering_one
from tap_bench.sim.road_edges import RoadEdges, left_road
from tap_bench.sim.traffic import TOUCH_MARGIN, limited_action, near_pairs, shape_of
from tap_bench.sim.womd_lanes import FastPolyLane, LaneIndex, _frame, lanes_points
from tap_bench.sim.womd_scene import Scene
from tap_bench.womd.roadmap import split_rows

__all__ = ["HIDDEN", "OFF_ROAD_MARGIN", "PATH_EXTENSION", "PATH_SPACING", "LoggedPath",
           "WomdPathVehicle", "logged_path", "ROUTE_CORRIDOR", "ROUTE_OFF_MAP", "STOP_LOOKAHEAD",
           "STOP_MARGIN", "WALKER_CLEARANCE", "WALKER_HORIZON", "WALKER_LOOKAHEAD",
           "NOMINAL_DRIVER", "ConstantVelocityVehicle", "DriverParameters", "LogVehicle",
           "WomdIDMVehicle", "WomdMDPVehicle",
           "WomdNetwork", "WomdRoad", "draw_driver", "logged_route", "path_columns",
           "path_progress", "sim_frame", "window_max"]

OFF_ROAD_MARGIN = 0.5  # [m] beyond half the lane's width, from every lane centre: off road
ROUTE_CORRIDOR = 4.0  # [m] progress counts while the ego is this close to the logged path
ROUTE_OFF_MAP = 3.0  # [m] a logged position farther than half a lane width + this is off
STOP_MARGIN = 1.0  # [m] IDM stops its front bumper this far before a red stop point
STOP_LOOKAHEAD = 60.0  # [m] stop points farther ahead along the route are ignored
HIDDEN = 1.0e6  # [m] where an agent waits while the log has no valid state for it
WALKER_LOOKAHEAD = 50.0  # [m] IDM yields to pedestrians and cyclists in its way this far ahead
WALKER_HORIZON = 1.5  # [s] ... where they are now or will be in this time
WALKER_CLEARANCE = 1.0  # [m] ... within half the vehicle's width + this of the lane centre
WALKER_RADIUS = 0.5  # [m] IDM stops its front bumper STOP_MARGIN before this around them
WALKER_STILL = 0.5  # [m/s] slower walkers count as standing in the way
WALKER_ALONG = math.cos(math.radians(30.0))  # a walker within 30 deg of the lane moves along
LEADER_LOOKAHEAD = 60.0  # [m] IDM sees a leader on its next lanes this far ahead
LANES_AHEAD = 60.0  # [m] the lanes ahead of a vehicle are looked up this far once a step
STOP_SIGN_REACH = 6.0  # [m] a stop sign listing no lane controls the lane ends this close
STOP_SIGN_SPEED = 1.0  # [m/s] slower than this near the stop point is a stop
STOP_SIGN_NEAR = 4.0  # [m] ... with the bumper this close to it
CONFLICT_LOOKAHEAD = 40.0  # [m] IDM looks for crossing and merging traffic this far ahead
CONFLICT_HORIZON = 8.0  # [s] others reaching the conflict point later are ignored
CONFLICT_CLEARANCE = 1.0  # [m] beyond the half widths, a box in the conflict zone blocks it
CONFLICT_TIE = 0.5  # [s] arrivals this close: the lower scene row goes first
CORRIDOR_MARGIN = 0.3  # [m] beyond half of both widths, a box ahead is out of the way
CORRIDOR_TIME = 1.5  # [s] IDM sees boxes in its straight way ahead this far in time ...
CORRIDOR_MIN = 6.0  # [m] ... plus this


def sim_frame(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """WOMD (x, y) -> highway-env's mirrored frame: (..., 2) [m] of x and -y (the same
    shape each; numpy's stack, without its Python-level work)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.shape != y.shape:
        return np.stack([x, -y], axis=-1)  # numpy's error: the shapes differ
    out = np.empty((*x.shape, 2))
    out[..., 0] = x
    np.negative(y, out=out[..., 1])
    return out


# ------------------------------------------------------------------ the road network


class WomdNetwork(RoadNetwork):
    """A highway-env road network of WOMD lanes.

    Lane index of WOMD lane ``k``: ``(str(k), f"{k}>", 0)``. The graph's nodes do not carry
    the topology; the WOMD exits and neighbours do, through :meth:`next_lane` and
    :meth:`side_lanes_at`, and :meth:`get_closest_lane_index` is compiled
    (:class:`~tap_bench.sim.womd_lanes.LaneIndex`).

    Attributes:
        road_map: the WOMD map.
        index: WOMD lane id -> lane index.
        left_out: WOMD lane ids not built (a single distinct point).
    """

    def __init__(self, road_map: Any) -> None:
        super().__init__()
        self.road_map = road_map
        self.index: dict[int, tuple[str, str, int]] = {}
        self.left_out: list[int] = []
        # scene row -> share of its logged path off the lanes (idm traffic's choice of who
        # drives, the same in every rollout of the scene)
        self.path_off_map: dict[int, float] = {}
        kept, lines = [], []
        every = list(road_map.lanes.values())
        for lane, points in zip(every, lanes_points([lane.centre for lane in every]),
                                strict=True):
            if points is None:
                self.left_out.append(lane.id)
                continue
            kept.append(lane)
            lines.append(points)
        if lines:  # to highway-env's mirrored frame, all at once
            flat = np.concatenate(lines) * (1.0, -1.0)
            lines = split_rows(flat, [len(points) for points in lines])
        built = FastPolyLane.many(
            lines, [lane.width for lane in kept], womd_ids=[lane.id for lane in kept],
            speed_limits=[lane.speed_limit if np.isfinite(lane.speed_limit) else 20.0
                          for lane in kept],
            # drawn (rgb_array) with a dashed line where the map names a neighbour
            line_types=[tuple(LineType.STRIPED if side else LineType.CONTINUOUS
                              for side in (lane.left, lane.right)) for lane in kept])
        # the pose arrays every lane of the network is a slice of (FastPolyLane.many makes
        # one set): x, y, tangent x, y, arc length of each pose [m]
        self.shared_poses: tuple[np.ndarray, ...] | None = (
            built[0]._shared[1] if built else None)
        lanes = []
        for lane, fast in zip(kept, built, strict=True):
            index = (str(lane.id), f"{lane.id}>", 0)
            self.add_lane(index[0], index[1], fast)
            self.index[lane.id] = index
            lanes.append((index, fast))
        self.lookup = LaneIndex(lanes)
        self._looked_up: dict[tuple[float, float, float], Any] = {}
        self._asking_position: np.ndarray | None = None
        self._neighbours: dict[Any, frozenset] = {}
        self._next_lanes: dict[tuple, Any] = {}  # next_lane's answers by lane and route

    @functools.cached_property
    def _centre_arcs(self) -> dict[int, list[float]]:
        """WOMD lane id -> arc lengths of its centre line's points [m] (filled as asked)."""
        return {}

    @functools.cached_property
    def road_edges(self) -> RoadEdges:
        """The road edges of its map, in WOMD's axes (built at the first use, then kept: a
        network reused for the next episode of its scene reuses them)."""
        return RoadEdges.from_polylines(self.road_map.road_edges)

    def get_closest_lane_index(self, position: np.ndarray, heading: float | None = None
                               ) -> tuple[str, str, int]:
        if self._looked_up and heading is not None:
            found = self._looked_up.get((float(position[0]), float(position[1]),
                                         float(heading)))
            if found is not None:
                return found
        return self.lookup.closest(position, heading)

    def look_up_lanes(self, states: np.ndarray) -> None:
        """Find the closest lanes of many (x [m], y [m], heading [rad]) rows (n, 3) at once
        (:meth:`LaneIndex.closest_many`): :meth:`get_closest_lane_index` answers those
        exact positions and headings from them until :meth:`forget_lanes`."""
        states = np.asarray(states, dtype=np.float64).reshape(-1, 3)
        found = self.lookup.closest_many(states[:, :2], states[:, 2])
        self._looked_up = {tuple(row): index
                           for row, index in zip(states.tolist(), found, strict=True)}

    def forget_lanes(self) -> None:
        """Drop the lanes found by :meth:`look_up_lanes`."""
        self._looked_up = {}

    def womd_id(self, lane_index: Any) -> int:
        """The WOMD id of a lane index."""
        return int(lane_index[0])

    def successors(self, lane_index: Any) -> list[tuple[str, str, int]]:
        """Lane indexes of the lane's exits (those built)."""
        lane = self.road_map.lanes[self.womd_id(lane_index)]
        return [self.index[i] for i in lane.exit if i in self.index]

    def side_lanes_at(self, lane_index: Any, position: np.ndarray, side: str | None = None
                      ) -> list[tuple[str, str, int]]:
        """The map's neighbours of a lane at ``position`` (within their index range):
        ``side`` ``"left"``, ``"right"`` or None for both."""
        lane = self.road_map.lanes[self.womd_id(lane_index)]
        built = self.get_lane(lane_index)
        lon, _ = built.local_coordinates(position)
        arcs = self._centre_arcs.get(lane.id)
        if arcs is None:  # asked every step: the centre line's arc lengths once per lane
            arcs = self._centre_arcs[lane.id] = _arc_lengths(lane.centre).tolist()
        if len(lane.centre) < 2:
            at = 0
        else:  # numpy's searchsorted (left) of a sorted list; a NaN goes past the end
            at = min(bisect.bisect_left(arcs, lon) if lon == lon else len(arcs),
                     len(lane.centre) - 1)
        out = []
        for name in ("left", "right"):
            if side not in (None, name):
                continue
            for n in getattr(lane, name):
                if n.self_start <= at <= n.self_end and n.lane in self.index:
                    out.append(self.index[n.lane])
        return out

    def side_lanes(self, lane_index: Any) -> list[tuple[str, str, int]]:
        """The map's neighbours of a lane: at the position a vehicle deciding a lane change
        asks from (:meth:`asked_from`, as :meth:`side_lanes_at`), else anywhere along the lane
        (MOBIL then checks that the lane is reachable from where the vehicle is)."""
        if self._asking_position is not None:
            return self.side_lanes_at(lane_index, self._asking_position)
        lane = self.road_map.lanes[self.womd_id(lane_index)]
        return [self.index[n.lane] for n in (*lane.left, *lane.right) if n.lane in self.index]

    def neighbours(self, lane_index: Any) -> frozenset:
        """The map's neighbours of a lane anywhere along it, either side (kept by lane)."""
        found = self._neighbours.get(lane_index)
        if found is None:
            lane = self.road_map.lanes[self.womd_id(lane_index)]
            found = self._neighbours[lane_index] = frozenset(
                self.index[n.lane] for n in (*lane.left, *lane.right) if n.lane in self.index)
        return found

    @contextlib.contextmanager
    def asked_from(self, position: np.ndarray) -> Iterator[None]:
        """Within the block, :meth:`side_lanes` answers for a vehicle at ``position`` (x, y
        [m], highway-env's frame): highway-env's lane-change policy asks for a lane's
        neighbours by lane alone, and WOMD neighbours hold over part of a lane only."""
        before, self._asking_position = self._asking_position, position
        try:
            yield
        finally:
            self._asking_position = before

    def next_lane(self, current_index: Any, route: Any = None, position: np.ndarray = None,
                  np_random: Any = None) -> Any:
        """The lane after ``current_index``: the route's next lane when it is an exit of
        this one, else the exit that continues most straight; the lane itself at a dead
        end (``position`` and ``np_random`` do not matter). Each lane's answer for a route
        is kept (by the route's lanes, not the list)."""
        try:
            key = (current_index, tuple(route) if route else None)
            found = self._next_lanes.get(key)
        except TypeError:  # a route of unhashable items: asked each time
            return self._next_lane(current_index, route)
        if found is None:
            found = self._next_lanes[key] = self._next_lane(current_index, route)
        return found

    def _next_lane(self, current_index: Any, route: Any) -> Any:
        """:meth:`next_lane`, found."""
        exits = self.successors(current_index)
        if not exits:
            return current_index
        if route:
            for k, index in enumerate(route):
                if index == current_index:
                    for later in route[k + 1:k + 4]:
                        if later in exits:
                            return later
                    break
            for index in route:
                if index in exits:
                    return index
        lane = self.get_lane(current_index)
        end_heading = lane.heading_at(lane.length)
        return min(exits, key=lambda i: abs(utils.wrap_to_pi(
            self.get_lane(i).heading_at(0.0) - end_heading)))


def _arc_lengths(centre: np.ndarray) -> np.ndarray:
    """(n,) arc length [m] of each point of a centre line (n, 2+) from its first."""
    if len(centre) < 2:
        return np.zeros(len(centre))
    return np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(centre, axis=0).T))))


# ------------------------------------------------------------------ vehicles


_LAID_OUT = frozenset(("states", "valid_steps", "clock", "row", "_xy", "_heading", "_speed",
                       "_valid", "_end", "LENGTH", "WIDTH", "diagonal", "check_collisions",
                       "_log_block", "_log_at"))
"""A replaying vehicle's attributes that :meth:`LogVehicle._laid_out` and
:meth:`LogVehicle.many` set themselves."""


class LogVehicle(Vehicle):
    """An agent replaying its logged states (sim frame), hidden while the log has none.

    The log is laid out once, when the vehicle is made: positions as one read-only (T + 1,
    2) array (the steps without a valid state, and one step past the log's end, at the
    hidden place), headings, speeds and validity as Python lists. ``position``,
    ``heading``, ``speed`` and ``collidable`` are read from the row of the road's current
    step (the shared ``clock``) when asked, so a step costs nothing; setting them changes
    nothing (the log decides). ``impact`` (set by a collision check) holds for the step it
    was set in.

    Attributes:
        row: the track's row in the scene.
    """

    _log_block: tuple[np.ndarray, ...] | None = None  # many's arrays of every vehicle made
    _log_at: int = -1  # ... this one's place in them

    def __init__(self, road: Road, row: int, states: np.ndarray, valid: np.ndarray,
                 length: float, width: float, clock: list[int]) -> None:
        self.states = states  # (T, 4) x, y, heading, speed in the sim frame
        self.valid_steps = valid
        self.clock = clock
        self.row = row
        states = np.asarray(states, dtype=np.float64)
        ok = np.asarray(valid, dtype=bool)
        n = len(ok)
        xy = np.empty((n + 1, 2))
        xy[:n] = states[:, :2]
        xy[np.flatnonzero(~ok)] = (HIDDEN + 10.0 * row, HIDDEN)
        xy[n] = (HIDDEN + 10.0 * row, HIDDEN)
        xy.flags.writeable = False  # a step's position is a view of its row
        self._xy = xy
        self._heading = [*np.where(ok, states[:, 2], 0.0).tolist(), 0.0]
        self._speed = [*np.where(ok, states[:, 3], 0.0).tolist(), 0.0]
        self._valid = [*ok.tolist(), False]
        self._end = n  # the hidden row past the log's end
        self.LENGTH, self.WIDTH = float(length), float(width)
        x, y, h, v = self._state(clock[0])
        super().__init__(road, np.array([x, y]), h, v)
        self.diagonal = math.hypot(self.LENGTH, self.WIDTH)
        self.check_collisions = False

    @classmethod
    def many(cls, road: Road, rows: Sequence[int], states: np.ndarray, valid: np.ndarray,
             length: np.ndarray, width: np.ndarray, clock: list[int]) -> list[LogVehicle]:
        """One replaying vehicle per row of ``rows``, their logs laid out together (the
        same vehicles as one by one).

        Args:
            road, clock: as the constructor.
            rows: the scene rows to make vehicles of.
            states: (n, T, 4) every row's x, y, heading, speed in the sim frame.
            valid: (n, T) bool.
            length, width: (n,) [m].
        """
        rows = np.asarray(rows, dtype=np.int64)
        given = states
        states = np.asarray(states, dtype=np.float64)[rows]
        ok = np.asarray(valid, dtype=bool)[rows]
        m, n = ok.shape
        hidden = np.c_[HIDDEN + 10.0 * rows, np.full(m, HIDDEN)]
        xy = np.empty((m, n + 1, 2))
        xy[:, :n] = np.where(ok[..., None], states[..., :2], hidden[:, None, :])
        xy[:, n] = hidden
        xy.flags.writeable = False  # a step's position is a view of its row
        end = np.zeros((m, 1))
        block = (xy, np.c_[np.where(ok, states[..., 2], 0.0), end],
                 np.c_[np.where(ok, states[..., 3], 0.0), end], np.c_[ok, np.zeros((m, 1), bool)])
        headings, speeds, flags = (values.tolist() for values in block[1:])
        out = []
        made = None  # the first vehicle's attributes from highway-env's constructor
        for i, row in enumerate(rows.tolist()):
            vehicle = cls.__new__(cls)
            vehicle._laid_out(road, row, given[row], valid[row], xy[i], headings[i],
                              speeds[i], flags[i], float(length[row]), float(width[row]),
                              clock, made)
            if made is None:
                made = vehicle._constructed()
            vehicle._log_block, vehicle._log_at = block, i  # for the road's _Layout
            out.append(vehicle)
        return out

    _CONSTRUCTED = frozenset(("road", "lane_index", "lane", "solid", "hit", "crashed",
                              "_impact", "prediction_type", "action", "log", "history"))
    """The attributes highway-env's ``Vehicle.__init__`` gives a replaying vehicle (its
    position, heading, speed and collidable are the log's; impact is kept as
    ``_impact``)."""

    def _constructed(self) -> dict[str, Any] | None:
        """The attributes highway-env's constructor gave this vehicle that are the same for
        every replaying vehicle of a road made at one step (:meth:`many` gives them to the
        others without the constructor), or None where the constructor gave others than
        :data:`_CONSTRUCTED` (another highway-env: the constructor then makes each)."""
        given = {k: v for k, v in self.__dict__.items() if k in self._CONSTRUCTED}
        if len(given) != len(self._CONSTRUCTED) or not all(
                k in self._CONSTRUCTED or k in _LAID_OUT for k in self.__dict__):
            return None
        return given

    def _laid_out(self, road: Road, row: int, states: np.ndarray, valid: np.ndarray,
                  xy: np.ndarray, headings: list[float], speeds: list[float],
                  flags: list[bool], length: float, width: float, clock: list[int],
                  made: dict[str, Any] | None = None) -> None:
        """Set the vehicle from its log laid out (``xy`` (T + 1, 2) read-only, the lists
        T + 1 long: the constructor's); ``made``: another replaying vehicle's
        :meth:`_constructed` attributes of this road and step, taken instead of
        highway-env's constructor (its lane looked up the same way, a new action, log and
        history each)."""
        self.states = states
        self.valid_steps = valid
        self.clock = clock
        self.row = row
        self._xy = xy
        self._heading = headings
        self._speed = speeds
        self._valid = flags
        self._end = len(flags) - 1
        self.LENGTH, self.WIDTH = length, width
        if (made is not None and road is not None and made["road"] is road
                and made["_impact"][0] == clock[0]):
            # RoadObject's and Vehicle's constructors without their calls: the lane of the
            # logged place (the position and heading properties), the rest as made
            lane_index = road.network.get_closest_lane_index(self.position, self.heading)
            self.__dict__.update(made)
            self.lane_index, self.lane = lane_index, road.network.get_lane(lane_index)
            self.action, self.log = dict(made["action"]), list(made["log"])
            self.history = type(made["history"])(made["history"], made["history"].maxlen)
        else:
            x, y, h, v = self._state(clock[0])
            Vehicle.__init__(self, road, np.array([x, y]), h, v)
        self.diagonal = math.hypot(self.LENGTH, self.WIDTH)
        self.check_collisions = False

    def _state(self, k: int) -> tuple[float, float, float, float]:
        """(x, y, heading, speed) at the record's step ``k`` (the hidden place and 0, 0
        where the log has no valid state)."""
        k = min(k, self._end)
        x, y = self._xy[k].tolist()
        return x, y, self._heading[k], self._speed[k]

    @property
    def position(self) -> np.ndarray:
        """(2,) [m] the logged position at the road's step (a read-only view)."""
        k = self.clock[0]
        return self._xy[k if k < self._end else self._end]

    # The setters below ignore every write: highway-env's Vehicle.__init__, its collision
    # handling and a highway-env step assign these, but a replayed vehicle's state is the
    # log's at the road's step.
    @position.setter
    def position(self, value: Any) -> None:
        pass

    @property
    def heading(self) -> float:
        """[rad] the logged heading at the road's step."""
        k = self.clock[0]
        return self._heading[k if k < self._end else self._end]

    @heading.setter
    def heading(self, value: Any) -> None:
        pass

    @property
    def speed(self) -> float:
        """[m/s] the logged speed at the road's step."""
        k = self.clock[0]
        return self._speed[k if k < self._end else self._end]

    @speed.setter
    def speed(self, value: Any) -> None:
        pass

    @property
    def collidable(self) -> bool:
        """Whether the log has a valid state at the road's step."""
        k = self.clock[0]
        return self._valid[k if k < self._end else self._end]

    @collidable.setter
    def collidable(self, value: Any) -> None:
        pass

    @property
    def impact(self) -> np.ndarray | None:
        """The push a collision check of this step gave (highway-env's), else None."""
        stamped = self.__dict__.get("_impact")
        return stamped[1] if stamped is not None and stamped[0] == self.clock[0] else None

    @impact.setter
    def impact(self, value: np.ndarray | None) -> None:
        self.__dict__["_impact"] = (self.clock[0], value)

    def act(self, action: Any = None) -> None:
        """Replaying: no decision."""

    def step(self, dt: float) -> None:
        """Replaying: the state follows the road's step by itself."""


class ConstantVelocityVehicle(Vehicle):
    """An agent that keeps its velocity at the current time (position, heading and velocity
    of the log then, sim frame): the constant-velocity traffic of the realism score's floor.
    It does not react and is never stopped by a collision.

    Attributes:
        row: the track's row in the scene (set by the env).
    """

    def __init__(self, road: Road, state: np.ndarray, velocity: np.ndarray, length: float,
                 width: float, clock: list[int]) -> None:
        x, y, h, v = (float(c) for c in state)
        velocity = np.asarray(velocity, float)
        if np.isfinite(velocity).all():
            v = float(np.hypot(*velocity))
        else:
            velocity = v * np.array([math.cos(h), math.sin(h)])
        super().__init__(road, np.array([x, y]), h, v)
        self.LENGTH, self.WIDTH = float(length), float(width)
        self.diagonal = math.hypot(self.LENGTH, self.WIDTH)
        self.origin = np.array([x, y])
        self.velocity_xy = velocity
        self.start = clock[0]
        self.clock = clock
        self.check_collisions = False

    @property
    def velocity(self) -> np.ndarray:
        return self.velocity_xy

    def act(self, action: Any = None) -> None:
        """No decision."""

    def step(self, dt: float) -> None:
        """Move to where the velocity takes it by the road's current step."""
        self.impact = None
        self.position = self.origin + self.velocity_xy * dt * (self.clock[0] - self.start)


class _RouteMixin:
    """Route following for WOMD vehicles: lane changes the route makes (the logged driver
    changed lanes there) and the map's neighbours only."""

    route: list

    def _route_change(self) -> Any:
        """The route's next lane when it is a neighbour of the current one (a logged lane
        change), else None."""
        if not self.route or self.lane_index not in self.route:
            return None
        k = self.route.index(self.lane_index)
        if k + 1 < len(self.route):
            nxt = self.route[k + 1]
            network = self.road.network
            # not a neighbour anywhere along the lane (the usual case): not one here
            if (nxt in network.neighbours(self.lane_index)
                    and nxt in network.side_lanes_at(self.lane_index, self.position)):
                return nxt
        return None


SPEED_INDEX = ("nearest", "uniform")
"""How a meta-action vehicle finds a speed's place on its target-speed grid: ``nearest``
(the grid speed nearest it), or ``uniform`` (highway-env's formula, which takes the grid as
evenly spaced: what every model trained on WOMD before 2026-12-05 drove with)."""


class WomdMDPVehicle(_RouteMixin, MDPVehicle):
    """highway-env's meta-action vehicle on a WOMD map: ``LANE_LEFT``/``LANE_RIGHT`` go to
    the map's neighbour on that side where there is one (else nothing happens). With a
    :attr:`safety` layer (:mod:`tap_bench.sim.womd_safety`, an agent's action config asks
    for it) its controller's acceleration is capped at every step.

    ``FASTER`` and ``SLOWER`` move the target speed one step up or down the grid from the
    grid speed nearest the vehicle's speed (:meth:`speed_to_index`), and the start's target
    speed is the grid speed nearest the one given. ``speed_index="uniform"`` (one of
    :data:`SPEED_INDEX`) keeps highway-env's reading of the grid instead, for the models
    that trained with it."""

    safety: Any = None

    def __init__(self, *args: Any, speed_index: str = "nearest", **kwargs: Any) -> None:
        if speed_index not in SPEED_INDEX:
            raise ParameterError("speed_index", speed_index, f"one of {SPEED_INDEX}")
        self.uniform_speed_index = speed_index == "uniform"
        super().__init__(*args, **kwargs)

    def speed_to_index(self, speed: float) -> int:
        """The index of the grid speed nearest ``speed`` [m/s] (the lower of two as near).

        highway-env computes it as if the grid were evenly spaced from its first to its last
        speed; tap-bench's grid (:data:`tap_bench.sim.womd_env.TARGET_SPEEDS`, 2.5 m/s apart
        up to 20, then 5) is not, and by that formula ``FASTER`` left the target at the
        vehicle's speed from 7.5 m/s up while ``SLOWER`` took 5 m/s off it."""
        if self.uniform_speed_index:
            return int(super().speed_to_index(speed))
        return int(np.argmin(np.abs(np.asarray(self.target_speeds, dtype=float) - speed)))

    def act(self, action: Any = None) -> None:
        if action in ("LANE_LEFT", "LANE_RIGHT"):
            side = "left" if action == "LANE_LEFT" else "right"
            for index in self.road.network.side_lanes_at(self.lane_index, self.position,
                                                         side):
                if self.road.network.get_lane(index).is_reachable_from(self.position):
                    self.target_lane_index = index
                    break
            action = None
        super().act(action)
        if self.safety is not None and not self.crashed:
            others = [v for v in self.road.vehicles if v is not self
                      and getattr(v, "collidable", True) and not getattr(v, "hidden", False)]
            clock = getattr(self.road, "clock", None)
            self.safety.apply(self, others, clock[0] if clock else None)

    def step(self, dt: float) -> None:
        super().step(dt)
        self.speed = max(self.speed, 0.0)  # highway-env lets a braking vehicle reverse


@dataclass(frozen=True)
class DriverParameters:
    """One IDM/MOBIL driver of idm traffic (SPEC section 8; Treiber & Kesting, *Traffic Flow
    Dynamics*, 2013, ch. 11: IDM with the constant-acceleration heuristic of its ACC model;
    Kesting et al. 2007: MOBIL).

    Attributes:
        speed_factor: desired speed v0 as a multiple of the vehicle's reference speed (the
            fastest it drove in the log) [-].
        time_gap: desired time gap T [s].
        min_gap: jam distance s0, bumper to bumper [m].
        max_acceleration: a [m/s^2].
        comfortable_braking: b [m/s^2] (positive): the braking the driver plans with.
        emergency_braking: the most it brakes at all [m/s^2] (positive).
        delta: free-road exponent [-].
        coolness: c of the ACC model: how much the heuristic that the leader keeps its
            speed softens IDM's braking when the gap is tight but not critical [-].
        politeness: MOBIL's p [-].
        lane_change_gain: MOBIL's threshold [m/s^2].
        safe_braking: MOBIL's most braking imposed on the new follower [m/s^2].
        critical_gap: gap acceptance at a conflict (a crossing or merging lane): the driver
            goes when the other reaches the conflict point at least this much later [s].
    """

    speed_factor: float = 1.0
    time_gap: float = 1.2
    min_gap: float = 2.0
    max_acceleration: float = 1.5
    comfortable_braking: float = 2.0
    emergency_braking: float = 8.0
    delta: float = 4.0
    coolness: float = 0.99
    politeness: float = 0.25
    lane_change_gain: float = 0.2
    safe_braking: float = 3.0
    critical_gap: float = 3.0

    def __post_init__(self) -> None:
        for name in ("speed_factor", "time_gap", "min_gap", "max_acceleration",
                     "comfortable_braking", "emergency_braking", "delta", "critical_gap"):
            if not getattr(self, name) > 0:
                raise ParameterError(name, getattr(self, name), "a positive number")
        if self.emergency_braking < self.comfortable_braking:
            raise ParameterError("emergency_braking", self.emergency_braking,
                                 f"at least comfortable_braking ({self.comfortable_braking})")
        if not 0 <= self.coolness < 1 or not 0 <= self.politeness <= 1:
            raise ParameterError("coolness/politeness", (self.coolness, self.politeness),
                                 "coolness in [0, 1), politeness in [0, 1]")


NOMINAL_DRIVER = DriverParameters()
"""Rollout 0's driver: the medians of :func:`draw_driver`'s distributions."""


def draw_driver(rng: np.random.Generator) -> DriverParameters:
    """A driver drawn for one rollout (medians: :data:`NOMINAL_DRIVER`):

    - desired speed factor: lognormal, median 1, sigma 0.1 (+-10 % around the fastest
      logged speed), within [0.75, 1.3];
    - time gap T: lognormal, median 1.2 s, sigma 0.3, within [0.6, 2.5] s;
    - jam distance s0: uniform 1.5-2.5 m;
    - acceleration a: lognormal, median 1.5, sigma 0.25, within [0.8, 3.0] m/s^2;
    - comfortable braking b: lognormal, median 2.0, sigma 0.25, within [1.2, 3.5] m/s^2;
    - politeness p: uniform 0-0.5; critical gap: uniform 2.5-3.5 s.

    City values of Treiber & Kesting (2013, table 11.2: T 1.0-1.5 s, s0 2 m, a 1.0-1.5,
    b 1.5-2.0) and Kesting et al. (2007: p 0-0.5).
    """

    def lognormal(median: float, sigma: float, low: float, high: float) -> float:
        return float(np.clip(median * math.exp(sigma * rng.standard_normal()), low, high))

    return DriverParameters(
        speed_factor=lognormal(1.0, 0.1, 0.75, 1.3),
        time_gap=lognormal(1.2, 0.3, 0.6, 2.5),
        min_gap=float(rng.uniform(1.5, 2.5)),
        max_acceleration=lognormal(1.5, 0.25, 0.8, 3.0),
        comfortable_braking=lognormal(2.0, 0.25, 1.2, 3.5),
        politeness=float(rng.uniform(0.0, 0.5)),
        critical_gap=float(rng.uniform(2.5, 3.5)))


class WomdIDMVehicle(_RouteMixin, IDMVehicle):
    """IDM/MOBIL on a WOMD map: follows its route (the route's lane changes included), MOBIL
    only towards the map's neighbours, stops at red (and yellow, when it can) stop points and
    before pedestrians and cyclists in its way, never reverses.

    The longitudinal model is IDM (written from Treiber & Kesting's equations) with the
    constant-acceleration heuristic of their ACC model: when IDM would brake harder than the
    situation needs assuming the leader keeps its speed, the braking is blended towards that
    need (coolness c), so a tight but harmless gap is closed at about the comfortable braking
    b rather than at IDM's clamp; the braking is limited to the driver's emergency braking.
    Traffic vehicles carry their own :class:`DriverParameters` (``driver``); a vehicle
    without one (the IDM ego of the ``idm`` policies) takes its parameters from highway-env's
    constants set on it (``TIME_WANTED``, ``DISTANCE_WANTED`` front to front,
    ``COMFORT_ACC_MAX``, ``COMFORT_ACC_MIN``, ``DELTA``, ``POLITENESS``)."""

    driver: DriverParameters | None = None
    hidden = False  # waiting for the step it appears at (appear_at)

    def appear_at(self, step: int) -> None:
        """Wait off the road, not collidable, until the road's step ``step``, then drive
        from where the vehicle was made (its logged state at that step)."""
        self.hidden = True
        self.start_step = int(step)
        self.start_state = (self.position.copy(), float(self.heading), float(self.speed))
        self.position = np.array([HIDDEN + 10.0 * getattr(self, "row", 0), -HIDDEN])
        self.collidable = False

    def _appear(self) -> None:
        position, heading, speed = self.start_state
        self.position, self.heading, self.speed = position.copy(), heading, speed
        network = self.road.network
        self.lane_index = network.get_closest_lane_index(position, heading)
        self.lane = network.get_lane(self.lane_index)
        self.target_lane_index = self.lane_index
        self.hidden = False
        self.collidable = True

    def act(self, action: Any = None) -> None:
        """Decide this step's steering and acceleration (``action`` is ignored): along the
        road and its route, a lane change by :meth:`change_lane_policy` (MOBIL), steering
        to the target lane (:meth:`steering_control`), and the IDM acceleration behind the
        leader on its lane, and on the target lane too while changing (the smaller), within
        ``ACC_MAX``. A crashed or hidden vehicle keeps its last action.

        Asked before the road has acted in this step (highway-env acts the controlled
        vehicle at each decision, then the road acts every vehicle), it follows the road and
        its lane changes, and asks about the standing obstacles for what they remember (the
        yellow lines held, the stop signs served, the walkers seen at this step), but leaves
        the steering and acceleration to the road's act, which decides them again with this
        step's movers."""
        if self.hidden or self.crashed:
            return
        self.follow_road()
        if self.enable_lane_change:
            self.change_lane_policy()
        if getattr(self.road, "acted", True) is False:
            self._standing_obstacles()
            return
        steering = self.steering_control(self.target_lane_index)
        road = self.road
        front, rear = road.neighbour_vehicles(self, self.lane_index)
        acc = self.acceleration(self, front, rear)
        if self.lane_index != self.target_lane_index:
            front, rear = road.neighbour_vehicles(self, self.target_lane_index)
            acc = min(acc, self.acceleration(self, front, rear))
        limit = self.ACC_MAX
        self.action = {"steering": steering,
                       "acceleration": -limit if acc < -limit else min(acc, limit)}

    def steering_control(self, target_lane_index: Any) -> float:
        """Front-wheel angle [rad] that keeps the vehicle on the centre of the lane
        ``target_lane_index``: the lane-keeping cascade of
        :func:`~tap_bench.sim.driver_models.steering_one` with this vehicle's gains, the
        lane's heading taken ``TAU_PURSUIT`` s ahead at its speed; within
        ``+-MAX_STEERING_ANGLE``."""
        lane = self.road.network.get_lane(target_lane_index)
        along, lateral = lane.local_coordinates(self.position)
        speed = float(self.speed)
        ahead = float(lane.heading_at(along + speed * self.TAU_PURSUIT))
        return steering_one(float(lateral), float(self.heading), ahead, speed,
                            float(self.LENGTH), self.KP_LATERAL, self.KP_HEADING,
                            self.MAX_STEERING_ANGLE)

    def parameters(self) -> DriverParameters:
        """This vehicle's driver (see the class docstring)."""
        if self.driver is not None:
            return self.driver
        # made once per set of constants (asked several times a step)
        key = (self.TIME_WANTED, self.DISTANCE_WANTED, self.COMFORT_ACC_MAX,
               self.COMFORT_ACC_MIN, self.ACC_MAX, self.DELTA, self.POLITENESS)
        made = self.__dict__.get("_parameters_made")
        if made is None or made[0] != key:
            made = self.__dict__["_parameters_made"] = (key, DriverParameters(
                time_gap=float(self.TIME_WANTED),
                min_gap=max(float(self.DISTANCE_WANTED) - ControlledVehicle.LENGTH, 0.5),
                max_acceleration=float(self.COMFORT_ACC_MAX),
                comfortable_braking=float(-self.COMFORT_ACC_MIN),
                emergency_braking=max(float(self.ACC_MAX), float(-self.COMFORT_ACC_MIN)),
                delta=float(self.DELTA), politeness=float(self.POLITENESS)))
        return made[1]

    def set_driver(self, driver: DriverParameters) -> None:
        """Drive with ``driver`` (MOBIL's constants set on this vehicle too)."""
        self.driver = driver
        self.POLITENESS = driver.politeness
        self.LANE_CHANGE_MIN_ACC_GAIN = driver.lane_change_gain
        self.LANE_CHANGE_MAX_BRAKING_IMPOSED = driver.safe_braking
        self.ACC_MAX = driver.emergency_braking

    def change_lane_policy(self) -> None:
        change = self._route_change()
        if change is not None and self.lane_index == self.target_lane_index:
            if self.road.network.get_lane(change).is_reachable_from(self.position):
                self.target_lane_index = change
                return
        # asked_from's block, without a generator's context manager at every step (the
        # policy usually returns at once: a lane change is decided once a second)
        network = self.road.network
        before, network._asking_position = network._asking_position, self.position
        try:
            super().change_lane_policy()
        finally:
            network._asking_position = before

    def mobil(self, lane_index: Any) -> bool:
        """highway-env's MOBIL without its planned-lane shortcut: that shortcut reads a route
        as lanes numbered across the road (``route[0][2]``), and every WOMD lane is number 0,
        so it accepted every safe change and a vehicle went back and forth between
        neighbours each second. The route's own lane changes are taken in
        :meth:`change_lane_policy`; MOBIL decides the others on its acceleration gain."""
        route, self.route = self.route, None
        try:
            return super().mobil(lane_index)
        finally:
            self.route = route

    def acceleration(self, ego_vehicle: ControlledVehicle, front_vehicle: Vehicle = None,
                     rear_vehicle: Vehicle = None) -> float:
        """IDM + ACC heuristic acceleration [m/s^2] of ``ego_vehicle`` (this vehicle, or
        another one MOBIL asks about) behind ``front_vehicle``; for this vehicle also before
        the stop points, walkers and conflicts ahead."""
        if not isinstance(ego_vehicle, Vehicle):
            return 0.0
        p = (ego_vehicle.parameters() if isinstance(ego_vehicle, WomdIDMVehicle)
            else self.parameters())
        v = max(float(ego_vehicle.speed), 0.0)
        v0 = float(getattr(ego_vehicle, "target_speed", v))
        lane = getattr(ego_vehicle, "lane", None)
        if (getattr(ego_vehicle, "driver", None) is None and lane is not None
                and lane.speed_limit is not None):
            v0 = min(v0, float(lane.speed_limit))  # the IDM ego keeps to the limit
        v0 = max(v0, 0.01)  # traffic drives at its own logged pace
        acc = p.max_acceleration * (1.0 - (v / v0) ** p.delta)
        if front_vehicle is not None:
            gap = (ego_vehicle.lane_distance_to(front_vehicle)
                - (ego_vehicle.LENGTH + front_vehicle.LENGTH) / 2)
            lead = float(np.dot(front_vehicle.velocity, ego_vehicle.direction))
            acc = _idm_acc(p, v, v0, gap, max(lead, 0.0))
        if ego_vehicle is self:
            for limit in self._obstacle_accelerations(p, v, v0):
                acc = min(acc, limit)
        return float(max(acc, -p.emergency_braking))

    def _obstacle_accelerations(self, p: DriverParameters, v: float, v0: float
                                ) -> tuple[float, ...]:
        """This vehicle's IDM accelerations [m/s^2] (driver ``p``, speed ``v`` and desired
        speed ``v0`` [m/s]) behind what it finds on its way beyond its own lane's leader, in
        the order :meth:`acceleration` takes their minimum: the leader on its next lanes,
        the corridor's leader, then each standing obstacle (:meth:`_standing_obstacles`).

        Asked again within a step of the road for the same state (a lane change's second
        lane, MOBIL's questions), it answers from the first time: the searches read the
        step's movers, and what the stop points and signs remember changes only at the
        first asking."""
        road = self.road
        key = (getattr(road, "clock", (None,))[0], getattr(road, "_positions", None) is None,
               id(getattr(road, "_movers", None)), id(self.route), self.lane_index,
               self.position.tobytes(), self.heading, self.speed, v, v0)
        memo = self.__dict__.get("_obstacle_memo")
        if memo is not None and memo[1] is p and memo[0] == key:
            return memo[2]
        ahead = getattr(road, "obstacles_ahead", None)
        found = ahead(self) if ahead is not None else None
        if found is None:  # one search after the other
            leader_ahead = getattr(road, "leader_ahead", None)
            leader, d = leader_ahead(self) if leader_ahead is not None else (None, math.inf)
            corridor = getattr(road, "corridor_leader", None)
            found = (leader, d, corridor(self) if corridor is not None else None,
                     self._standing_obstacles())
        leader, d, corridor, standing = found
        out = []
        if leader is not None:
            lead = float(np.dot(leader.velocity, self.direction))
            out.append(_idm_acc(p, v, v0, d - (self.LENGTH + leader.LENGTH) / 2,
                                max(lead, 0.0)))
        if corridor is not None:
            out.append(_idm_acc(p, v, v0, corridor[0], max(corridor[1], 0.0)))
        for d in standing:
            out.append(_idm_acc(p, v, v0, d, 0.0))
        self.__dict__["_obstacle_memo"] = (key, p, tuple(out))
        return self.__dict__["_obstacle_memo"][2]

    def _standing_obstacles(self) -> list[float]:
        """Gaps [m] from the front bumper to where it must stop: red stop points and stop
        signs not yet stopped at (less :data:`STOP_MARGIN`), walkers in its way (less their
        radius and the margin), conflict zones where it gives way
        (:meth:`WomdRoad.conflict_gap`)."""
        out = []
        road = self.road
        stop = getattr(road, "stop_distance", None)
        if stop is not None:
            d = stop(self)
            if d is not None:
                out.append(d - self.LENGTH / 2 - STOP_MARGIN)
        walker = getattr(road, "walker_distance", None)
        if walker is not None:
            d = walker(self)
            if d is not None:
                out.append(d - WALKER_RADIUS - self.LENGTH / 2 - STOP_MARGIN)
        sign = getattr(road, "stop_sign_distance", None)
        if sign is not None:
            d = sign(self)
            if d is not None:
                out.append(d - self.LENGTH / 2 - STOP_MARGIN)
        conflict = getattr(road, "conflict_gap", None)
        if conflict is not None:
            d = conflict(self)
            if d is not None:
                out.append(d)
        return out

    def step(self, dt: float) -> None:
        """Move by the kinematic bicycle model (:func:`~tap_bench.sim.driver_models.
        bicycle_one`) with this step's action, clipped as highway-env's ``clip_actions``
        does (a crashed vehicle stops straight; speeds within ``[MIN_SPEED, MAX_SPEED]``),
        add a pending impact (then crashed), look the lane up (``on_state_update``); never
        reverse. A hidden vehicle waits for its step."""
        if self.hidden:
            if self.road.clock[0] >= self.start_step:
                self._appear()
            return
        speed = float(self.speed)
        steering, acc = limited_action(self)
        x, y, heading, speed = bicycle_one(float(self.position[0]), float(self.position[1]),
                                           float(self.heading), speed, steering, acc,
                                           float(self.LENGTH), dt)
        if self.impact is not None:
            x, y = x + float(self.impact[0]), y + float(self.impact[1])
            self.crashed = True
            self.impact = None
        self.timer += dt
        self.position, self.heading, self.speed = np.array((x, y)), heading, speed
        self.on_state_update()
        self.speed = max(self.speed, 0.0)  # IDM can ask a stopped vehicle to reverse


def _idm_acc(p: DriverParameters, v: float, v0: float, gap: float, lead: float) -> float:
    """IDM with the ACC model's constant-acceleration heuristic (Treiber & Kesting 2013,
    eqs. 11.3-11.4 and 11.25-11.26, the leader's acceleration taken as 0).

    Args:
        p: the driver.
        v: own speed [m/s]; v0: desired speed [m/s].
        gap: bumper-to-bumper gap to the leader (or standing obstacle) [m].
        lead: the leader's speed along our heading [m/s].
    """
    dv = v - lead
    s_star = p.min_gap + max(0.0, v * p.time_gap
                             + v * dv / (2.0 * math.sqrt(p.max_acceleration
                                                          * p.comfortable_braking)))
    s = max(gap, 0.01)
    a_idm = p.max_acceleration * (1.0 - (v / v0) ** p.delta - (s_star / s) ** 2)
    # what the situation needs if the leader keeps its speed: nothing while it is faster,
    # else the braking that matches its speed at the bumper
    a_cah = 0.0 if dv <= 0 else -dv * dv / (2.0 * s)
    if a_idm >= a_cah:
        return a_idm
    b = p.comfortable_braking
    return (1.0 - p.coolness) * a_idm + p.coolness * (a_cah + b * math.tanh((a_idm - a_cah)
                                                                            / b))


# ------------------------------------------------------------------ driving along the log


PATH_SPACING = 0.5  # [m] a logged position this close to the last one kept is dropped
PATH_EXTENSION = 100.0  # [m] the path goes on straight past its last logged position
PATH_LOOKAHEAD = 30.0  # [m] a path vehicle looks this far ahead along its path ...
PATH_TIME = 3.0  # [s] ... plus this long at its speed
PATH_MARGIN = 0.1  # [m] beyond both half widths: a box this close to the path is in the way
PATH_PREDICTION = (1.0, 2.0)  # [s] where crossing movers will be (constant velocity)
PATH_CROSSING = math.cos(math.radians(30.0))  # a mover more across the path than 30 deg
PATH_ARRIVAL = 1.0  # [s] a predicted blocker counts when we would be there by then + this
DESIRED_BEHIND = 10.0  # [m] the desired speed is the fastest logged speed from this far back
DESIRED_AHEAD = 20.0  # [m] ... to this far ahead along the path
DESIRED_MIN = 1.0  # [m/s] the slowest desired speed
APPEAR_CLEARANCE = 1.0  # [m] a vehicle appears when its box this much longer at each end is free


def _box_polygon(x: float, y: float, heading: float, length: float, width: float
                 ) -> np.ndarray:
    """(5, 2) closed polygon of a box (highway-env's polygon convention)."""
    c, s = math.cos(heading), math.sin(heading)
    hl, hw = length / 2, width / 2
    corners = np.array([[-hl, -hw], [-hl, hw], [hl, hw], [hl, -hw]]) @ np.array([[c, s],
                                                                               [-s, c]])
    corners += (x, y)
    return np.vstack([corners, corners[:1]])


@dataclass(frozen=True)
class LoggedPath:
    """The path a vehicle drove in the log (sim frame), as a polyline by arc length.

    Attributes:
        points: (n, 2) [m], positions at least :data:`PATH_SPACING` apart (the standstill
            jitter of the log dropped), then one :data:`PATH_EXTENSION` m further along the
            last heading.
        cum: (n,) arc length of each point from the first [m].
        heading: (n,) the logged heading at each point, unwrapped [rad].
        reference: (n,) the fastest logged speed within :data:`DESIRED_BEHIND` m behind and
            :data:`DESIRED_AHEAD` m ahead of each point [m/s] (the desired speed's scale).
        steps: (n,) the record's step at which the log was at each point (the extension:
            inf).
    """

    points: np.ndarray
    cum: np.ndarray
    heading: np.ndarray
    reference: np.ndarray
    steps: np.ndarray

    def step_at(self, s: float) -> float:
        """The record's step at which the log reached arc length ``s`` [m] (inf beyond
        the logged part)."""
        k = int(np.searchsorted(self.cum, s, side="left"))
        return float(self.steps[min(k, len(self.steps) - 1)])

    def at(self, s: float) -> tuple[float, float, float]:
        """(x, y, heading) at arc length ``s`` [m] (clipped to the path)."""
        cum = self.cum
        k = int(np.searchsorted(cum, s, side="right")) - 1
        k = min(max(k, 0), len(cum) - 2)
        span = cum[k + 1] - cum[k]
        u = min(max((s - cum[k]) / span, 0.0), 1.0) if span > 0 else 0.0
        a, b = self.points[k], self.points[k + 1]
        return (float(a[0] + u * (b[0] - a[0])), float(a[1] + u * (b[1] - a[1])),
                float(self.heading[k] + u * (self.heading[k + 1] - self.heading[k])))

    @property
    def length(self) -> float:
        """Arc length of the logged part [m] (the extension not counted)."""
        return float(self.cum[-1] - PATH_EXTENSION)

    def reference_at(self, s: float) -> float:
        """The desired speed's scale at arc length ``s`` [m/s]."""
        return float(np.interp(s, self.cum, self.reference))

    def project(self, point: np.ndarray) -> tuple[float, float, float]:
        """(s [m], signed lateral distance [m], the path's direction there [rad]) of a point
        on the nearest segment of the whole path."""
        s, d, theta = _project_path(self.points[:, 0], self.points[:, 1], self.cum,
                                    0.0, float(self.cum[-1]), float(point[0]),
                                    float(point[1]))
        return s, d, theta


def window_max(values: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(m,) the largest of ``values[lo[i]:hi[i]]`` for every window i (each non-empty:
    ``lo < hi``), from a table of the maxima of every run of 2^k values (two overlapping
    runs cover a window), without a loop over the windows.

    Args:
        values: (n,) float, no NaN.
        lo, hi: (m,) int, 0 <= lo < hi <= n.
    """
    values = np.asarray(values, dtype=np.float64)
    lo, hi = np.asarray(lo, dtype=np.int64), np.asarray(hi, dtype=np.int64)
    runs = [values]  # runs[k][j]: the largest of values[j:j + 2^k]
    while 2 ** len(runs) <= len(values):
        half = 2 ** (len(runs) - 1)
        runs.append(np.maximum(runs[-1][:-half], runs[-1][half:]))
    table = np.full((len(runs), len(values)), -np.inf)
    for k, run in enumerate(runs):
        table[k, :len(run)] = run
    level = np.zeros(len(lo), dtype=np.int64)  # the largest k with 2^k <= hi - lo
    while ((2 ** (level + 1)) <= hi - lo).any():
        level += (2 ** (level + 1)) <= hi - lo
    return np.maximum(table[level, lo], table[level, hi - 2 ** level])


def logged_path(xy: np.ndarray, heading: np.ndarray, speed: np.ndarray,
                steps: np.ndarray | None = None) -> LoggedPath:
    """The :class:`LoggedPath` of a vehicle's valid logged states (sim frame), in order.

    Args:
        xy: (T, 2) positions [m]; heading: (T,) [rad]; speed: (T,) [m/s] (NaN: 0).
        steps: (T,) the record's step of each state (default 0, 1, ...).
    """
    xy = np.asarray(xy, float)
    if len(xy) == 0:
        raise ParameterError("xy", "no positions", "at least one valid logged state")
    heading = np.unwrap(np.asarray(heading, float))
    speed = np.nan_to_num(np.asarray(speed, float), nan=0.0)
    keep = [0]
    xs, ys = xy[:, 0].tolist(), xy[:, 1].tolist()  # the same numbers as Python floats
    for k in range(1, len(xy)):
        j = keep[-1]
        if math.hypot(xs[k] - xs[j], ys[k] - ys[j]) >= PATH_SPACING:
            keep.append(k)
    points = xy[keep]
    headings = heading[keep]
    speeds = speed[keep]
    at = (np.arange(len(xy)) if steps is None else np.asarray(steps, float))[keep]
    # the fastest speed of the dropped (standstill) samples is at most the kept one's
    cum = (np.r_[0.0, np.cumsum(np.hypot(*np.diff(points, axis=0).T))] if len(points) > 1
        else np.zeros(1))
    end = points[-1] + PATH_EXTENSION * np.array([math.cos(headings[-1]),
                                                  math.sin(headings[-1])])
    points = np.vstack([points, end])
    cum = np.r_[cum, cum[-1] + PATH_EXTENSION]
    headings = np.r_[headings, headings[-1]]
    speeds = np.r_[speeds, speeds[-1]]
    at = np.r_[np.asarray(at, float), np.inf]
    lo = np.searchsorted(cum, cum - DESIRED_BEHIND, side="left")
    hi = np.searchsorted(cum, cum + DESIRED_AHEAD, side="right")
    reference = window_max(speeds, lo, np.maximum(hi, lo + 1))
    return LoggedPath(points, cum, headings, reference, at)


@numba.njit(cache=True, nogil=True)
def _to_segment(px, py, k, qx, qy):  # pragma: no cover - compiled
    """(distance [m], u) from point q to segment k of a path (points k to k + 1), u in
    [0, 1] the share along the segment of its nearest point; distance inf for a segment
    of zero length."""
    dx, dy = px[k + 1] - px[k], py[k + 1] - py[k]
    n2 = dx * dx + dy * dy
    if n2 <= 0:
        return np.inf, 0.0
    u = ((qx - px[k]) * dx + (qy - py[k]) * dy) / n2
    u = min(max(u, 0.0), 1.0)
    return math.hypot(qx - px[k] - u * dx, qy - py[k] - u * dy), u


@numba.njit(cache=True, nogil=True)
def _on_segment(px, py, cum, k, u, qx, qy):  # pragma: no cover - compiled
    """(s [m] along the path, signed lateral distance [m], direction [rad]) of point q
    projected at share u of segment k (:func:`_to_segment`); positive lateral: q to the
    segment's left."""
    dx, dy = px[k + 1] - px[k], py[k + 1] - py[k]
    n = math.sqrt(dx * dx + dy * dy)
    ex, ey = qx - px[k] - u * dx, qy - py[k] - u * dy
    return cum[k] + u * n, (dx * ey - dy * ex) / n, math.atan2(dy, dx)


@numba.njit(cache=True, nogil=True)
def _project_path(px, py, cum, s0, s1, qx, qy):  # pragma: no cover - compiled
    """(s, signed lateral distance, direction) of point q on the nearest segment of the
    path with some part in [s0, s1] (s NaN when none)."""
    best, bs, bd, bt = np.inf, np.nan, np.nan, 0.0
    k0 = max(np.searchsorted(cum, s0, side="right") - 1, 0)
    for k in range(k0, px.shape[0] - 1):
        if cum[k] > s1:
            break
        dist, u = _to_segment(px, py, k, qx, qy)
        if dist < best:
            best = dist
            bs, bd, bt = _on_segment(px, py, cum, k, u, qx, qy)
    return bs, bd, bt


CHUNK = 8  # path segments bounded by one circle in the nearest-segment search
CHUNK_SLACK = 1e-6  # [m] a chunk is skipped only when surely farther than the nearest found


@numba.njit(cache=True, nogil=True)
def _window_chunks(px, py, cum, s0, s1):  # pragma: no cover - compiled
    """The segments of a path with some part in [s0, s1] (k0 to k1 - 1, as
    :func:`_project_path` scans them) in chunks of :data:`CHUNK`: each chunk's bounding
    circle (centres (c, 2), radii (c,)) [m]."""
    k0 = max(np.searchsorted(cum, s0, side="right") - 1, 0)
    k1 = k0
    while k1 < px.shape[0] - 1 and cum[k1] <= s1:
        k1 += 1
    count = (k1 - k0 + CHUNK - 1) // CHUNK
    centres = np.empty((count, 2))
    radii = np.empty(count)
    for c in range(count):
        a = k0 + c * CHUNK
        b = min(a + CHUNK, k1)  # points a to b (the segments' ends)
        lo_x, hi_x, lo_y, hi_y = px[a], px[a], py[a], py[a]
        for k in range(a + 1, b + 1):
            lo_x, hi_x = min(lo_x, px[k]), max(hi_x, px[k])
            lo_y, hi_y = min(lo_y, py[k]), max(hi_y, py[k])
        mx, my = 0.5 * (lo_x + hi_x), 0.5 * (lo_y + hi_y)
        r = 0.0
        for k in range(a, b + 1):
            r = max(r, math.hypot(px[k] - mx, py[k] - my))
        centres[c, 0], centres[c, 1], radii[c] = mx, my, r
    return k0, k1, centres, radii


@numba.njit(cache=True, nogil=True)
def _project_window(px, py, cum, k0, k1, centres, radii, qx, qy):  # pragma: no cover
    """:func:`_project_path` over the segments k0 to k1 - 1 (:func:`_window_chunks`),
    the same answer: a chunk whose circle is farther than the nearest segment found so far
    holds no nearer one and is skipped; the point is placed on the nearest segment once,
    at the end (the same segment and share as :func:`_project_path` places it on)."""
    best, best_k, best_u = np.inf, -1, 0.0
    for c in range(radii.shape[0]):
        if (math.hypot(qx - centres[c, 0], qy - centres[c, 1]) - radii[c]
                > best + CHUNK_SLACK):
            continue
        a = k0 + c * CHUNK
        for k in range(a, min(a + CHUNK, k1)):
            dist, u = _to_segment(px, py, k, qx, qy)
            if dist < best:
                best, best_k, best_u = dist, k, u
    if best_k < 0:
        return np.nan, np.nan, 0.0
    return _on_segment(px, py, cum, best_k, best_u, qx, qy)


@numba.njit(cache=True, nogil=True)
def _path_blockers(px, py, cum, s0, s1, x0, y0, half_width, half_length, margins,
                   xs, ys, hs, vs, ls, ws, horizons, unpredicted, skip
                   ):  # pragma: no cover - compiled
    """The movers in a path's way ahead, now and predicted.

    For each mover j (centre xs, ys, heading hs, speed vs, box ls x ws) and each horizon
    tau (0 first: where it is now; then where it will be at constant velocity, for movers
    across the path, except those ``unpredicted``), whether its box is within the half
    widths + ``margins[j]`` of the path between s0 and s1 with its centre ahead of s0.
    Mover ``skip`` (the path's own vehicle; -1: none) is not looked at (NaN gaps).

    Returns:
        (m * H, 4): gap from our bumper to its box along the path [m], its speed along the
        path [m/s], tau [s], j; NaN gap where not in the way.
    """
    m, h = xs.shape[0], horizons.shape[0]
    out = np.full((m * h, 4), np.nan)
    reach = s1 - s0
    k0, k1, centres, radii = _window_chunks(px, py, cum, s0, s1)
    for j in range(m):
        if j == skip:
            continue
        far = reach + ls[j] + half_length
        cos_j, sin_j = math.cos(hs[j]), math.sin(hs[j])
        s, d, theta = np.nan, np.nan, np.nan
        x_now, y_now = np.nan, np.nan  # the point projected last (a standing one's again)
        for t in range(h):
            tau = horizons[t]
            if tau > 0 and unpredicted[j]:
                continue
            cx = xs[j] + tau * vs[j] * cos_j
            cy = ys[j] + tau * vs[j] * sin_j
            # hypot is at least either side: a side longer than far skips the hypot
            if (abs(cx - x0) > far or abs(cy - y0) > far
                    or math.hypot(cx - x0, cy - y0) > far):
                continue
            if not (cx == x_now and cy == y_now):
                s, d, theta = _project_window(px, py, cum, k0, k1, centres, radii, cx, cy)
                x_now, y_now = cx, cy
            if not s > s0:
                continue
            c = math.cos(hs[j] - theta)
            if tau > 0 and abs(c) > PATH_CROSSING and vs[j] > 0.5:
                continue  # moving along the path: it is a leader now, not a blocker
            sn = abs(math.sin(hs[j] - theta))
            across = sn * ls[j] / 2 + abs(c) * ws[j] / 2
            along = abs(c) * ls[j] / 2 + sn * ws[j] / 2
            if abs(d) >= half_width + across + margins[j]:
                continue
            out[j * h + t, 0] = s - s0 - half_length - along
            out[j * h + t, 1] = vs[j] * c if tau == 0 else 0.0
            out[j * h + t, 2] = tau
            out[j * h + t, 3] = j
    return out


@numba.njit(cache=True, nogil=True)
def _idm_compiled(v, v0, gap, lead, min_gap, time_gap, a, b, delta, coolness, two
                  ):  # pragma: no cover - compiled
    """:func:`_idm_acc` compiled, the same operations in the same order; ``two`` is the
    square's exponent 2.0 passed at run time, so that the square is the C library's ``pow``
    as in Python (a constant exponent is compiled to a multiplication, whose last bit can
    differ from ``pow``'s)."""
    dv = v - lead
    s_star = min_gap + max(0.0, v * time_gap + v * dv / (2.0 * math.sqrt(a * b)))
    s = max(gap, 0.01)
    a_idm = a * (1.0 - (v / v0) ** delta - (s_star / s) ** two)
    a_cah = 0.0 if dv <= 0 else -dv * dv / (2.0 * s)
    if a_idm >= a_cah:
        return a_idm
    return (1.0 - coolness) * a_idm + coolness * (a_cah + b * math.tanh((a_idm - a_cah) / b))


@numba.njit(cache=True, nogil=True)
def _path_ahead(starts, ends, px, py, cum, s0, s1, x0, y0, half_width, half_length, speed, v0,
                drivers, mine, margins, xs, ys, hs, vs, ls, ws, walker, is_path, horizons,
                two):  # pragma: no cover - compiled
    """Every path vehicle's IDM acceleration [m/s^2] behind what is in its way ahead
    (:meth:`WomdPathVehicle.ahead_acceleration`, for n vehicles at once).

    Path i is points starts[i] to ends[i] - 1 of (px, py, cum); s0, s1: where it is
    and how far it looks along its path [m]; (x0, y0), half widths and lengths [m], speed
    and desired speed v0 [m/s]: (n,); drivers: (n, 6) max acceleration, comfortable
    braking, delta, jam distance, time gap, coolness; mine: its row among the movers (-1:
    none). The movers (m,): centres, headings, speeds, boxes, ``margins``, pedestrians or
    cyclists (``walker``), path vehicles (``is_path``)."""
    n = s0.shape[0]
    out = np.empty(n)
    h = horizons.shape[0]
    for i in range(n):
        lo, hi = starts[i], ends[i]
        a, b, delta = drivers[i, 0], drivers[i, 1], drivers[i, 2]
        v = speed[i]
        acc = a * (1.0 - (v / v0[i]) ** delta)
        found = _path_blockers(px[lo:hi], py[lo:hi], cum[lo:hi], s0[i], s1[i], x0[i], y0[i],
                               half_width[i], half_length[i], margins, xs, ys, hs, vs, ls, ws,
                               horizons, is_path, mine[i])
        for r in range(found.shape[0]):
            gap = found[r, 0]
            if not np.isfinite(gap) or r // h == mine[i]:
                continue
            lead, tau, j = found[r, 1], found[r, 2], int(found[r, 3])
            if tau > 0 and is_path[j]:
                continue  # where logged paths cross, the log's order decides
            if tau > 0 and not walker[j]:
                if (gap <= 0 or gap / (0.5 if 0.5 > v else v) > tau + PATH_ARRIVAL
                        or v * v > 2 * b * gap):
                    continue
            x = _idm_compiled(v, v0[i], gap, 0.0 if 0.0 > lead else lead, drivers[i, 3],
                              drivers[i, 4], a, b, delta, drivers[i, 5], two)
            if x < acc:
                acc = x
        out[i] = acc
    return out


@numba.njit(cache=True, nogil=True)
def _first_crossing(ax, ay, acum, na, bx, by, bcum, nb, min_sin):  # pragma: no cover
    """(s on a, s on b) [m] of the first point along polyline a (its first ``na`` points)
    where it crosses polyline b (its first ``nb``) at more than asin(min_sin); NaN if
    none."""
    blo_x, bhi_x = np.min(bx[:nb]), np.max(bx[:nb])
    blo_y, bhi_y = np.min(by[:nb]), np.max(by[:nb])
    for k in range(na - 1):
        px, py, qx, qy = ax[k], ay[k], ax[k + 1], ay[k + 1]
        if (max(px, qx) < blo_x or min(px, qx) > bhi_x or max(py, qy) < blo_y
                or min(py, qy) > bhi_y):
            continue
        ux, uy = qx - px, qy - py
        lu = math.hypot(ux, uy)
        if lu <= 0:
            continue
        for q in range(nb - 1):
            cx, cy, dx, dy = bx[q], by[q], bx[q + 1], by[q + 1]
            if (max(cx, dx) < min(px, qx) or min(cx, dx) > max(px, qx)
                    or max(cy, dy) < min(py, qy) or min(cy, dy) > max(py, qy)):
                continue
            vx, vy = dx - cx, dy - cy
            lv = math.hypot(vx, vy)
            if lv <= 0:
                continue
            den = ux * vy - uy * vx
            if abs(den) <= min_sin * lu * lv:
                continue  # (nearly) parallel: following, not crossing
            t = ((cx - px) * vy - (cy - py) * vx) / den
            w = ((cx - px) * uy - (cy - py) * ux) / den
            if 0.0 <= t <= 1.0 and 0.0 <= w <= 1.0:
                return acum[k] + t * lu, bcum[q] + w * lv
    return np.nan, np.nan


_HORIZONS = np.array((0.0, *PATH_PREDICTION))
_NONE = np.zeros(0)  # an empty column for a compiled pass's unused arguments
PATH_CROSSING_MIN = math.sin(math.radians(5.0))  # paths crossing at a smaller angle follow


class WomdPathVehicle(Vehicle):
    """An idm-traffic vehicle that drives along its logged path, IDM (with the ACC model's
    heuristic, :func:`_idm_acc`) deciding only its speed along it.

    The path (:class:`LoggedPath`) keeps every lane change, turn and lateral offset the driver
    made; what the vehicle decides is when it gets where: IDM towards a desired speed (the
    driver's :attr:`DriverParameters.speed_factor` times the fastest logged speed around
    that point of the path), behind the nearest box in the way ahead (any agent whose box is
    within both half widths + :data:`PATH_MARGIN` (a pedestrian's or cyclist's:
    :data:`WALKER_CLEARANCE`) of the path, within
    :data:`PATH_LOOKAHEAD` m + :data:`PATH_TIME` s at its speed), before a pedestrian or
    cyclist that will be in the way within :data:`PATH_PREDICTION` s, and before a vehicle
    crossing the path that will be in the way then when it would be there too (unless it can
    no longer stop comfortably), where its logged path crosses another path vehicle's that
    went first in the log (:meth:`_give_way_gap`), at red (and yellow, when it can stop
    comfortably) stop points and stop signs on its path. It never reverses. A vehicle that
    appears after the current time waits until its place is free
    (:meth:`_room_to_appear`); one whose log ends before the record's leaves the scene once
    past its logged path's end and the log's last step.

    Attributes:
        row: the track's row in the scene.
        path: the logged path; s: where it is along it [m].
        driver: its :class:`DriverParameters`.
    """

    hidden = False

    def __init__(self, road: Road, path: LoggedPath, speed: float, driver: DriverParameters,
                 length: float, width: float, row: int, last_step: int = 1 << 30) -> None:
        x, y, h = path.at(0.0)
        super().__init__(road, np.array([x, y]), h, max(float(speed), 0.0))
        self.path = path
        self.s = 0.0
        self.last_step = int(last_step)
        self.driver = driver
        self.row = row
        self.LENGTH, self.WIDTH = float(length), float(width)
        self.diagonal = math.hypot(self.LENGTH, self.WIDTH)
        self.check_collisions = True
        self.stops: list[tuple[str, Any, float]] | None = None  # found on the first act
        self.stop_signs_served: set = set()
        self.stop_signs_seen: set = set()
        self.yellow_stops: set = set()

    def parameters(self) -> DriverParameters:
        """This vehicle's driver."""
        return self.driver

    def set_driver(self, driver: DriverParameters) -> None:
        """Drive with ``driver``."""
        self.driver = driver

    @property
    def target_speed(self) -> float:
        """The desired speed here [m/s]."""
        return max(self.driver.speed_factor * self.path.reference_at(self.s), DESIRED_MIN)

    def appear_at(self, step: int) -> None:
        """Wait off the road, not collidable, until the road's step ``step``."""
        self.hidden = True
        self.start_step = int(step)
        self.position = np.array([HIDDEN + 10.0 * self.row, -HIDDEN])
        self.collidable = False

    def _room_to_appear(self) -> bool:
        """Whether the vehicle's box where it appears, :data:`APPEAR_CLEARANCE` longer at
        both ends, is clear of every other agent's (the simulated traffic may be where the
        log's was not: a vehicle that appears waits until there is room)."""
        x, y, h = self.path.at(self.s)
        mine = _box_polygon(x, y, h, self.LENGTH + 2 * APPEAR_CLEARANCE, self.WIDTH)
        reach = self.diagonal / 2 + APPEAR_CLEARANCE
        for other in self.road.vehicles:
            if other is self or not other.collidable:
                continue
            if (math.hypot(other.position[0] - x, other.position[1] - y) >
                    reach + getattr(other, "diagonal", 10.0) / 2):
                continue
            theirs = _box_polygon(float(other.position[0]), float(other.position[1]),
                                  float(other.heading), other.LENGTH, other.WIDTH)
            if utils.are_polygons_intersecting(mine, theirs, np.zeros(2), np.zeros(2))[0]:
                return False
        return True

    def act(self, action: Any = None) -> None:
        if self.hidden:
            return
        if self.crashed:  # brake to a stop, as highway-env's crashed vehicles do
            self.action = {"steering": 0.0, "acceleration": -float(self.speed)}
            return
        self.action = {"steering": 0.0, "acceleration": self.path_acceleration()}

    def path_acceleration(self) -> float:
        """IDM + ACC heuristic acceleration [m/s^2] behind whatever is in the way ahead, the
        stop points and stop signs and where it gives way (the part ahead computed for all
        path vehicles of the road at once when the road did, :meth:`WomdRoad.act`)."""
        p = self.driver
        v = max(float(self.speed), 0.0)
        ahead = getattr(self.road, "_path_accelerations", {}).get(id(self))
        if ahead is None:
            v0 = self.target_speed
            acc = self.ahead_acceleration(v, v0)
        else:
            acc, v0 = ahead
        for gap in self._stop_gaps(v):
            acc = min(acc, _idm_acc(p, v, v0, gap, 0.0))
        gap = self._give_way_gap(v)
        if gap is not None:
            acc = min(acc, _idm_acc(p, v, v0, gap, 0.0))
        return float(max(acc, -p.emergency_braking))

    def ahead_acceleration(self, v: float, v0: float) -> float:
        """IDM + ACC heuristic acceleration [m/s^2] at speed ``v`` towards the desired speed
        ``v0`` [m/s], behind the nearest box in the way ahead (see the class docstring)."""
        p = self.driver
        acc = p.max_acceleration * (1.0 - (v / v0) ** p.delta)
        road = self.road
        positions = getattr(road, "_positions", None)
        if positions is not None and len(positions):
            reach = PATH_LOOKAHEAD + PATH_TIME * v
            boxes = road._boxes
            mine = road._movers.index_of(self)  # itself: not looked at
            found = _path_blockers(
                self.path.points[:, 0], self.path.points[:, 1], self.path.cum, self.s,
                self.s + reach, float(self.position[0]), float(self.position[1]),
                self.WIDTH / 2, self.LENGTH / 2, road._path_margins, positions[:, 0],
                positions[:, 1], boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 3],
                _HORIZONS, road._path_mask, -1 if mine is None else int(mine))
            walkers = road._walker_mask
            movers = road._movers
            for gap, lead, tau, j in found[np.isfinite(found[:, 0])]:
                if tau > 0 and isinstance(movers[int(j)], WomdPathVehicle):
                    continue  # where logged paths cross, the log's order decides (below)
                if tau > 0 and not walkers[int(j)]:
                    # a vehicle later: only if we would be there by then, and can stop
                    if (gap <= 0 or gap / max(v, 0.5) > tau + PATH_ARRIVAL
                            or v * v > 2 * p.comfortable_braking * gap):
                        continue
                acc = min(acc, _idm_acc(p, v, v0, gap, max(lead, 0.0)))
        return acc

    def _give_way_gap(self, v: float) -> float | None:
        """Gap [m] from the bumper to the nearest point where its logged path crosses
        another path vehicle's that passed there first in the log (ties: the lower scene
        row first), while that one has not passed and reaches it within the driver's
        critical gap after us (and :data:`CONFLICT_HORIZON`); not once it can no longer
        stop comfortably before the crossing (it clears it). None if none."""
        conflicts = getattr(self.road, "path_conflicts", None)
        if conflicts is None:
            return None
        p = self.driver
        best = None
        for other, s_mine, s_other, first in conflicts(self):
            if first or other.hidden:
                continue
            zone_i = other.WIDTH / 2 + CONFLICT_CLEARANCE
            if self.s - self.LENGTH / 2 > s_mine + zone_i:
                continue  # we are past it
            zone_j = other.LENGTH / 2 + self.WIDTH / 2 + CONFLICT_CLEARANCE
            d_j = s_other - other.s
            if d_j < -zone_j:
                continue  # it is past it
            gap = s_mine - zone_i - self.s - self.LENGTH / 2
            if gap <= 0 or v * v > 2 * p.comfortable_braking * gap:
                continue  # in the zone, or committed: clear it
            if d_j > zone_j:
                t_j = (d_j - zone_j) / max(float(other.speed), 0.1)
                if t_j > CONFLICT_HORIZON or t_j > gap / max(v, 1.0) + p.critical_gap:
                    continue
            best = gap if best is None else min(best, gap)
        return best

    def _find_stops(self) -> list[tuple[str, Any, float]]:
        """The signal stop points and stop signs on the path: (kind, key, s [m]) for those
        within their lane's half width + 0.5 m of it, the lane within 45 deg of the path."""
        road = self.road
        stops: list[tuple[str, Any, float]] = []
        network = road.network
        marks = [("signal", j, index, s) for j, (index, s) in
                 enumerate(zip(getattr(road, "_signal_lanes", ()), getattr(road, "_stop_s", ()),
                               strict=True)) if index is not None and np.isfinite(s)]
        marks += [("sign", (index, k), index, s) for index, points in
                  getattr(road, "_stop_signs", {}).items() for k, s in enumerate(points)]
        for kind, key, index, s_lane in marks:
            lane = network.get_lane(index)
            point = lane.position(s_lane, 0.0)
            s, d, theta = self.path.project(point)
            if (abs(d) <= lane.width / 2 + 0.5 and
                    math.cos(theta - lane.heading_at(s_lane)) > math.cos(math.radians(45))):
                stops.append((kind, key, s))
        return stops

    def _stop_gaps(self, v: float) -> list[float]:
        """Gaps [m] from the bumper to the stop points and stop signs it must stop at."""
        if self.stops is None:
            self.stops = self._find_stops()
        if not self.stops:
            return []
        road = self.road
        k = road.clock[0]
        p = self.driver
        out = []
        red = getattr(road, "_red", None)
        for kind, key, s_stop in self.stops:
            d = s_stop - self.s
            if d < -0.5 or d > STOP_LOOKAHEAD:
                continue
            room = d - self.LENGTH / 2
            if kind == "signal":
                if red is None or not len(red):
                    continue
                step = min(k, len(red) - 1)
                if red[step, key]:
                    out.append(room - STOP_MARGIN)
                elif road._red_or_yellow[step, key]:
                    if key not in self.yellow_stops:
                        r = room - STOP_MARGIN
                        if r <= 0 or v * v > 2 * p.comfortable_braking * r:
                            continue  # too late to stop comfortably: through
                        self.yellow_stops.add(key)
                    out.append(room - STOP_MARGIN)
                else:
                    self.yellow_stops.discard(key)
                continue
            if key in self.stop_signs_served:
                continue
            if room <= STOP_SIGN_NEAR and v < STOP_SIGN_SPEED:
                self.stop_signs_served.add(key)
                continue
            if key not in self.stop_signs_seen:
                self.stop_signs_seen.add(key)
                if v * v > 2 * p.comfortable_braking * max(room - STOP_MARGIN, 0.0):
                    self.stop_signs_served.add(key)  # rolling through already: passes
                    continue
            out.append(room - STOP_MARGIN)
        return out

    def step(self, dt: float) -> None:
        if self.hidden:
            if self.road.clock[0] >= self.start_step and self._room_to_appear():
                self.hidden = False
                self.collidable = True
                x, y, h = self.path.at(self.s)
                self.position = np.array([x, y])
                self.heading = h
            return
        if self.road.clock[0] > self.last_step and self.s >= self.path.length:
            self.hidden = True  # its log has ended and it is past it: it leaves the scene
            self.start_step = 1 << 30
            self.position = np.array([HIDDEN + 10.0 * self.row, -HIDDEN])
            self.collidable = False
            return
        if self.impact is not None:  # a collision: crashed, but it stays on its path
            self.crashed = True
            self.impact = None
        v = float(self.speed)
        v_next = max(v + float(self.action["acceleration"]) * dt, 0.0)
        self.s += 0.5 * (v + v_next) * dt
        self.speed = v_next
        x, y, h = self.path.at(self.s)
        self.position = np.array([x, y])
        self.heading = h


# ------------------------------------------------------------------ the road


@numba.njit(cache=True, nogil=True)
def _lane_clearance(ax, ay, bx, by, half, owner, x, y):  # pragma: no cover - compiled
    """min over lanes of (distance to the lane's centre line - half its width) [m]."""
    best = np.inf
    for k in range(ax.shape[0]):
        dx, dy = bx[k] - ax[k], by[k] - ay[k]
        n2 = dx * dx + dy * dy
        u = 0.0 if n2 == 0 else ((x - ax[k]) * dx + (y - ay[k]) * dy) / n2
        u = min(max(u, 0.0), 1.0)
        d = math.hypot(x - ax[k] - u * dx, y - ay[k] - u * dy) - half[owner[k]]
        if d < best:
            best = d
    return best


@numba.njit(cache=True, nogil=True)
def _segment_hits(px, py, near, ax, ay, bx, by):  # pragma: no cover - compiled
    """Where the polyline (px, py) crosses or touches the segments ``near`` of (ax, ay) ->
    (bx, by) (collinear overlaps do not count): (h, 4) rows (its segment k, the segment q,
    d1, d2), in (k, q) order, where d1 and d2 are the sides (cross products) of k's ends
    from q's line (the crossing is at d1 / (d1 - d2) along k)."""
    rows = []
    m = near.shape[0]
    lo_x, hi_x, lo_y, hi_y = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    for i in range(m):
        q = near[i]
        lo_x[i], hi_x[i] = min(ax[q], bx[q]), max(ax[q], bx[q])
        lo_y[i], hi_y[i] = min(ay[q], by[q]), max(ay[q], by[q])
    for k in range(px.shape[0] - 1):
        x0, y0, x1, y1 = px[k], py[k], px[k + 1], py[k + 1]
        k_lo_x, k_hi_x = min(x0, x1), max(x0, x1)
        k_lo_y, k_hi_y = min(y0, y1), max(y0, y1)
        for i in range(m):
            # boxes apart: the segments neither cross nor touch (skipped unmeasured)
            if (hi_x[i] < k_lo_x or lo_x[i] > k_hi_x or hi_y[i] < k_lo_y
                    or lo_y[i] > k_hi_y):
                continue
            q = near[i]
            d1 = (bx[q] - ax[q]) * (y0 - ay[q]) - (by[q] - ay[q]) * (x0 - ax[q])
            d2 = (bx[q] - ax[q]) * (y1 - ay[q]) - (by[q] - ay[q]) * (x1 - ax[q])
            d3 = (x1 - x0) * (ay[q] - y0) - (y1 - y0) * (ax[q] - x0)
            d4 = (x1 - x0) * (by[q] - y0) - (y1 - y0) * (bx[q] - x0)
            if d1 * d2 <= 0 and d3 * d4 <= 0 and d1 != d2 and d3 != d4:
                rows.append((float(k), float(q), d1, d2))
    out = np.empty((len(rows), 4))
    for i in range(len(rows)):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = rows[i]
    return out


@numba.njit(cache=True, nogil=True)
def _lane_members(px, py, tx, ty, s, half, lo, hi, xs, ys):  # pragma: no cover - compiled
    """The points (xs, ys) on a lane (poses px, py, tx, ty, s: ``FastPolyLane.arrays``):
    (the rows within ``half`` [m] of its centre line with a longitudinal coordinate in
    [lo, hi) [m], in order; every point's longitudinal coordinate [m])."""
    lon = np.empty(xs.shape[0])
    members = np.empty(xs.shape[0], np.int64)
    n = 0
    for i in range(xs.shape[0]):
        lon[i], lat = _frame(px, py, tx, ty, s, xs[i], ys[i])
        if abs(lat) <= half and lon[i] >= lo and lon[i] < hi:
            members[n] = i
            n += 1
    return members[:n], lon


@numba.njit(cache=True, nogil=True)
def _lane_members_into(px, py, tx, ty, s, half, lo, hi, xs, ys, members, lon
                       ):  # pragma: no cover - compiled
    """:func:`_lane_members` written into ``members`` and ``lon`` (n,) each, made by the
    caller (each array a compiled function returns costs a few microseconds): returns how
    many members (the first ones of ``members``)."""
    found, along = _lane_members(px, py, tx, ty, s, half, lo, hi, xs, ys)
    members[:found.shape[0]] = found
    lon[:] = along
    return found.shape[0]


@numba.njit(cache=True, nogil=True)
def _lane_members_near(px, py, tx, ty, s, half, lo, hi, xs, ys, bound
                       ):  # pragma: no cover - compiled
    """:func:`_lane_members` with the points that cannot be members left out before their
    frame is found: ``bound`` = (x min, y min, x max, y max of the lane's poses, then the
    slack, slope and tail of :meth:`~tap_bench.sim.womd_lanes.LaneIndex._wedges`, the
    box's reach (``LaneIndex.reach``), and the largest lane distance a member can have
    [m] + 1e-6 m for rounding: :func:`_member_limit`). A member has |lat| <= ``half`` and
    lon in [lo, hi), so its lane distance (|lat| + overshoot beyond either end, as
    :func:`~tap_bench.sim.womd_lanes._lane_distances`) is within that limit; a point whose
    lower bound of that distance (as :func:`~tap_bench.sim.womd_lanes._bounds_into`) is
    above it is not one. The same members; the longitudinal coordinate of a point left
    out is NaN (only the members' are read)."""
    lon = np.empty(xs.shape[0])
    members = np.empty(xs.shape[0], np.int64)
    n = 0
    for i in range(xs.shape[0]):
        x, y = xs[i], ys[i]
        dx = max(bound[0] - x, x - bound[2], 0.0)
        dy = max(bound[1] - y, y - bound[3], 0.0)
        box = np.sqrt(dx * dx + dy * dy)
        low = max(box - bound[7], min((box - bound[4]) / (1.0 + bound[5]), box - bound[6],
                                      box))
        if low > bound[8]:
            lon[i] = np.nan
            continue
        lon[i], lat = _frame(px, py, tx, ty, s, x, y)
        if abs(lat) <= half and lon[i] >= lo and lon[i] < hi:
            members[n] = i
            n += 1
    return members[:n], lon


def _member_limit(half: float, lo: float, hi: float, length: float) -> float:
    """The largest lane distance [m] (|lat| + overshoot beyond either end) a point with
    |lat| <= ``half`` and a longitudinal coordinate in [lo, hi) can have on a lane
    ``length`` long, + 1e-6 m (the rounding of the bound it is compared with)."""
    return half + max(-lo, hi - length, 0.0) + 1e-6


@numba.njit(cache=True, nogil=True)
def _front_rear(members, lon, s, mine):  # pragma: no cover - compiled
    """The nearest movers on a lane ahead of and behind the longitudinal coordinate ``s``
    [m] (:meth:`WomdRoad.neighbour_vehicles`): among ``members`` (their rows, in order;
    ``lon`` every mover's longitudinal coordinate [m]), ``mine`` left out (-1: none): (the
    front's row, with lon >= s, the last of equal ones; the rear's, lon < s, the first of
    equal ones), -1 where none."""
    front = rear = -1
    s_front = s_rear = 0.0
    for i in members:
        if i == mine:
            continue
        sv = lon[i]
        if s <= sv and (front < 0 or sv <= s_front):
            s_front, front = sv, i
        if sv < s and (rear < 0 or sv > s_rear):
            s_rear, rear = sv, i
    return front, rear


@numba.njit(cache=True, nogil=True)
def _leader_on(members, lon, hs, base, mine, heading, best_d, reach
               ):  # pragma: no cover - compiled
    """The nearest mover ahead on one of the next lanes (:meth:`WomdRoad.leader_ahead`):
    among ``members`` (rows, in order; ``lon`` every mover's longitudinal coordinate on the
    lane [m], ``hs`` its heading [rad]) the first whose distance ``base + lon`` [m] is in
    (0, min(best_d, reach + 0)) (not beyond ``reach``, below ``best_d``), not ``mine`` and
    not oncoming (cos of the heading difference not below 0, ``heading`` [rad] the
    vehicle's): (its row or -1, its distance or ``best_d``)."""
    best = -1
    for i in members:
        d = base + lon[i]
        if i == mine or d <= 0 or d >= best_d or d > reach:
            continue
        if math.cos(hs[i] - heading) < 0:
            continue
        best, best_d = i, d
    return best, best_d


@numba.njit(cache=True, nogil=True)
def _leader_ahead_on(px, py, tx, ty, s, lanes, bases, xs, ys, hs, mine, heading, reach
                     ):  # pragma: no cover - compiled
    """:meth:`WomdRoad.leader_ahead` over its next lanes in one pass: for each lane (a row
    of ``lanes``: its poses c:d of the network's pose arrays px, py, tx, ty, s, then the
    half width, lo and hi of :func:`_lane_members`), starting ``bases`` [m] along the way,
    the movers on it (:func:`_lane_members` of xs, ys) searched by :func:`_leader_on`
    (headings ``hs``); the first lane with a leader ends the search: (its row or -1, its
    distance [m] or inf)."""
    best_d = np.inf
    for j in range(lanes.shape[0]):
        c, d = int(lanes[j, 0]), int(lanes[j, 1])
        members, lon = _lane_members(px[c:d], py[c:d], tx[c:d], ty[c:d], s[c:d], lanes[j, 2],
                                     lanes[j, 3], lanes[j, 4], xs, ys)
        best, best_d = _leader_on(members, lon, hs, bases[j], mine, heading, best_d, reach)
        if best >= 0:
            return best, best_d
    return -1, best_d


@numba.njit(cache=True, nogil=True)
def _corridor(xs, ys, hs, vs, ls, ws, x, y, heading, length, width, reach, mine
              ):  # pragma: no cover - compiled
    """:meth:`WomdRoad.corridor_leader` over the movers (centres xs, ys, headings hs, speeds
    vs, boxes ls x ws) of a vehicle at (x, y, heading) with a box length x width and the
    look ahead ``reach`` [m]; ``mine``: its own row (-1: none). Returns (row, gap [m], the
    row's speed along the heading [m/s]); row -1 if none."""
    c, s_ = math.cos(heading), math.sin(heading)
    best, best_gap = -1, np.inf
    for j in range(xs.shape[0]):
        if j == mine:
            continue
        dx, dy = xs[j] - x, ys[j] - y
        lon = dx * c + dy * s_
        lat = -dx * s_ + dy * c
        dh = hs[j] - heading
        along = abs(math.cos(dh)) * ls[j] / 2 + abs(math.sin(dh)) * ws[j] / 2
        across = abs(math.sin(dh)) * ls[j] / 2 + abs(math.cos(dh)) * ws[j] / 2
        gap = lon - length / 2 - along
        if (abs(lat) < width / 2 + across + CORRIDOR_MARGIN and lon > 0 and gap < reach
                and gap > -along):
            if not gap == gap:  # not a number: the first one, as numpy's argmin
                return j, gap, vs[j] * math.cos(dh)
            if best < 0 or gap < best_gap:
                best, best_gap = j, gap
    if best < 0:
        return -1, np.nan, np.nan
    return best, best_gap, vs[best] * math.cos(hs[best] - heading)


@numba.njit(cache=True, nogil=True)
def _any_within(xs, ys, x, y, r2):  # pragma: no cover - compiled
    """Whether a point (xs, ys) is within sqrt(``r2``) [m] of (x, y): its squared distance,
    x then y, at most ``r2``."""
    for i in range(xs.shape[0]):
        dx, dy = xs[i] - x, ys[i] - y
        if dx * dx + dy * dy <= r2:
            return True
    return False


@numba.njit(cache=True, nogil=True)
def _walkers_on_lane(px, py, tx, ty, s, headings, base, half, length, xs, ys, hs, vs,
                     best):  # pragma: no cover - compiled
    """The nearest distance [m] along the way (``base`` + the longitudinal coordinate) to a
    pedestrian or cyclist (xs, ys, headings hs, speeds vs) on one lane ahead within
    ``half`` [m] of its centre line, not moving along it (:meth:`WomdRoad.walker_distance`);
    ``best``: the nearest found before (NaN: none), returned where nothing is nearer."""
    for i in range(xs.shape[0]):
        lon, lat = _frame(px, py, tx, ty, s, xs[i], ys[i])
        d = base + lon
        if not (abs(lat) <= half and lon >= 0 and lon <= length and d > 0
                and d <= WALKER_LOOKAHEAD):
            continue
        if lon != lon:
            k = headings.shape[0] - 1
        else:
            k = max(np.searchsorted(s, lon, side="right") - 1, 0)
        along = abs(math.cos(hs[i] - headings[k]))
        if vs[i] >= WALKER_STILL and along > WALKER_ALONG:
            continue
        if best != best or d < best:
            best = d
    return best


@numba.njit(cache=True, nogil=True)
def _apart_along(nx, ny, x_i, y_i, c_i, s_i, hl_i, hw_i, x_j, y_j, c_j, s_j, hl_j, hw_j, dx,
                 dy):  # pragma: no cover - compiled
    """Whether box i swept by (dx, dy) stays more than TOUCH_MARGIN from box j along the
    axis (nx, ny) (:func:`~tap_bench.sim.traffic.swept_apart`'s test on one axis)."""
    reach_i = hl_i * abs(c_i * nx + s_i * ny) + hw_i * abs(c_i * ny - s_i * nx)
    reach_j = hl_j * abs(c_j * nx + s_j * ny) + hw_j * abs(c_j * ny - s_j * nx)
    centre_i = x_i * nx + y_i * ny
    centre_j = x_j * nx + y_j * ny
    moved = dx * nx + dy * ny
    low_i = centre_i - reach_i + min(moved, 0.0)
    high_i = centre_i + reach_i + max(moved, 0.0)
    ahead, behind = centre_j - reach_j - high_i, low_i - (centre_j + reach_j)
    if ahead != ahead or behind != behind:  # not a number: not apart
        return False
    return max(ahead, behind) > TOUCH_MARGIN


@numba.njit(cache=True, nogil=True)
def _pairs_to_check(xs, ys, diagonal, length, width, heading, speed, checks, own, dt
                    ):  # pragma: no cover - compiled
    """The pairs of movers the collision check looks at, and which of them stay apart.

    Pair (i, j), i < j, in row order, is near when one has its own collision test
    (``own``), or one checks collisions and their centres are at most half the sum of
    their diagonals + their relative speed x dt + TOUCH_MARGIN apart (a NaN distance:
    near), as :func:`~tap_bench.sim.traffic.near_pairs_of`; apart: the boxes swept over dt
    stay apart along a side's axis (:func:`~tap_bench.sim.traffic.swept_apart`).

    Returns:
        (first, second, apart), (p,) each."""
    m = xs.shape[0]
    vx, vy = np.empty(m), np.empty(m)
    cos_h, sin_h = np.empty(m), np.empty(m)
    for k in range(m):
        cos_h[k], sin_h[k] = math.cos(heading[k]), math.sin(heading[k])
        vx[k], vy[k] = speed[k] * cos_h[k], speed[k] * sin_h[k]
    first, second = [], []
    for i in range(m):
        for j in range(i + 1, m):
            if not (own[i] or own[j]):
                if not (checks[i] or checks[j]):
                    continue
                distance = math.hypot(xs[j] - xs[i], ys[j] - ys[i])
                relative = math.hypot(vx[i] - vx[j], vy[i] - vy[j]) * dt
                if distance > (diagonal[i] + diagonal[j]) / 2 + relative + TOUCH_MARGIN:
                    continue
            first.append(i)
            second.append(j)
    p = len(first)
    a, b = np.empty(p, np.int64), np.empty(p, np.int64)
    apart = np.zeros(p, np.bool_)
    for q in range(p):
        i, j = first[q], second[q]
        a[q], b[q] = i, j
        if own[i] or own[j]:
            continue
        dx, dy = (vx[i] - vx[j]) * dt, (vy[i] - vy[j]) * dt
        ci, si, cj, sj = cos_h[i], sin_h[i], cos_h[j], sin_h[j]
        hl_i, hw_i, hl_j, hw_j = length[i] / 2, width[i] / 2, length[j] / 2, width[j] / 2
        for nx, ny in ((ci, si), (-si, ci), (cj, sj), (-sj, cj)):
            if _apart_along(nx, ny, xs[i], ys[i], ci, si, hl_i, hw_i, xs[j], ys[j], cj, sj,
                            hl_j, hw_j, dx, dy):
                apart[q] = True
                break
    return a, b, apart


@numba.njit(cache=True, nogil=True)
def _pairs_of_movers(collidable, position, diagonal, length, width, heading, speed, checks,
                     own, dt):  # pragma: no cover - compiled
    """(the rows of the movers, those whose ``collidable`` is set; :func:`_pairs_to_check`
    of their columns: first, second, apart) of a road's vehicles, (n,) columns each
    (``position`` (n, 2))."""
    m = 0
    for i in range(collidable.shape[0]):
        if collidable[i]:
            m += 1
    rows = np.empty(m, np.int64)
    xs, ys, ds, ls, ws, hs, vs = (np.empty(m), np.empty(m), np.empty(m), np.empty(m),
                                  np.empty(m), np.empty(m), np.empty(m))
    cs, os_ = np.empty(m, np.bool_), np.empty(m, np.bool_)
    k = 0
    for i in range(collidable.shape[0]):
        if not collidable[i]:
            continue
        rows[k] = i
        xs[k], ys[k] = position[i, 0], position[i, 1]
        ds[k], ls[k], ws[k] = diagonal[i], length[i], width[i]
        hs[k], vs[k] = heading[i], speed[i]
        cs[k], os_[k] = checks[i], own[i]
        k += 1
    first, second, apart = _pairs_to_check(xs, ys, ds, ls, ws, hs, vs, cs, os_, dt)
    return rows, first, second, apart


@numba.njit(cache=True, nogil=True)
def _pairs_packed(collidable, position, diagonal, length, width, heading, speed, checks,
                  own, dt):  # pragma: no cover - compiled
    """:func:`_pairs_of_movers` as one array, which Python receives in one piece (each
    array a compiled function returns costs a few microseconds): (rows (m,), first (p,),
    second (p,), apart (p,) as 0/1, end to end; m; p)."""
    rows, first, second, apart = _pairs_of_movers(collidable, position, diagonal, length,
                                                  width, heading, speed, checks, own, dt)
    m, p = rows.shape[0], first.shape[0]
    out = np.empty(m + 3 * p, np.int64)
    out[:m] = rows
    out[m:m + p] = first
    out[m + p:m + 2 * p] = second
    for q in range(p):
        out[m + 2 * p + q] = 1 if apart[q] else 0
    return out, m, p


@numba.njit(cache=True, nogil=True)
def _approach_rows(members, lon, hs, ls, walker, s, headings, s_point, offset, width, mine,
                   seen):  # pragma: no cover - compiled
    """The movers of one lane's table (``members``, longitudinal coordinates ``lon`` [m])
    approaching a point ``s_point`` [m] of the lane they lead into (``offset`` [m]: where
    this lane starts before it) along the lane, not yet past it: not pedestrians or
    cyclists (``walker``), not row ``mine`` nor one ``seen`` (marked here), within 30 deg
    of the lane's heading there (poses ``s``, ``headings``). Returns (rows, distance [m]
    from each centre to the point) (:func:`_conflict_gap_on`)."""
    rows = np.empty(members.shape[0], np.int64)
    dist = np.empty(members.shape[0])
    n = 0
    for i in members:
        if i == mine or seen[i] or walker[i]:
            continue
        d = s_point + offset - lon[i]
        if d < -(ls[i] + width) or d > CONFLICT_LOOKAHEAD * 2:
            continue
        if lon[i] != lon[i]:
            k = headings.shape[0] - 1
        else:
            k = max(np.searchsorted(s, lon[i], side="right") - 1, 0)
        if math.cos(hs[i] - headings[k]) < 0.5:
            continue
        seen[i] = True
        rows[n], dist[n] = i, d
        n += 1
    return rows[:n], dist[:n]


@numba.njit(cache=True, nogil=True)
def _conflict_gap_on(d_ahead, conf, at, approach, offsets, lanes, px, py, tx, ty, s, hd,
                     xs, ys, hs, ls, ws, vs, walker, yielder, braking_j, row_j, mine, row,
                     length, width, v_i, braking, critical):  # pragma: no cover - compiled
    """:meth:`WomdRoad.conflict_gap` over the conflicts of one lane of a vehicle's way.

    Conflict q is at ``d_ahead + conf[q, 0]`` [m] along the way and at ``conf[q, 1]`` [m]
    on the other lane; the lanes approaching it are rows ``at[q]:at[q + 1]`` of
    ``approach`` (a row of ``lanes``: poses ``c:d`` of the pose arrays px, py, tx, ty, s,
    headings hd, a mover's half-width reach, and its longitudinal range [lo, hi); with 14
    columns, then the bound by which :func:`_lane_members_near` leaves out the movers that
    cannot be on it) and ``offsets`` (where that lane starts before the other one [m]).
    The movers: centres xs, ys, headings hs, lengths ls, widths ws, speeds vs, walker,
    yielder (gives way: its comfortable braking braking_j), scene row row_j; the vehicle:
    mover ``mine``, scene ``row``, its box length x width, speed v_i, comfortable braking
    and critical gap.
    Returns the smallest gap [m] to a conflict zone where it gives way, NaN if none."""
    n = xs.shape[0]
    m = lanes.shape[0]
    lon = np.empty((m, n))  # the lanes' tables (_lane_members), made when first needed
    members = np.empty((m, n), np.int64)
    count = np.full(m, -1)
    seen = np.zeros(n, np.bool_)
    best = np.nan
    for q in range(conf.shape[0]):
        d_i = d_ahead + conf[q, 0]
        if d_i > CONFLICT_LOOKAHEAD:
            continue
        seen[:] = False
        for r in range(at[q], at[q + 1]):
            u = approach[r]
            c, d = int(lanes[u, 0]), int(lanes[u, 1])
            if count[u] < 0:
                if lanes.shape[1] >= 14:  # with the lane's bound: the far ones left out
                    found, along = _lane_members_near(
                        px[c:d], py[c:d], tx[c:d], ty[c:d], s[c:d], lanes[u, 2],
                        lanes[u, 3], lanes[u, 4], xs, ys, lanes[u, 5:14])
                else:
                    found, along = _lane_members(px[c:d], py[c:d], tx[c:d], ty[c:d],
                                                 s[c:d], lanes[u, 2], lanes[u, 3],
                                                 lanes[u, 4], xs, ys)
                lon[u, :] = along
                count[u] = found.shape[0]
                members[u, :count[u]] = found
            if count[u] == 0:
                continue
            rows, dist = _approach_rows(members[u, :count[u]], lon[u], hs, ls, walker,
                                        s[c:d], hd[c:d], conf[q, 1], offsets[r], width,
                                        mine, seen)
            for j in range(rows.shape[0]):
                i, d_j = rows[j], dist[j]
                # whether the vehicle gives way to it: as WomdRoad.conflict_gap
                half = ws[i] / 2 + CONFLICT_CLEARANCE
                gap_i = d_i - length / 2 - half
                if gap_i < -length:
                    continue
                inside_j = (-(ls[i] / 2 + width / 2 + CONFLICT_CLEARANCE) < d_j
                            <= ls[i] / 2 + width / 2 + CONFLICT_CLEARANCE)
                if gap_i <= 0:
                    continue
                if not inside_j and v_i ** 2.0 > 2 * braking * gap_i:
                    continue
                if not inside_j:
                    v_j = vs[i]
                    t_j = max(d_j - ls[i] / 2, 0.0) / max(v_j, 0.1)
                    if t_j > CONFLICT_HORIZON:
                        continue
                    t_i = gap_i / max(v_i, 1.0)
                    yields = yielder[i] and v_j ** 2.0 <= 2 * braking_j[i] * max(
                        d_j - ls[i] / 2 - width / 2 - CONFLICT_CLEARANCE, 0.0)
                    if yields:
                        first = t_j < t_i - CONFLICT_TIE or (
                            abs(t_j - t_i) <= CONFLICT_TIE and row_j[i] < row)
                        if not first:
                            continue
                    elif t_j > t_i + critical:
                        continue
                best = gap_i if best != best else min(best, gap_i)
    return best


@numba.njit(cache=True, nogil=True)
def _ahead_in_one(px, py, tx, ty, s, hd, whd, lanes, bases, xs, ys, hs, vs, ls, ws, walker,
                  yielder, braking_j, row_j, conf, at, approach, offsets, clanes, sections,
                  wx0, wy0, wx1, wy1, whs, wvs, ego, mine, row, cuts, walkers
                  ):  # pragma: no cover - compiled
    """:meth:`WomdRoad.obstacles_ahead`'s searches in one pass over a vehicle's lanes ahead
    (rows of ``lanes``: poses c:d of the network's pose arrays px, py, tx, ty, s (headings
    hd; ``whd`` the walkers' lane headings), :func:`_lane_members`' half width, lo and hi,
    the lane's length [m]; each starting ``bases`` [m] along the way; ``cuts``: how many of
    them :meth:`WomdRoad._lanes_ahead` gives within :data:`LEADER_LOOKAHEAD` and within
    :data:`WALKER_LOOKAHEAD` (the first ones)):

    - the leader on the next lanes: :func:`_leader_ahead_on` over lanes 1 to ``cuts[0]``;
    - the corridor's leader: :func:`_corridor` (two movers or more);
    - when ``walkers``: the nearest walker in the way, :func:`_any_within` the reach, then
      :func:`_walkers_on_lane` on the lanes within :data:`WALKER_LOOKAHEAD`, where they are
      (wx0, wy0) then where they will be (wx1, wy1), headings whs, speeds wvs, on the
      first ``cuts[1]`` lanes;
    - the give-way gap: :func:`_conflict_gap_on` on each lane of ``sections`` (the lanes
      within :data:`CONFLICT_LOOKAHEAD`; the search stops at one starting beyond it) whose
      conflicts (``sections`` row j: conf rows q0:q1, at
      rows a0:a0 + q1 - q0 + 1, approach and offsets rows r0:r1, clanes rows u0:u1, each
      lane's table as :meth:`WomdRoad._conflict_table` makes it) are not empty, the
      smallest.

    The movers: centres xs, ys, headings hs, speeds vs, boxes ls x ws, walker, yielder,
    braking_j, row_j as :meth:`WomdRoad._conflict_movers`; the vehicle: mover ``mine``,
    scene ``row``, ``ego`` = (x, y, heading, length, width, speed v_i >= 0, comfortable
    braking, critical gap, the corridor's reach, the walkers' squared reach, their half
    width). Returns (leader row or -1, its distance or inf, the corridor's row or -1, gap,
    speed, the walker's distance, the conflict gap), NaN where none."""
    x, y, heading, length, width = ego[0], ego[1], ego[2], ego[3], ego[4]
    v_i, braking, critical, reach = ego[5], ego[6], ego[7], ego[8]
    leader, leader_d = -1, np.inf
    if cuts[0] > 1:
        leader, leader_d = _leader_ahead_on(px, py, tx, ty, s, lanes[1:cuts[0]],
                                            bases[1:cuts[0]], xs, ys, hs, mine, heading,
                                            LEADER_LOOKAHEAD)
    corridor, gap, speed = -1, np.nan, np.nan
    if xs.shape[0] >= 2:
        corridor, gap, speed = _corridor(xs, ys, hs, vs, ls, ws, x, y, heading, length,
                                         width, reach, mine)
    walker_d = np.nan
    if walkers and _any_within(wx0, wy0, x, y, ego[9]):
        for j in range(cuts[1]):
            c, d = int(lanes[j, 0]), int(lanes[j, 1])
            for xw, yw in ((wx0, wy0), (wx1, wy1)):
                walker_d = _walkers_on_lane(px[c:d], py[c:d], tx[c:d], ty[c:d], s[c:d],
                                            whd[c:d], bases[j], ego[10], lanes[j, 5], xw,
                                            yw, whs, wvs, walker_d)
    best = np.nan
    for j in range(sections.shape[0]):
        if bases[j] > CONFLICT_LOOKAHEAD:
            break
        q0, q1, a0, r0, r1, u0, u1 = sections[j]
        if q1 == q0:
            continue
        g = _conflict_gap_on(bases[j], conf[q0:q1], at[a0:a0 + q1 - q0 + 1],
                             approach[r0:r1], offsets[r0:r1], clanes[u0:u1], px, py, tx, ty,
                             s, hd, xs, ys, hs, ls, ws, vs, walker, yielder, braking_j, row_j,
                             mine, row, length, width, v_i, braking, critical)
        if g == g and (best != best or g < best):
            best = g
    return leader, leader_d, corridor, gap, speed, walker_d, best


def _intersecting(a: Vehicle, b: Vehicle) -> bool:
    """Whether two vehicles' boxes overlap now."""
    return bool(utils.are_polygons_intersecting(a.polygon(), b.polygon(), np.zeros(2),
                                                np.zeros(2))[0])


def _pair(a: Vehicle, b: Vehicle) -> tuple[int, int]:
    """The two vehicles' scene rows, in order (-1: no row)."""
    ra, rb = getattr(a, "row", -1), getattr(b, "row", -1)
    return (ra, rb) if ra <= rb else (rb, ra)


def _segments(lines: Sequence[np.ndarray]) -> tuple[np.ndarray, ...]:
    """(ax, ay, bx, by, owner) of the segments of polylines (sim frame)."""
    parts = [(np.asarray(p)[:-1], np.asarray(p)[1:], np.full(len(p) - 1, i))
             for i, p in enumerate(lines) if len(p) >= 2]
    if not parts:
        z = np.zeros(0)
        return z, z, z, z, np.zeros(0, np.int64)
    a = np.concatenate([p[0] for p in parts])
    b = np.concatenate([p[1] for p in parts])
    owner = np.concatenate([p[2] for p in parts]).astype(np.int64)
    return (np.ascontiguousarray(a[:, 0]), np.ascontiguousarray(a[:, 1]),
            np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1]), owner)


def _centre_segments(centres: Sequence[np.ndarray]) -> tuple[np.ndarray, ...]:
    """:func:`_segments` of lane centre lines (n_i, 2) in WOMD's axes, mirrored to the sim
    frame all at once; owner k is the k-th line."""
    sizes = np.array([len(c) for c in centres], dtype=np.int64)
    if not len(sizes) or (sizes < 2).all():
        return _segments([])
    points = np.concatenate([np.asarray(c, dtype=np.float64).reshape(-1, 2)
                             for c in centres]) * (1.0, -1.0)
    ends = np.cumsum(sizes)
    starts = ends - sizes
    head, tail = np.ones(len(points), bool), np.ones(len(points), bool)
    head[ends[sizes > 0] - 1] = False  # a line's last point starts no segment
    tail[starts[sizes > 0]] = False  # ... its first ends none
    a, b = points[head], points[tail]
    owner = np.repeat(np.arange(len(sizes), dtype=np.int64), np.maximum(sizes - 1, 0))
    return (np.ascontiguousarray(a[:, 0]), np.ascontiguousarray(a[:, 1]),
            np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1]), owner)


@numba.njit(cache=True, nogil=True)
def _movers_now(collidable, position, heading, speed, length, width, walker, path,
                walker_clearance, path_margin):  # pragma: no cover - compiled
    """A step's movers, the vehicles whose ``collidable`` is set: (their rows, positions (n,
    2) [m], x, y, heading [rad], speed (not below 0, as ``np.maximum``) [m/s], length,
    width [m], the four as a box (n, 4), walker, path vehicle, margin to a path (the
    walker's clearance or the path margin) [m], how many are walkers); each (n,) column
    contiguous."""
    n = 0
    for i in range(collidable.shape[0]):
        if collidable[i]:
            n += 1
    rows = np.empty(n, np.int64)
    xy = np.empty((n, 2))
    xs, ys, hs, vs = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    ls, ws, boxes = np.empty(n), np.empty(n), np.empty((n, 4))
    walkers, paths, margins = np.empty(n, np.bool_), np.empty(n, np.bool_), np.empty(n)
    k = 0
    n_walkers = 0
    for i in range(collidable.shape[0]):
        if not collidable[i]:
            continue
        rows[k] = i
        xy[k, 0] = xs[k] = position[i, 0]
        xy[k, 1] = ys[k] = position[i, 1]
        v = speed[i]
        v = v if v > 0.0 or v != v else 0.0  # as np.maximum(v, 0.0): -0.0 -> 0.0
        boxes[k, 0] = hs[k] = heading[i]
        boxes[k, 1] = vs[k] = v
        boxes[k, 2] = ls[k] = length[i]
        boxes[k, 3] = ws[k] = width[i]
        walkers[k] = walker[i]
        paths[k] = path[i]
        margins[k] = walker_clearance if walker[i] else path_margin
        n_walkers += walker[i]
        k += 1
    return rows, xy, xs, ys, hs, vs, ls, ws, boxes, walkers, paths, margins, n_walkers


@numba.njit(cache=True, nogil=True)
def _movers_into(collidable, position, heading, speed, length, width, walker, path,
                 walker_clearance, path_margin, rows, xy, columns, boxes, flags
                 ):  # pragma: no cover - compiled
    """:func:`_movers_now` written into arrays the caller made for the n movers (each array
    a compiled function returns costs a few microseconds): rows (n,), xy (n, 2), columns
    (7, n) x, y, heading, speed, length, width, margin; boxes (n, 4); flags (2, n) walker,
    path vehicle. Returns how many are walkers."""
    (rows_, xy_, xs, ys, hs, vs, ls, ws, boxes_, walkers, paths, margins,
     n_walkers) = _movers_now(collidable, position, heading, speed, length, width, walker,
                              path, walker_clearance, path_margin)
    rows[:] = rows_
    xy[:, :] = xy_
    boxes[:, :] = boxes_
    for j, column in enumerate((xs, ys, hs, vs, ls, ws, margins)):
        columns[j, :] = column
    flags[0, :] = walkers
    flags[1, :] = paths
    return n_walkers


class _Movers:
    """A step's movers: the vehicles of a layout at ``rows`` (sorted), read by index as a
    list of them would be, without the list or an index of them made each step."""

    __slots__ = ("found", "layout", "rows")

    def __init__(self, layout: _Layout, rows: np.ndarray) -> None:
        self.layout, self.rows = layout, rows
        self.found: dict[int, int | None] = {}  # index_of's answers, by the vehicle's id

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, i: int) -> Vehicle:
        return self.layout.vehicles[self.rows[i]]

    def index_of(self, vehicle: Vehicle, default: int | None = None) -> int | None:
        """The vehicle's index among the movers (``default`` when it is not one)."""
        key = id(vehicle)
        if key in self.found:
            k = self.found[key]
            return default if k is None else k
        row = self.layout.row_of.get(key)
        k = None
        if row is not None:
            rows = self.rows.tolist()
            k = bisect.bisect_left(rows, row)
            k = k if k < len(rows) and rows[k] == row else None
        self.found[key] = k
        return default if k is None else k


class _Layout:
    """A road's vehicles (in the road's order) laid out once so that their states at any
    step come as arrays: the log vehicles' from their logs in one indexing, the others'
    from their attributes.

    Attributes:
        vehicles: the vehicles; acting: those that decide (not the log vehicles).
        end: the hidden step past the logs' end (the log vehicles' layouts share it).
        length, width, diagonal: (n,) [m]; walker: (n,) a pedestrian or cyclist;
        checks: (n,) checks collisions.
    """

    def __init__(self, vehicles: tuple[Vehicle, ...], walker_rows: frozenset,
                 previous: _Layout | None = None) -> None:
        """``previous``: the road's layout before, whose logs are taken as they are when
        its log vehicles are these (the policy's ego put in the place of the env's)."""
        self.vehicles = vehicles
        self.row_of = {id(v): i for i, v in enumerate(vehicles)}  # id -> place in vehicles
        self.acting = [v for v in vehicles if type(v) is not LogVehicle]
        logs = [i for i, v in enumerate(vehicles) if type(v) is LogVehicle]
        self.logs = np.array(logs, np.int64)
        self.others = [i for i, v in enumerate(vehicles) if type(v) is not LogVehicle]
        ends = {vehicles[i]._end for i in logs}
        self.end = ends.pop() if len(ends) == 1 else None
        if self.end is None:  # logs of different lengths: one by one
            self.others, self.logs = list(range(len(vehicles))), np.zeros(0, np.int64)
        else:
            self.log_vehicles = [vehicles[i] for i in logs]
            before = getattr(previous, "log_vehicles", None)
            if before is not None and len(before) == len(logs) and all(
                    a is b for a, b in zip(before, self.log_vehicles, strict=True)):
                self.xy, self.heading = previous.xy, previous.heading
                self.speed, self.valid = previous.speed, previous.valid
            elif len({id(v._log_block) for v in self.log_vehicles}) == 1 and (
                    self.log_vehicles[0]._log_block is not None):
                # made together (LogVehicle.many): their rows of its arrays, the same values
                # as their own logs
                xy, heading, speed, valid = self.log_vehicles[0]._log_block
                at = np.array([v._log_at for v in self.log_vehicles], np.int64)
                self.xy = np.ascontiguousarray(xy[at].swapaxes(0, 1))  # (T + 1, n, 2)
                self.heading, self.speed = heading[at].T.copy(), speed[at].T.copy()
                self.valid = valid[at].T.copy()
            else:
                self.xy = np.stack([v._xy for v in self.log_vehicles], axis=1)  # (T + 1, n, 2)
                self.heading = np.array([v._heading for v in self.log_vehicles]).T.copy()
                self.speed = np.array([v._speed for v in self.log_vehicles]).T.copy()
                self.valid = np.array([v._valid for v in self.log_vehicles], bool).T.copy()
        self.end = self.end if self.end is not None else 1 << 30
        self.other_vehicles = [vehicles[i] for i in self.others]
        logs = self.logs
        # the log vehicles' rows: a slice where they follow each other (the usual case)
        self.log_rows = (slice(int(logs[0]), int(logs[-1]) + 1)
            if len(logs) and logs[-1] - logs[0] + 1 == len(logs) else logs)
        self.own_others = [shape_of(v) for v in self.other_vehicles]  # by class: fixed
        self.length = np.array([float(v.LENGTH) for v in vehicles])
        self.width = np.array([float(v.WIDTH) for v in vehicles])
        self.shaped = all(hasattr(v, "diagonal") and hasattr(v, "check_collisions")
                          for v in vehicles)  # else every pair is checked
        self.diagonal = np.array([float(getattr(v, "diagonal", np.nan)) for v in vehicles])
        self.walker = np.array([getattr(v, "row", -1) in walker_rows for v in vehicles], bool)
        self.checks = np.array([bool(getattr(v, "check_collisions", False))
                                for v in vehicles], bool)
        self.path = np.array([isinstance(v, WomdPathVehicle) for v in vehicles], bool)
        self.any_path = bool(self.path.any())
        # gives way at conflicts (WomdRoad.conflict_gap); scene rows (-1: none)
        self.yielder = np.array([isinstance(v, WomdIDMVehicle | WomdPathVehicle)
                                 for v in vehicles], bool)
        self.row = np.array([getattr(v, "row", -1) for v in vehicles], np.int64)
        self.yielder_rows = np.flatnonzero(self.yielder).tolist()
        self._braking: tuple[list, np.ndarray] | None = None  # conflict_braking's
        paths = [v.path for v in vehicles if isinstance(v, WomdPathVehicle)]
        if paths:  # the path vehicles' logged paths end to end
            self.path_points = np.concatenate([q.points for q in paths])
            self.path_px = np.ascontiguousarray(self.path_points[:, 0])
            self.path_py = np.ascontiguousarray(self.path_points[:, 1])
            self.path_cum = np.concatenate([q.cum for q in paths])
            sizes = np.array([len(q.cum) for q in paths], np.int64)
            self.path_ends = np.cumsum(sizes)
            self.path_starts = self.path_ends - sizes

    def conflict_braking(self) -> np.ndarray:
        """(n,) each vehicle's comfortable braking [m/s^2] as its driver's parameters give it
        now (NaN for those that do not give way at conflicts), made again when a driver
        changes."""
        drivers = [self.vehicles[r].parameters() for r in self.yielder_rows]
        made = self._braking
        if made is None or any(a is not b for a, b in zip(made[0], drivers, strict=True)):
            braking = np.full(len(self.vehicles), np.nan)
            for r, p in zip(self.yielder_rows, drivers, strict=True):
                braking[r] = p.comfortable_braking
            made = self._braking = (drivers, braking)
        return made[1]

    def states(self, step: int) -> dict[str, np.ndarray]:
        """The vehicles' states at the road's step ``step`` as they stand: ``position``
        (n, 2) [m], ``heading`` [rad], ``speed`` [m/s], ``collidable`` (n,) and ``own``
        (n,) whether a vehicle's class has its own collision test (None when a vehicle
        lacks a diagonal: every pair is then checked), ``checks`` (n,) whether it checks
        collisions."""
        n = len(self.vehicles)
        position = np.empty((n, 2))
        heading, speed = np.empty(n), np.empty(n)
        collidable = np.empty(n, bool)
        checks = self.checks.copy()
        own = np.zeros(n, bool) if self.shaped else None
        if len(self.logs):
            k = min(step, self.end)
            logs = self.log_rows
            position[logs] = self.xy[k]
            heading[logs] = self.heading[k]
            speed[logs] = self.speed[k]
            collidable[logs] = self.valid[k]
        if len(self.others) <= 8:  # few: one by one
            for i, v, mine in zip(self.others, self.other_vehicles, self.own_others,
                                  strict=True):
                position[i] = v.position
                heading[i], speed[i] = v.heading, v.speed
                collidable[i] = v.collidable
                if own is not None:
                    own[i] = mine
                    checks[i] = v.check_collisions
        else:  # many (idm traffic): one list each
            rows, others = self.others, self.other_vehicles
            position[rows] = [v.position for v in others]
            heading[rows] = [v.heading for v in others]
            speed[rows] = [v.speed for v in others]
            collidable[rows] = [v.collidable for v in others]
            if own is not None:
                own[rows] = self.own_others
                checks[rows] = [v.check_collisions for v in others]
        return {"position": position, "heading": heading, "speed": speed,
                "collidable": collidable, "own": own, "checks": checks}


class WomdRoad(Road):
    """highway-env's road for a WOMD scene: the step counter the log replays read, the
    neighbour search projected once per step per lane (compiled), collisions checked for the
    vehicles that check them, signals and off-road geometry.

    Attributes:
        clock: [k], the record's step the road is at.
    """

    def __init__(self, network: WomdNetwork, scene: Scene, clock: list[int],
                 np_random: Any = None) -> None:
        super().__init__(network=network, vehicles=[], np_random=np_random,
                         record_history=False)
        self.scene = scene
        self.clock = clock
        road = scene.road
        lanes = [lane for lane in road.lanes.values() if lane.id in network.index]
        self._lane_segments = _centre_segments([lane.centre for lane in lanes])
        self._half = np.array([lane.width / 2 for lane in lanes])
        self.road_edges = network.road_edges  # WOMD's axes; built once per network
        self.off_road_start: dict[str, float] = {}
        self._projections: dict[Any, tuple[np.ndarray, np.ndarray]] = {}
        self._headings: dict[Any, np.ndarray] = {}  # lane index -> its poses' headings
        self._everyone: tuple | None = None  # _everyone_on's positions and tables
        self._walker_rows = frozenset(np.flatnonzero(np.isin(scene.object_types,
                                                             ("pedestrian", "cyclist"))).tolist())
        self._walkers: tuple[np.ndarray, ...] | None = None
        self._positions: np.ndarray | None = None
        self._movers: _Movers | list[Vehicle] = []  # this step's (act)
        self._path_accelerations: dict[int, tuple[float, float]] = {}
        signals = road.signals
        self._signal_lanes = [network.index.get(int(i)) for i in signals.lane]
        self._stop_s = []
        for k, index in enumerate(self._signal_lanes):
            if index is None:
                self._stop_s.append(np.nan)
                continue
            p = sim_frame(*signals.stop_point[k])
            self._stop_s.append(float(network.get_lane(index).local_coordinates(p)[0]))
        self._red = signals.red
        self._red_or_yellow = signals.red_or_yellow
        # each step's signals that are red, and red or yellow, as lists of their columns
        # (made at a step's first asking: stop_distance and crossed_red ask at every step)
        self._red_at: dict[int, list[int]] = {}
        self._red_or_yellow_at: dict[int, list[int]] = {}
        self._lane_list = [network.index[lane.id] for lane in lanes]
        self._lane_slot = {index: k for k, index in enumerate(self._lane_list)}
        self._segment_boxes: tuple[np.ndarray, ...] | None = None  # conflicts' boxes
        self._predecessors: dict[Any, list[Any]] = {}
        for index in self._lane_list:
            for nxt in network.successors(index):
                self._predecessors.setdefault(nxt, []).append(index)
        self._conflicts: dict[Any, list[tuple[Any, float, float]]] = {}
        self._conflict_tables: dict[Any, tuple[np.ndarray, ...]] = {}
        self._poses: tuple[np.ndarray, ...] | None = None  # _pose_arrays
        self._lane_limits: dict[Any, tuple[float, ...]] = {}  # leader_ahead's, by lane
        self._mover_conflict: tuple[np.ndarray, ...] | None = None  # _conflict_movers
        self._states_at: tuple[int, _Layout, dict] | None = None  # _snapshot's
        self._crossings: dict[int, list] | None = None
        self._stop_signs = self._stop_sign_points(network, road)
        self._ahead_lanes: dict[tuple, np.ndarray] = {}  # obstacles_ahead's lane rows
        self._ahead_conflicts: dict[tuple, tuple[np.ndarray, ...]] = {}  # ... conflicts
        self._walker_hd: np.ndarray | None = None  # the walkers' lanes' headings, by pose
        self._walker_hd_lanes: set = set()  # ... the lanes filled in

    def release(self) -> None:
        """Let go of the road's vehicles (the env calls it when a reset replaces the road):
        the vehicles point at their road and the road at them through its list and its
        per-step tables, a cycle only the garbage collector's full passes would free; with
        these emptied the old scene's road, vehicles, network and map are freed by reference
        counting as soon as nothing else holds them. The road keeps its network, scene and
        geometry but no vehicles."""
        self.vehicles = []
        self.objects = []
        self.__dict__.pop("_vehicle_layout", None)
        self._movers = []
        self._states_at = None
        self._crossings = None
        self._everyone = None
        self._positions = None
        self._path_accelerations = {}

    def path_conflicts(self, vehicle: Vehicle) -> list[tuple[Any, float, float, bool]]:
        """(other path vehicle, where their logged paths first cross on ours [m], ... on
        theirs [m], whether ours passed there first in the log) for every path vehicle of
        the road whose logged path crosses this one's (at more than 5 deg; the extensions
        beyond the logs not counted). Built for all of them at the first call."""
        if self._crossings is None:
            self._crossings = {}
            paths = [v for v in self.vehicles if isinstance(v, WomdPathVehicle)]
            for a in paths:
                self._crossings[id(a)] = []
            for i, a in enumerate(paths):
                pa = a.path
                for b in paths[i + 1:]:
                    pb = b.path
                    sa, sb = _first_crossing(
                        pa.points[:, 0], pa.points[:, 1], pa.cum, len(pa.cum) - 1,
                        pb.points[:, 0], pb.points[:, 1], pb.cum, len(pb.cum) - 1,
                        PATH_CROSSING_MIN)
                    if not np.isfinite(sa):
                        continue
                    ta, tb = pa.step_at(sa), pb.step_at(sb)
                    a_first = ta < tb or (ta == tb and a.row < b.row)
                    self._crossings[id(a)].append((b, float(sa), float(sb), a_first))
                    self._crossings[id(b)].append((a, float(sb), float(sa), not a_first))
        return self._crossings.get(id(vehicle), [])

    # the vehicles' states as arrays, the log's from its layout
    def _layout(self) -> _Layout:
        """The road's vehicles laid out for :meth:`_snapshot` (made again when the list
        changes: a reset, the policy's ego put in the place of the env's)."""
        vehicles = tuple(self.vehicles)
        layout = self.__dict__.get("_vehicle_layout")
        if layout is None or layout.vehicles != vehicles:
            layout = self._vehicle_layout = _Layout(vehicles, self._walker_rows, layout)
        return layout

    @property
    def acted(self) -> bool:
        """Whether the road has acted in this step (its movers are laid out)."""
        return self._positions is not None

    def _snapshot(self) -> tuple[_Layout, dict[str, np.ndarray]]:
        """Every vehicle's state now (:meth:`_Layout.states`), laid out once per step of
        the road and layout (vehicles move only in the road's step, which lays out the
        states it checks collisions with; the next step's act and the env's measures
        between them read those)."""
        layout = self._layout()
        k = self.clock[0]
        laid = self._states_at
        if laid is None or laid[0] != k or laid[1] is not layout:
            laid = self._states_at = (k, layout, layout.states(k))
        return layout, laid[2]

    # the neighbour search, once per lane per step
    def act(self) -> None:
        self._projections.clear()
        self._everyone = None
        layout, now = self._snapshot()
        # the movers (the collidable vehicles) and their columns, in one compiled pass
        collidable = now["collidable"]
        n = int(np.count_nonzero(collidable))
        rows, positions = np.empty(n, np.int64), np.empty((n, 2))
        columns, self._boxes, flags = np.empty((7, n)), np.empty((n, 4)), np.empty((2, n), bool)
        walkers = _movers_into(collidable, now["position"], now["heading"], now["speed"],
                               layout.length, layout.width, layout.walker, layout.path,
                               WALKER_CLEARANCE, PATH_MARGIN, rows, positions, columns,
                               self._boxes, flags)
        self._xs, self._ys, heading, speed, length, width, self._path_margins = columns
        walker, self._path_mask = flags
        self._mover_rows = rows
        self._mover_conflict = None
        self._movers = _Movers(layout, rows)
        self._positions = positions
        columns = (heading, speed, length, width)
        self._box_columns = columns  # heading, speed, length, width: (n,) contiguous each
        self._walker_mask = walker
        if walkers:
            x, y = self._xs[walker], self._ys[walker]
            heading, speed = columns[0][walker], columns[1][walker]
            reach = WALKER_HORIZON * speed  # where they will be: at their logged velocity
            ahead = (x + reach * np.cos(heading), y + reach * np.sin(heading))
            self._walkers = (x, y, heading, speed)
            self._walker_fastest = float(speed.max())
            self._walker_columns = [(x, y), ahead]
        else:
            self._walkers = None
        self._path_accelerations = self._ahead_of_paths(layout) if layout.any_path else {}
        for vehicle in layout.acting:
            vehicle.act()

    def _ahead_of_paths(self, layout: _Layout) -> dict[int, tuple[float, float]]:
        """id -> (:meth:`WomdPathVehicle.ahead_acceleration` [m/s^2], its desired speed
        [m/s]) of the road's path vehicles that drive this step (not hidden, not crashed),
        computed for all of them in one compiled call (:func:`_path_ahead`)."""
        if not len(self._positions):
            return {}
        paths = [v for v in layout.vehicles if isinstance(v, WomdPathVehicle)]
        rows = [k for k, v in enumerate(paths) if not v.hidden and not v.crashed]
        if not rows:
            return {}
        chosen = [paths[k] for k in rows]
        n = len(chosen)
        s0, s1, x0, y0 = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        half_width, half_length, speed, v0 = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        drivers = np.empty((n, 6))
        mine = np.empty(n, np.int64)
        movers = self._movers
        for i, vehicle in enumerate(chosen):
            p = vehicle.driver
            v = max(float(vehicle.speed), 0.0)
            s0[i], s1[i] = vehicle.s, vehicle.s + (PATH_LOOKAHEAD + PATH_TIME * v)
            x0[i], y0[i] = float(vehicle.position[0]), float(vehicle.position[1])
            half_width[i], half_length[i] = vehicle.WIDTH / 2, vehicle.LENGTH / 2
            speed[i], v0[i] = v, vehicle.target_speed
            drivers[i] = (p.max_acceleration, p.comfortable_braking, p.delta, p.min_gap,
                          p.time_gap, p.coolness)
            mine[i] = movers.index_of(vehicle, -1)
        rows_ = np.array(rows, np.int64)
        acc = _path_ahead(layout.path_starts[rows_], layout.path_ends[rows_], layout.path_px,
                          layout.path_py, layout.path_cum, s0, s1, x0, y0, half_width,
                          half_length, speed, v0, drivers, mine, self._path_margins,
                          self._xs, self._ys, *self._box_columns,
                          self._walker_mask, self._path_mask, _HORIZONS, 2.0)
        return {id(vehicle): (a, b) for vehicle, a, b in zip(chosen, acc.tolist(), v0.tolist(),
                                                             strict=True)}

    def neighbour_vehicles(self, vehicle: Any, lane_index: Any = None
                           ) -> tuple[Any | None, Any | None]:
        lane_index = lane_index or vehicle.lane_index
        if not lane_index or (self._positions is None and self.objects):
            return super().neighbour_vehicles(vehicle, lane_index)
        if self._positions is None:  # before the road's act (the decision's own act): all
            lon, rows = self._everyone_on(lane_index)  # vehicles, as highway-env
            candidates = self._everyone[0].vehicles
            mine = self._everyone[0].row_of.get(id(vehicle), -1)
        else:
            lon, rows = self._lane_table(lane_index)
            candidates = self._movers
            mine = candidates.index_of(vehicle, -1)
        lane = self.network.get_lane(lane_index)
        s = lane.local_coordinates(vehicle.position)[0]
        front, rear = _front_rear(rows, lon, float(s), mine)
        return (None if front < 0 else candidates[front],
                None if rear < 0 else candidates[rear])

    def step(self, dt: float) -> None:
        """Move everyone one step, then check collisions: every pair in which a vehicle
        checks them (the ego; idm traffic), with highway-env's rule (``handle_collisions``:
        boxes that intersect are both ``crashed``, boxes that will within the step are
        pushed apart and crashed at the next; a crashed simulated vehicle brakes to a stop,
        a replayed one keeps to its log). Pairs of traffic (the ego not in them) that
        collide are added to :attr:`traffic_collisions` as (step at which they are crashed,
        row, row), once; pairs that already overlap in the log at the current time are not
        collisions of the simulation (the record's own boxes) and are not checked."""
        self.clock[0] += 1
        self._positions = None
        self._path_accelerations = {}
        self._everyone = None
        layout = self._layout()
        for vehicle in layout.acting:  # in the road's order (log vehicles follow the clock)
            vehicle.step(dt)
        now = layout.states(self.clock[0])
        self._states_at = (self.clock[0], layout, now)  # read by _snapshot until it moves
        if now["own"] is not None:
            # the movers' rows, the pairs to check and those that stay apart over the step
            # (highway-env's test would change nothing for them)
            packed, m, p = _pairs_packed(
                now["collidable"], now["position"], layout.diagonal, layout.length,
                layout.width, now["heading"], now["speed"], now["checks"], now["own"],
                float(dt))
            packed = packed.tolist()
            vehicles = [layout.vehicles[i] for i in packed[:m]]
            first, second, apart = (packed[m:m + p], packed[m + p:m + 2 * p],
                                    packed[m + 2 * p:])
        else:  # an object without position or diagonal: every pair, as highway-env
            moving = np.flatnonzero(now["collidable"])  # their rows
            vehicles = [layout.vehicles[i] for i in moving.tolist()]
            first, second = (k.tolist() for k in np.triu_indices(len(vehicles), 1))
            apart = [False] * len(first)
        ego = self.vehicles[0]  # the env puts the ego first (a policy's takes its place)
        for i, j, far in zip(first, second, apart, strict=True):
            a, b = vehicles[i], vehicles[j]
            if a is ego or b is ego:  # the env names the ego's partner
                other = b if a is ego else a
                row = getattr(other, "row", -1)
                if row in self.ego_exempt:  # the record's overlap, while it lasts
                    if _intersecting(ego, other):
                        continue
                    self.ego_exempt.discard(row)
                if not far:
                    a.handle_collisions(b, dt)
                continue
            if far:
                continue
            pair = _pair(a, b)
            if pair in self.exempt:
                continue
            # whether this pair collides: it intersects (both crashed now), or will within
            # dt (an impact, which crashes a simulated vehicle at its next step)
            crashed, impact = (a.crashed, b.crashed), (a.impact, b.impact)
            a.crashed = b.crashed = False
            a.impact = b.impact = None
            a.handle_collisions(b, dt)
            now = a.crashed and b.crashed
            soon = a.impact is not None or b.impact is not None
            a.crashed |= crashed[0]
            b.crashed |= crashed[1]
            if a.impact is None:  # highway-env's last impact of a step wins
                a.impact = impact[0]
            if b.impact is None:
                b.impact = impact[1]
            if (now or soon) and pair not in self._pairs:
                self._pairs.add(pair)
                self.traffic_collisions.append((self.clock[0] + (0 if now else 1), *pair))

    def start_collisions(self) -> None:
        """Begin an episode's collision record (the vehicles placed, the ego first): pairs
        of traffic that overlap already (log states at the current time) are exempt, and
        so are the agents whose boxes overlap the ego's there (:attr:`ego_exempt`, rows),
        until they come apart: the record's overlaps, not collisions (SPEC section 8)."""
        self.traffic_collisions: list[tuple[int, int, int]] = []
        self._pairs: set[tuple[int, int]] = set()
        self.exempt: set[tuple[int, int]] = set()
        ego = self.vehicles[0]
        self.ego_exempt: set[int] = {
            v.row for v in self.vehicles[1:] if v.collidable and hasattr(v, "row")
            and np.hypot(*(v.position - ego.position)) <= (v.diagonal + ego.diagonal) / 2
            and _intersecting(ego, v)}
        vehicles = [v for v in self.vehicles[1:] if v.collidable]
        near = near_pairs(vehicles, [], 0.0)
        if near is None:
            return
        for i, j in zip(*np.nonzero(np.triu(near | near.T, 1)), strict=True):
            a, b = vehicles[i], vehicles[j]
            if utils.are_polygons_intersecting(a.polygon(), b.polygon(), np.zeros(2),
                                               np.zeros(2))[0]:
                self.exempt.add(_pair(a, b))

    # traffic's view ahead: leaders on the next lanes, stop signs, conflicts
    def _everyone_on(self, lane_index: Any) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_lane_table` of every vehicle of the road (collidable or not) where they
        are now, in the road's order (cached until the road acts or steps)."""
        layout = self._layout()
        if self._everyone is None or self._everyone[0] is not layout:
            position = self._snapshot()[1]["position"]
            self._everyone = (layout, np.ascontiguousarray(position[:, 0]),
                              np.ascontiguousarray(position[:, 1]), {})
        _, xs, ys, tables = self._everyone
        table = tables.get(lane_index)
        if table is None:
            lane = self.network.get_lane(lane_index)
            n = len(xs)
            members, lon = np.empty(n, np.int64), np.empty(n)
            n = _lane_members_into(*lane.arrays, lane.width / 2 + 1.0, -lane.VEHICLE_LENGTH,
                                   lane.length + lane.VEHICLE_LENGTH, xs, ys, members, lon)
            members = members[:n]
            table = tables[lane_index] = (lon, members)
        return table

    def _lane_table(self, lane_index: Any) -> tuple[np.ndarray, np.ndarray]:
        """(every one of this step's movers' longitudinal coordinate on a lane [m] (n,); the
        rows of those on it, in order: within its half width + 1 m, from ``VEHICLE_LENGTH``
        before its start to as far past its end), cached per step."""
        table = self._projections.get(lane_index)
        if table is None:
            lane = self.network.get_lane(lane_index)
            n = len(self._xs)
            members, lon = np.empty(n, np.int64), np.empty(n)
            n = _lane_members_into(*lane.arrays, lane.width / 2 + 1.0, -lane.VEHICLE_LENGTH,
                                   lane.length + lane.VEHICLE_LENGTH, self._xs, self._ys,
                                   members, lon)
            members = members[:n]
            table = self._projections[lane_index] = (lon, members)
        return table

    def leader_ahead(self, vehicle: Vehicle) -> tuple[Vehicle | None, float]:
        """The nearest mover ahead on the vehicle's next lanes (its route's, else the
        straightest; not its own lane, whose leader :meth:`neighbour_vehicles` finds) within
        :data:`LEADER_LOOKAHEAD`, and the distance between their centres along the way [m];
        (None, inf) if none."""
        if self._positions is None or not len(self._positions):
            return None, math.inf
        ahead = self._lanes_ahead(vehicle, LEADER_LOOKAHEAD)[1:]
        if not ahead:
            return None, math.inf
        # the lanes one after the other in one compiled pass (each lane's table as
        # _lane_table makes it, the search as _leader_on)
        limits = self._lane_limits
        for index, _ in ahead:
            if index not in limits:
                lane = self.network.get_lane(index)
                c, d = lane._shared[6:8]
                limits[index] = (float(c), float(d), lane.width / 2 + 1.0,
                                 -lane.VEHICLE_LENGTH, lane.length + lane.VEHICLE_LENGTH)
        px, py, tx, ty, s, _ = self._pose_arrays()
        best, best_d = _leader_ahead_on(
            px, py, tx, ty, s, np.array([limits[index] for index, _ in ahead]),
            np.array([float(base) for _, base in ahead]), self._xs, self._ys,
            self._box_columns[0], self._movers.index_of(vehicle, -1), float(vehicle.heading),
            LEADER_LOOKAHEAD)
        return (self._movers[best], best_d) if best >= 0 else (None, best_d)

    def corridor_leader(self, vehicle: Vehicle) -> tuple[float, float] | None:
        """The nearest mover whose box is in the vehicle's straight way ahead (the box's
        extent across the vehicle's axis within its half width + :data:`CORRIDOR_MARGIN`,
        its centre ahead of the vehicle's, within :data:`CORRIDOR_TIME` s at its speed plus
        :data:`CORRIDOR_MIN` m), whatever lane it is on: (bumper-to-box gap [m], its speed
        along the vehicle's heading [m/s]); None if none. The last line of defence where
        the lanes say nothing (overlapping junction lanes, a car cutting in)."""
        if self._positions is None or len(self._positions) < 2:
            return None
        reach = CORRIDOR_MIN + CORRIDOR_TIME * max(float(vehicle.speed), 0.0)
        k, gap, speed = _corridor(self._xs, self._ys, *self._box_columns,
                                  float(vehicle.position[0]), float(vehicle.position[1]),
                                  float(vehicle.heading), float(vehicle.LENGTH),
                                  float(vehicle.WIDTH), reach,
                                  self._movers.index_of(vehicle, -1))
        return None if k < 0 else (float(gap), float(speed))

    def obstacles_ahead(self, vehicle: Vehicle
                        ) -> tuple[Vehicle | None, float, tuple[float, float] | None,
                                   list[float]] | None:
        """What the vehicle finds on its way beyond its own lane's leader, as
        :meth:`leader_ahead`, :meth:`corridor_leader` and the vehicle's
        ``_standing_obstacles`` (:meth:`stop_distance`, :meth:`walker_distance`,
        :meth:`stop_sign_distance`, :meth:`conflict_gap`, each less its margins) give it,
        asked in that order, with the searches over the step's movers in one compiled pass
        (:func:`_ahead_in_one`): (the leader or None, its distance [m] or inf, the
        corridor's (gap [m], speed [m/s]) or None, the standing obstacles' gaps [m]). None
        before the road has acted in this step or without movers (then ask each)."""
        if self._positions is None or not len(self._positions):
            return None
        ahead = self._lanes_ahead(vehicle, LANES_AHEAD)
        # each shorter look's lanes (_lanes_ahead's cut: the first lane, then those that
        # start within it) are the first ones of the longest: the lanes start farther and
        # farther along the way
        key = tuple(index for index, _ in ahead)
        bases_list = [float(base) for _, base in ahead]
        n_leader = n_walker = n_conflict = 1
        for base in bases_list[1:]:
            n_leader += base <= LEADER_LOOKAHEAD
            n_walker += base <= WALKER_LOOKAHEAD
            n_conflict += base <= CONFLICT_LOOKAHEAD
        if bases_list[0] > CONFLICT_LOOKAHEAD:  # conflict_gap's search ends at once
            n_conflict = 0
        lanes = self._ahead_lane_rows(key)
        conflicts = self._ahead_conflict_tables(key, n_conflict)
        bases = np.array(bases_list)
        px, py, tx, ty, s, hd = self._pose_arrays()
        heading, speed, length, width = self._box_columns
        yielder, braking_j, row_j = self._conflict_movers()
        p = vehicle.parameters() if hasattr(vehicle, "parameters") else None
        braking = p.comfortable_braking if p is not None else 3.0
        critical = p.critical_gap if p is not None else 3.0
        v = max(float(vehicle.speed), 0.0)
        x, y = float(vehicle.position[0]), float(vehicle.position[1])
        half_length = vehicle.LENGTH / 2
        # the walkers: remembered for the step and lane (MOBIL, the decision's own act)
        walkers = self._walkers
        look = remembered = None
        reach2 = half = 0.0
        columns = (_NONE,) * 6
        if walkers is not None and len(walkers[0]):
            look = (self.clock[0], vehicle.lane_index)
            cached = vehicle.__dict__.get("_walker_distance")
            if cached is not None and cached[0] == look:
                remembered, look = cached[1], None
            else:
                reach = (WALKER_LOOKAHEAD + vehicle.LENGTH
                         + WALKER_HORIZON * self._walker_fastest)
                reach2, half = reach * reach, vehicle.WIDTH / 2 + WALKER_CLEARANCE
                (wx0, wy0), (wx1, wy1) = self._walker_columns
                columns = (wx0, wy0, wx1, wy1, walkers[2], walkers[3])
                self._fill_walker_headings(key[:n_walker])
        ego = np.array((x, y, float(vehicle.heading), float(vehicle.LENGTH),
                        float(vehicle.WIDTH), v, float(braking), float(critical),
                        CORRIDOR_MIN + CORRIDOR_TIME * max(float(vehicle.speed), 0.0),
                        reach2, half))
        whd = self._walker_hd if self._walker_hd is not None else hd
        leader, leader_d, k, gap, along, walker_d, give_way = _ahead_in_one(
            px, py, tx, ty, s, hd, whd, lanes, bases, self._xs, self._ys, heading, speed,
            length, width, self._walker_mask, yielder, braking_j, row_j, *conflicts,
            *columns, ego, self._movers.index_of(vehicle, -1), getattr(vehicle, "row", -1),
            (n_leader, n_walker), look is not None)
        standing = []
        d = self.stop_distance(vehicle)
        if d is not None:
            standing.append(d - half_length - STOP_MARGIN)
        if look is not None:
            remembered = None if math.isnan(walker_d) else walker_d
            vehicle.__dict__["_walker_distance"] = (look, remembered)
        if remembered is not None:
            standing.append(remembered - WALKER_RADIUS - half_length - STOP_MARGIN)
        d = self.stop_sign_distance(vehicle)
        if d is not None:
            standing.append(d - half_length - STOP_MARGIN)
        if give_way == give_way:
            standing.append(give_way)
        return (self._movers[leader] if leader >= 0 else None, leader_d,
                None if k < 0 else (float(gap), float(along)), standing)

    def _ahead_lane_rows(self, key: tuple) -> np.ndarray:
        """(k, 6) the rows of :func:`_ahead_in_one`'s ``lanes`` for the lanes ``key`` (lane
        indices, :meth:`_lanes_ahead`'s): each lane's poses c, d, a mover's reach across it, its
        longitudinal range [lo, hi) (:meth:`_lane_table`'s), its length [m]; kept by the
        lanes."""
        rows = self._ahead_lanes.get(key)
        if rows is None:
            out = []
            for index in key:
                lane = self.network.get_lane(index)
                c, d = lane._shared[6:8]
                out.append((float(c), float(d), lane.width / 2 + 1.0, -lane.VEHICLE_LENGTH,
                            lane.length + lane.VEHICLE_LENGTH, float(lane.length)))
            rows = self._ahead_lanes[key] = np.array(out, np.float64).reshape(-1, 6)
        return rows

    def _ahead_conflict_tables(self, key: tuple, n: int) -> tuple[np.ndarray, ...]:
        """The conflict tables (:meth:`_conflict_table`) of the first ``n`` lanes of ``key``
        (lane indices) end to end for :func:`_ahead_in_one`: (conf, at, approach, offsets,
        clanes, sections (k, 7): each lane's rows q0, q1 of conf, a0 of at, r0, r1 of
        approach and offsets, u0, u1 of clanes); kept by the lanes (a lane's table is made
        when first asked for)."""
        made = self._ahead_conflicts.get((key, n))
        if made is None:
            tables = [self._conflict_table(index) for index in key[:n]]
            sections, q, a, r, u = [], 0, 0, 0, 0
            for conf, at, approach, _, lanes in tables:
                sections.append((q, q + len(conf), a, r, r + len(approach), u, u + len(lanes)))
                q, a, r, u = q + len(conf), a + len(at), r + len(approach), u + len(lanes)
            made = self._ahead_conflicts[key, n] = (
                np.concatenate([t[0] for t in tables] or [np.zeros((0, 2))]).reshape(-1, 2),
                np.concatenate([t[1] for t in tables] or [np.zeros(0, np.int64)]),
                np.concatenate([t[2] for t in tables] or [np.zeros(0, np.int64)]),
                np.concatenate([t[3] for t in tables] or [np.zeros(0)]),
                np.concatenate([t[4] for t in tables] or [np.zeros((0, 14))]).reshape(-1, 14),
                np.array(sections, np.int64).reshape(-1, 7))
        return made

    def _fill_walker_headings(self, lanes: tuple) -> None:
        """The walkers' lane headings (:meth:`_lane_headings`) of ``lanes`` (lane indices)
        set in their poses' places of :attr:`_walker_hd`."""
        filled = self._walker_hd_lanes
        for index in lanes:
            if index not in filled:
                if self._walker_hd is None:
                    self._walker_hd = np.full(len(self._pose_arrays()[0]), np.nan)
                c, d = self.network.get_lane(index)._shared[6:8]
                self._walker_hd[c:d] = self._lane_headings(index)
                filled.add(index)

    @staticmethod
    def _stop_sign_points(network: WomdNetwork, road: Any) -> dict[Any, list[float]]:
        """Lane index -> where on the lane [m] its stop signs stand: on the lanes a sign
        lists, else on the lanes that end within :data:`STOP_SIGN_REACH` of it (the lanes
        entering the junction it guards)."""
        out: dict[Any, list[float]] = {}
        ends = {lane_id: lane.centre[-1] for lane_id, lane in road.lanes.items()
                if lane_id in network.index and len(lane.centre) and lane.exit}
        end_ids = list(ends)
        end_points = np.array([end[:2] for end in ends.values()]).reshape(-1, 2)
        for sign in road.stop_signs:
            position = np.asarray(sign.position, float)[:2]
            lanes = [i for i in sign.lanes if i in network.index]
            if not lanes and ends:
                # near by numpy's hypot, then each one by the exact rule
                near = np.flatnonzero(np.hypot(*(end_points - position).T)
                                      <= STOP_SIGN_REACH + 1e-6)
                lanes = [end_ids[k] for k in near.tolist()
                         if math.hypot(*(end_points[k] - position)) <= STOP_SIGN_REACH]
            for lane_id in lanes:
                index = network.index[lane_id]
                lane = network.get_lane(index)
                s_stop = float(lane.local_coordinates(sim_frame(*position))[0])
                out.setdefault(index, []).append(min(max(s_stop, 0.0), lane.length))
        return out

    def stop_sign_distance(self, vehicle: Vehicle) -> float | None:
        """Distance [m] along the vehicle's way (from its centre) to the next stop sign it
        has not stopped at yet; None if none within :data:`STOP_LOOKAHEAD`. A vehicle has
        stopped at a sign once it is slower than :data:`STOP_SIGN_SPEED` with its bumper
        within :data:`STOP_SIGN_NEAR` of it; one that cannot stop there braking comfortably
        when it first sees the sign (it was already rolling through at the current time)
        goes on."""
        if not self._stop_signs:
            return None
        served = vehicle.__dict__.setdefault("stop_signs_served", set())
        braking = (vehicle.parameters().comfortable_braking
            if hasattr(vehicle, "parameters") else 3.0)
        best = None
        for index, base in self._lanes_ahead(vehicle, STOP_LOOKAHEAD):
            for k, s_stop in enumerate(self._stop_signs.get(index, ())):
                key = (index, k)
                d = base + s_stop
                if key in served or d < 0 or d > STOP_LOOKAHEAD:
                    continue
                room = d - vehicle.LENGTH / 2
                if room <= STOP_SIGN_NEAR and vehicle.speed < STOP_SIGN_SPEED:
                    served.add(key)
                    continue
                seen = vehicle.__dict__.setdefault("stop_signs_seen", set())
                if key not in seen:
                    seen.add(key)
                    if vehicle.speed ** 2 > 2 * braking * max(room - STOP_MARGIN, 0.0):
                        served.add(key)  # too late to stop comfortably: through
                        continue
                best = d if best is None else min(best, d)
        return best

    def conflicts(self, lane_index: Any) -> list[tuple[Any, float, float]]:
        """(other lane, where the conflict is on this lane [m], ... on the other [m]) for
        the lanes that cross this one (their centre lines intersect; not lanes joined end to
        start, leaving the same lane or beside it) and that merge with it (they lead into
        the same lane: the conflict is at both ends)."""
        cached = self._conflicts.get(lane_index)
        if cached is not None:
            return cached
        network = self.network
        lane = network.get_lane(lane_index)
        out: list[tuple[Any, float, float]] = []
        successors = set(network.successors(lane_index))
        predecessors = set(self._predecessors.get(lane_index, ()))
        siblings = {s for p in predecessors for s in network.successors(p)}
        beside = set(network.side_lanes(lane_index))
        for other in {s for p in successors for s in self._predecessors.get(p, ())}:
            if other != lane_index:
                out.append((other, lane.length, network.get_lane(other).length))
        ax, ay, bx, by, owner = self._lane_segments
        centre = network.road_map.lanes[network.womd_id(lane_index)].centre
        pts = sim_frame(centre[:, 0], centre[:, 1])
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if self._segment_boxes is None:
            self._segment_boxes = (np.maximum(ax, bx), np.minimum(ax, bx),
                                   np.maximum(ay, by), np.minimum(ay, by))
        hi_x, lo_x, hi_y, lo_y = self._segment_boxes
        near = np.flatnonzero((hi_x >= lo[0]) & (lo_x <= hi[0]) & (hi_y >= lo[1])
                              & (lo_y <= hi[1]))
        # the segments of the lanes it meets end to end or runs beside are never conflicts
        skip = np.zeros(len(self._lane_list), bool)
        for other in (lane_index, *successors, *predecessors, *siblings, *beside):
            k = self._lane_slot.get(other)
            if k is not None:
                skip[k] = True
        near = near[~skip[owner[near]]]
        if len(near) and len(pts) >= 2:
            hits = _segment_hits(np.ascontiguousarray(pts[:, 0]),
                                 np.ascontiguousarray(pts[:, 1]), near, ax, ay, bx, by)
            for k, q, d1, d2 in hits.tolist():
                k = int(k)
                other = self._lane_list[owner[int(q)]]
                if (other == lane_index or other in successors or other in predecessors
                        or other in siblings or other in beside):
                    continue
                u = d1 / (d1 - d2)  # d1 != d2: not parallel
                point = pts[k] + u * (pts[k + 1] - pts[k])
                s_self = float(lane.local_coordinates(point)[0])
                s_other = float(network.get_lane(other).local_coordinates(point)[0])
                if any(o == other and abs(a - s_self) < 2.0 for o, a, _ in out):
                    continue
                out.append((other, s_self, s_other))
        self._conflicts[lane_index] = out
        return out

    def conflict_gap(self, vehicle: Vehicle) -> float | None:
        """Gap [m] from the bumper to the nearest conflict zone ahead where the vehicle must
        give way (gap acceptance); None if none.

        At a conflict point on its way (within :data:`CONFLICT_LOOKAHEAD`) the vehicle gives
        way to another mover approaching it along the other lane (or the lanes into it)
        that is in the conflict zone now, or that reaches it first, or within the driver's
        critical gap after it when the other cannot give way (a replayed agent, the ego, or
        one that cannot stop there braking comfortably); arrivals within
        :data:`CONFLICT_TIE` s go by scene row. It does not give way once it cannot stop
        before the zone braking comfortably (it clears it)."""
        if self._positions is None or not len(self._positions):
            return None
        p = vehicle.parameters() if hasattr(vehicle, "parameters") else None
        braking = p.comfortable_braking if p is not None else 3.0
        critical = p.critical_gap if p is not None else 3.0
        v_i = max(float(vehicle.speed), 0.0)
        yielder, braking_j, row_j = self._conflict_movers()
        px, py, tx, ty, s, hd = self._pose_arrays()
        heading, speed, length, width = self._box_columns
        mine = self._movers.index_of(vehicle, -1)
        row = getattr(vehicle, "row", -1)
        best = None
        for index, base in self._lanes_ahead(vehicle, CONFLICT_LOOKAHEAD):
            if base > CONFLICT_LOOKAHEAD:
                break
            conf, at, approach, offsets, lanes = self._conflict_table(index)
            if not len(conf):
                continue
            gap = _conflict_gap_on(
                float(base), conf, at, approach, offsets, lanes, px, py, tx, ty, s, hd,
                self._xs, self._ys, heading, length, width, speed, self._walker_mask,
                yielder, braking_j, row_j, mine, row, float(vehicle.LENGTH),
                float(vehicle.WIDTH), v_i, float(braking), float(critical))
            if gap == gap:
                best = gap if best is None else min(best, gap)
        return best

    def _conflict_movers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(whether each of this step's movers gives way at conflicts (an IDM or path
        vehicle), its comfortable braking [m/s^2] (NaN for the others), its scene row (-1:
        none)), made once per step."""
        if self._mover_conflict is None:
            layout = self._vehicle_layout  # the act's
            rows = self._mover_rows
            self._mover_conflict = (layout.yielder[rows], layout.conflict_braking()[rows],
                                    layout.row[rows])
        return self._mover_conflict

    def _pose_arrays(self) -> tuple[np.ndarray, ...]:
        """(px, py, tx, ty, s, heading) of every pose of the network's lanes (the arrays
        their lanes are slices of; heading [rad] as :meth:`_lane_headings`)."""
        if self._poses is None:
            # WomdNetwork builds its lanes together (FastPolyLane.many): one set of arrays,
            # which it keeps; another network's lanes are asked
            made = getattr(self.network, "shared_poses", None)
            shared = {id(made): made} if made is not None else {id(poses): poses for poses in (
                self.network.get_lane(i)._shared[1] for i in self._lane_list)}
            if len(shared) != 1:
                raise ValueError(f"the lanes of the road's network have {len(shared)} sets "
                                 "of pose arrays; WomdNetwork builds them as one")
            px, py, tx, ty, s = next(iter(shared.values()))
            self._poses = (px, py, tx, ty, s, np.arctan2(ty, tx))
        return self._poses

    def _conflict_table(self, lane_index: Any) -> tuple[np.ndarray, ...]:
        """The conflicts of a lane (:meth:`conflicts`) as arrays for
        :func:`_conflict_gap_on`: (conf (m, 2) where each is on this lane and on the other
        [m], at (m + 1,) its approaching lanes' rows, approach (k,) each row's lane in
        ``lanes``, offsets (k,) where that lane starts before the other one [m], lanes (u,
        14) each lane's poses c, d, the mover's reach across it, its longitudinal range
        [lo, hi) [m] (:meth:`_lane_table`'s), then the bound of its lane distance that
        :func:`_lane_members_near` leaves far movers out by (:meth:`_member_bound`));
        built once per lane."""
        table = self._conflict_tables.get(lane_index)
        if table is not None:
            return table
        network = self.network
        conflicts = self.conflicts(lane_index)
        at, approach, offsets, lanes, slot = [0], [], [], [], {}
        for other_lane, _, _ in conflicts:
            for index, offset in [(other_lane, 0.0)] + [
                    (p, float(network.get_lane(p).length))
                    for p in self._predecessors.get(other_lane, ())]:
                if index not in slot:
                    lane = network.get_lane(index)
                    c, d = lane._shared[6:8]
                    slot[index] = len(lanes)
                    half, lo, hi = (lane.width / 2 + 1.0, -lane.VEHICLE_LENGTH,
                                    lane.length + lane.VEHICLE_LENGTH)
                    lanes.append((c, d, half, lo, hi,
                                  *self._member_bound(index, c, d, half, lo, hi)))
                approach.append(slot[index])
                offsets.append(offset)
            at.append(len(approach))
        table = self._conflict_tables[lane_index] = (
            np.array([(a, b) for _, a, b in conflicts], dtype=np.float64).reshape(-1, 2),
            np.array(at, np.int64), np.array(approach, np.int64),
            np.array(offsets, np.float64), np.array(lanes, np.float64).reshape(-1, 14))
        return table

    def _member_bound(self, lane_index: Any, c: int, d: int, half: float, lo: float,
                      hi: float) -> tuple[float, ...]:
        """The bound row of :func:`_lane_members_near` for a lane (its poses ``c:d`` of
        the pose arrays; a member within ``half`` of its centre line, lon in [lo, hi)):
        the network's :class:`~tap_bench.sim.womd_lanes.LaneIndex` row of the lane (the
        box of its poses, the wedge's slack, slope and tail, the box's reach) and
        :func:`_member_limit`; a limit of inf (no mover left out) where the index has no
        such row for these poses."""
        lookup = self.network.lookup
        rows = self.__dict__.get("_lookup_rows")
        if rows is None:
            rows = self._lookup_rows = {index: j for j, index in enumerate(lookup.indexes)}
        j = rows.get(lane_index)
        boxes = lookup.boxes
        if (j is None or boxes.shape[1] < 7 or int(lookup.offsets[j]) != c
                or int(lookup.offsets[j + 1]) != d):
            return (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, math.inf)
        return (*boxes[j, :7].tolist(), float(lookup.reach[j]),
                _member_limit(half, lo, hi, float(lookup.lengths[j])))

    # signals
    def _lanes_ahead(self, vehicle: Vehicle, lookahead: float) -> list[tuple[Any, float]]:
        """(lane index, where the lane starts [m] along the vehicle's way from its centre) of
        its lane and the next ones (its route's, else the straightest) up to ``lookahead``
        [m] (at most three more). The longest look of a step is kept on the vehicle and cut
        for shorter ones (the stop points, walkers, conflicts and leaders all ask), each
        cut kept too: the list is shared, read it without changing it."""
        key = (self.clock[0], vehicle.lane_index, vehicle.position.tobytes())
        cached = vehicle.__dict__.get("_lanes_ahead_cache")
        if cached is None or cached[0] != key or cached[1] < lookahead:
            cached = (key, max(lookahead, LANES_AHEAD), self._lanes_ahead_now(
                vehicle, max(lookahead, LANES_AHEAD)), {})
            vehicle.__dict__["_lanes_ahead_cache"] = cached
        cut = cached[3].get(lookahead)  # each look's lanes, kept with the step's
        if cut is None:
            cut = cached[3][lookahead] = [item for k, item in enumerate(cached[2])
                                          if k == 0 or item[1] <= lookahead]
        return cut

    def _lanes_ahead_now(self, vehicle: Vehicle, lookahead: float) -> list[tuple[Any, float]]:
        """:meth:`_lanes_ahead`, computed."""
        network = self.network
        lane_index = vehicle.lane_index
        s = network.get_lane(lane_index).local_coordinates(vehicle.position)[0]
        ahead = [(lane_index, -s)]
        route = getattr(vehicle, "route", None)
        offset = network.get_lane(lane_index).length - s
        current = lane_index
        for _ in range(3):
            if offset > lookahead:
                break
            nxt = network.next_lane(current, route=route, position=vehicle.position)
            if nxt == current:
                break
            ahead.append((nxt, offset))
            offset += network.get_lane(nxt).length
            current = nxt
        return ahead

    def walker_distance(self, vehicle: Vehicle) -> float | None:
        """Distance [m] along the vehicle's lanes to the nearest pedestrian or cyclist in its
        way ahead (within :data:`WALKER_LOOKAHEAD`): one whose position now or in
        :data:`WALKER_HORIZON` s (at its logged velocity) is within half the vehicle's width
        + :data:`WALKER_CLEARANCE` of the lane's centre line, crossing it or standing (one
        moving along the lane is a leader IDM follows already); None if none."""
        walkers = self._walkers
        if walkers is None or not len(walkers[0]):
            return None
        key = (self.clock[0], vehicle.lane_index)  # MOBIL asks again within a step
        cached = vehicle.__dict__.get("_walker_distance")
        if cached is not None and cached[0] == key:
            return cached[1]
        best = self._walker_distance(vehicle, walkers)
        vehicle.__dict__["_walker_distance"] = (key, best)
        return best

    def _walker_distance(self, vehicle: Vehicle, walkers: tuple[np.ndarray, ...]
                         ) -> float | None:
        _, _, heading, speed = walkers
        reach = WALKER_LOOKAHEAD + vehicle.LENGTH + WALKER_HORIZON * self._walker_fastest
        xs, ys = self._walker_columns[0]
        if not _any_within(xs, ys, float(vehicle.position[0]), float(vehicle.position[1]),
                           reach * reach):
            return None  # nobody within reach of its way (the usual case): no lane walk
        half = vehicle.WIDTH / 2 + WALKER_CLEARANCE
        best = math.nan
        for index, base in self._lanes_ahead(vehicle, WALKER_LOOKAHEAD):
            lane = self.network.get_lane(index)
            for xs, ys in self._walker_columns:  # where they are, where they will be
                best = _walkers_on_lane(*lane.arrays, self._lane_headings(index), base, half,
                                        lane.length, xs, ys, heading, speed, best)
        return None if math.isnan(best) else best

    def _lane_headings(self, lane_index: Any) -> np.ndarray:
        """(n_poses,) the heading [rad] of each pose of a lane (``heading_at``'s)."""
        out = self._headings.get(lane_index)
        if out is None:
            _, _, tx, ty, _ = self.network.get_lane(lane_index).arrays
            out = self._headings[lane_index] = np.arctan2(ty, tx)
        return out

    def stop_distance(self, vehicle: Vehicle) -> float | None:
        """Distance [m] along the vehicle's lanes to the nearest stop point ahead whose signal
        is red, or yellow and far enough to stop at (comfortable braking); None if none."""
        k = min(self.clock[0], len(self._red) - 1)
        if not len(self._signal_lanes) or k < 0:
            return None
        active = self._red_or_yellow_at.get(k)
        if active is None:
            active = self._red_or_yellow_at[k] = np.flatnonzero(
                self._red_or_yellow[k]).tolist()
        # the yellow lines this vehicle decided to stop at (while they stay yellow or red)
        held = vehicle.__dict__.setdefault("yellow_stops", set())
        held.intersection_update(active)
        if not active:
            return None
        ahead = self._lanes_ahead(vehicle, STOP_LOOKAHEAD)
        red = None
        best = None
        for j in active:
            index = self._signal_lanes[j]
            for lane, base in ahead:
                if lane != index or not math.isfinite(self._stop_s[j]):
                    continue
                d = base + self._stop_s[j]
                if d < -0.5 or d > STOP_LOOKAHEAD:
                    continue
                if red is None:
                    red = self._red_at_step(k)
                if j not in red and j not in held:
                    # yellow: stop only when the bumper can stop STOP_MARGIN before the line
                    # braking comfortably; once it stops it keeps stopping (no late dash)
                    room = d - vehicle.LENGTH / 2 - STOP_MARGIN
                    brake = vehicle.speed ** 2 / max(2 * room, 1e-3)
                    if room <= 0 or brake > -getattr(vehicle, "COMFORT_ACC_MIN", -5.0):
                        continue
                    held.add(int(j))
                best = d if best is None else min(best, d)
        return best

    def _red_at_step(self, k: int) -> list[int]:
        """The signals (columns of the signal states) that are red at step ``k``, in order;
        made once per step."""
        red = self._red_at.get(k)
        if red is None:
            red = self._red_at[k] = np.flatnonzero(self._red[k]).tolist()
        return red

    def crossed_red(self, before: np.ndarray, after: np.ndarray) -> bool:
        """Whether a move (sim frame) crossed a stop point whose signal is red at the road's
        step: from before to beyond it along its lane, within the lane's width."""
        k = min(self.clock[0], len(self._red) - 1)
        if k < 0 or not len(self._signal_lanes):
            return False
        for j in self._red_at_step(k):
            index = self._signal_lanes[j]
            if index is None or not math.isfinite(self._stop_s[j]):
                continue
            lane = self.network.get_lane(index)
            s0, d0 = lane.local_coordinates(before)
            s1, d1 = lane.local_coordinates(after)
            stop = self._stop_s[j]
            if s0 < stop <= s1 and max(abs(d0), abs(d1)) <= lane.width / 2 + OFF_ROAD_MARGIN:
                return True
        return False

    def off_road_distance(self, vehicle: Vehicle) -> tuple[float, str]:
        """(signed distance [m], rule) of a vehicle's box to the drivable area, positive off
        the road (SPEC section 8): against the road edges (:mod:`tap_bench.sim.road_edges`,
        rule ``"road edge"``) where one is within
        :data:`~tap_bench.sim.road_edges.EDGE_REACH` of it, else the centre's distance beyond
        half the nearest lane's width + :data:`OFF_ROAD_MARGIN` (rule ``"lane centre"``)."""
        x, y = float(vehicle.position[0]), float(vehicle.position[1])
        d = self.road_edges.box_distance(x, -y, -float(vehicle.heading),
                                         float(vehicle.LENGTH), float(vehicle.WIDTH))
        if math.isfinite(d):  # a float: math's test, not numpy's on a scalar
            return d, "road edge"
        ax, ay, bx, by, owner = self._lane_segments
        if not len(ax):
            return float("nan"), "none"
        return float(_lane_clearance(ax, ay, bx, by, self._half, owner, x, y)
                     - OFF_ROAD_MARGIN), "lane centre"

    def start_off_road(self, vehicle: Vehicle) -> None:
        """Record where the ego starts, by each rule (the episode's start is the human's: a
        policy is judged on leaving the road, never on starting off it)."""
        x, y = float(vehicle.position[0]), float(vehicle.position[1])
        ax, ay, bx, by, owner = self._lane_segments
        lane = (float(_lane_clearance(ax, ay, bx, by, self._half, owner, x, y))
                - OFF_ROAD_MARGIN) if len(ax) else float("nan")
        edge = self.road_edges.box_distance(x, -y, -float(vehicle.heading),
                                            float(vehicle.LENGTH), float(vehicle.WIDTH))
        self.off_road_start = {"road edge": edge, "lane centre": lane}

    def off_road(self, vehicle: Vehicle) -> tuple[bool, float, str]:
        """(left the road, signed distance [m], rule) of a vehicle at this step
        (:meth:`off_road_distance`, :func:`~tap_bench.sim.road_edges.left_road` against the
        start :meth:`start_off_road` recorded by the same rule)."""
        if not vehicle.collidable:  # a replayed ego at a step its log does not have
            return False, float("nan"), "none"
        d, rule = self.off_road_distance(vehicle)
        return left_road(d, self.off_road_start.get(rule, float("nan"))), d, rule


# ------------------------------------------------------------------ routes


def logged_route(network: WomdNetwork, xy: np.ndarray, heading: np.ndarray
                 ) -> tuple[list[tuple[str, str, int]], float]:
    """The lanes a logged path follows (sim frame): the nearest lane by distance and heading
    at each position, consecutive repeats and one-step flickers removed, gaps between lanes
    that are neither exits nor neighbours bridged through the graph (up to three lanes).

    Returns:
        the route (lane indexes, in order) and the share of positions farther than half
        their lane's width + :data:`ROUTE_OFF_MAP` from it (the path leaves the map there).
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    # every position's lane in one compiled pass, then each lane's positions projected at once
    indexes = network.lookup.closest_many(xy, heading) if len(xy) else []
    on_lane: dict[Any, list[int]] = {}
    for k, index in enumerate(indexes):
        on_lane.setdefault(index, []).append(k)
    off = 0
    for index, rows in on_lane.items():
        lane = network.get_lane(index)
        _, lat = lane.project(xy[rows, 0], xy[rows, 1])
        off += int(np.count_nonzero(np.abs(lat) > lane.width / 2 + ROUTE_OFF_MAP))
    seq: list = []
    for index in indexes:
        if not seq or seq[-1] != index:
            seq.append(index)
    cleaned: list = []
    for index in seq:  # A B A -> A
        if len(cleaned) >= 2 and cleaned[-2] == index:
            cleaned.pop()
            continue
        cleaned.append(index)
    route = cleaned[:1]
    for b in cleaned[1:]:
        a = route[-1]
        if b in network.successors(a) or b in network.side_lanes(a):
            route.append(b)
            continue
        route.extend(_bridge(network, a, b))
        route.append(b)
    return route, off / max(len(xy), 1)


def _bridge(network: WomdNetwork, a: Any, b: Any, depth: int = 3) -> list:
    """Lanes between a and b through the exits (breadth first, up to ``depth``); [] if
    none."""
    frontier = [[a]]
    for _ in range(depth):
        nxt = []
        for path in frontier:
            for s in network.successors(path[-1]):
                if s == b:
                    return path[1:]
                if s not in path:
                    nxt.append([*path, s])
        frontier = nxt
    return []


def path_progress(path: np.ndarray, cum: np.ndarray, p: np.ndarray,
                  columns: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                  ) -> tuple[float, float]:
    """(s, distance) [m] of point p projected on a polyline path (n >= 2) with arc lengths
    ``cum``: on its nearest segment (the first of equally near ones). ``columns``: the
    path's :func:`path_columns`, made once by a caller that asks at every step (then
    ``path`` and ``cum`` are not read)."""
    px, py, arc = columns if columns is not None else path_columns(path, cum)
    s, d = _path_progress(px, py, arc, float(p[0]), float(p[1]))
    return float(s), float(d)


def path_columns(path: np.ndarray, cum: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, arc length) (n,) [m] each, contiguous float64: a polyline path (n, 2) and its
    arc lengths ``cum`` as :func:`path_progress`'s compiled pass reads them."""
    path = np.asarray(path, dtype=np.float64)
    return (np.ascontiguousarray(path[:, 0]), np.ascontiguousarray(path[:, 1]),
            np.ascontiguousarray(cum, dtype=np.float64))


@numba.njit(cache=True, nogil=True)
def _path_progress(px, py, cum, x, y):  # pragma: no cover - compiled
    """:func:`path_progress` in one pass (segments of zero length count as 1e-12 m^2)."""
    best_d, best_s = np.inf, np.nan
    for k in range(px.shape[0] - 1):
        abx, aby = px[k + 1] - px[k], py[k + 1] - py[k]
        n2 = max(abx * abx + aby * aby, 1e-12)
        u = min(max(((x - px[k]) * abx + (y - py[k]) * aby) / n2, 0.0), 1.0)
        d = np.hypot(x - (px[k] + u * abx), y - (py[k] + u * aby))
        if not d == d:  # not a number: the first one wins, as numpy's argmin
            return cum[k] + u * math.sqrt(n2), d
        if d < best_d:
            best_d, best_s = d, cum[k] + u * math.sqrt(n2)
    return best_s, best_d


# ------------------------------------------------------------------ scenes and the env
