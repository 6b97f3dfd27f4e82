"""Missions in: QGroundControl ``.plan``, MAVLink waypoint files (QGC WPL 110), route CSVs,
GeoJSON LineStrings and the project's own plan GeoJSON, read into one ``Mission``.

Problem statement (kept apart from how it is solved): a mission file lists where the robot
goes (latitude/longitude/altitude items, or map-frame rows), at what speed, how long it holds
at each point, how it turns, and whether it comes home at the end. ``check`` needs that as
waypoints in the map's frame (x east, y north, z above home [m]) with those attributes, or a
one-line refusal naming the item when the file cannot be flown as read (an unknown command, no
home, a coordinate that is not a number, an altitude below the terrain it is measured from).

How it is solved: latitude/longitude go through the map's ``origin`` with the exact
conversion of ``export.autopilot`` (``latlon_to_xy``); with no origin, a local frame at the
mission's home (its first point) stands in. MAVLink items are read in order:

* ``NAV_TAKEOFF`` (22) gives the take-off altitude;
* ``NAV_WAYPOINT`` (16) is a waypoint: param1 its hold time [s], param2 its acceptance radius
  [m] (0: the autopilot's default, ``DEFAULT_ACCEPTANCE_RADIUS_M``), params 5-7 its position;
* ``NAV_LOITER_TIME`` (19) is a waypoint held for param1 seconds;
* ``DO_CHANGE_SPEED`` (178) sets param2 [m/s] for the legs that follow (-1: unchanged);
* ``NAV_RETURN_TO_LAUNCH`` (20) ends the mission with the way home; ``NAV_LAND`` (21) ends it
  with a landing where it says (at home, or at the last waypoint when it gives no position);
* the commands in ``PASSIVE_COMMANDS`` (camera, gimbal, servo, heading) do not move the
  robot and are skipped; any other command is refused: the check cannot say what it does.

Altitudes (the MAVLink frames of the QGroundControl plan format): a relative-altitude frame
(3, 6: ``MAV_FRAME_GLOBAL_RELATIVE_ALT``) is above home; a global frame (0, 5:
``MAV_FRAME_GLOBAL``) is above mean sea level and becomes above-home with the home's altitude;
a terrain frame (10, 11: ``MAV_FRAME_GLOBAL_TERRAIN_ALT``) is above the ground at the
waypoint, kept as such (``MissionWaypoint.above_terrain``) until ``Mission.above_home`` places
it on a terrain. A waypoint may lie below home (a survey of a valley flown from a ridge);
whether it is above the ground there is for the terrain to say (``planning.mission_check``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from orange_plan.errors import InputError
from orange_plan.export.autopilot import (
    DO_CHANGE_SPEED,
    NAV_RETURN_TO_LAUNCH,
    NAV_TAKEOFF,
    NAV_WAYPOINT,
    MissionItem,
    latlon_to_xy,
)
from orange_plan.files import csv_delimiter_hint, read_json, require_file
from orange_plan.limits import MAX_MISSION_WAYPOINTS

NAV_LAND, NAV_LOITER_TIME = 21, 19
PASSIVE_COMMANDS = {
    112: "CONDITION_DELAY", 115: "CONDITION_YAW", 183: "DO_SET_SERVO", 184: "DO_REPEAT_SERVO", 189: "DO_LAND_START",
    195: "DO_SET_ROI_LOCATION", 197: "DO_SET_ROI_NONE", 201: "DO_SET_ROI",
    203: "DO_DIGICAM_CONTROL", 205: "DO_MOUNT_CONTROL", 206: "DO_SET_CAM_TRIGG_DIST",
    530: "SET_CAMERA_MODE", 1000: "DO_GIMBAL_MANAGER_PITCHYAW", 2000: "IMAGE_START_CAPTURE",
    2001: "IMAGE_STOP_CAPTURE", 2500: "VIDEO_START_CAPTURE", 2501: "VIDEO_STOP_CAPTURE",
}
"""MAV_CMDs that do not move the robot: skipped by the reader."""
RELATIVE_FRAMES = {3, 6}
"""MAV_FRAME_GLOBAL_RELATIVE_ALT(_INT): altitude above home."""
GLOBAL_FRAMES = {0, 5}
"""MAV_FRAME_GLOBAL(_INT): altitude above mean sea level."""
TERRAIN_FRAMES = {10, 11}
"""MAV_FRAME_GLOBAL_TERRAIN_ALT(_INT): altitude above the ground at the waypoint."""
DEFAULT_ACCEPTANCE_RADIUS_M = 2.0
"""Acceptance radius of a waypoint whose param2 is 0 (the autopilot's own default: ArduPilot's
WPNAV_RADIUS; PX4 sets NAV_ACC_RAD) [m]: the turn there starts this far before the waypoint."""
HOME_MATCH_M = 1.0
"""A last waypoint this close to home (horizontally) is the mission's way home [m]."""
MIN_SPEED_MPS = 0.01
"""Slowest commanded speed accepted [m/s]: slower is a slip of units, not a mission (a
kilometre would take a day)."""
ROUTE_COLUMNS = ("x_m", "y_m", "z_m", "speed_mps", "stay_s", "corner_radius_m")
"""Route CSV columns (the first two required)."""
QGC_SUFFIXES = (".plan",)
CSV_SUFFIXES = (".csv",)
GEOJSON_SUFFIXES = (".geojson", ".json")


@dataclass(frozen=True)
class MissionWaypoint:
    """One waypoint of a mission in the map frame.

    Attributes
    ----------
    x_m, y_m : position (x east, y north) [m]
    z_m : altitude above home (negative: below home), or above the ground there when
        ``above_terrain`` [m] (aerial robots; ground and marine robots follow the terrain)
    speed_mps : commanded speed of the leg LEAVING this waypoint [m/s]; None: the robot's
        default for the leg's kind (cruise, climb, descent)
    stay_s : hold (hover) time at the waypoint [s]
    corner_radius_m : how the robot turns here: None stops at the waypoint (a "normal" mission
        without corner radius); r >= 0 turns on the arc tangent to both legs that starts r
        before the waypoint, at the speed a lateral acceleration of ``accel_max`` allows on it;
        inf passes the waypoint without slowing (a plan's tour vertex, as the plan models it)
    above_terrain : ``z_m`` is above the ground at the waypoint (a terrain-frame item), not
        above home
    """

    x_m: float
    y_m: float
    z_m: float = 0.0
    speed_mps: float | None = None
    stay_s: float = 0.0
    corner_radius_m: float | None = None
    above_terrain: bool = False


@dataclass(frozen=True)
class Mission:
    """A mission: waypoints in the map frame, waypoints[0] the home (take-off point).

    Attributes
    ----------
    waypoints : the waypoints in order, the first one home
    takeoff_alt_m : aerial: altitude of the vertical climb at home before the first leg [m];
        None: waypoints[0].z_m
    returns_home : the mission ends with the way home (RTL, or a last leg to home); False: it
        ends (lands) at its last waypoint
    source : where it came from (for messages)

    Raises
    ------
    InputError
        Fewer than two waypoints, a non-finite value, an altitude below the terrain it is
        measured from, a speed <= 0, a negative hold time or corner radius (naming the
        waypoint).
    """

    waypoints: tuple[MissionWaypoint, ...]
    takeoff_alt_m: float | None = None
    returns_home: bool = True
    source: str = "mission"

    def __post_init__(self):
        object.__setattr__(self, "waypoints", tuple(self.waypoints))
        if len(self.waypoints) < 2:
            raise InputError(f"{self.source}: a mission needs home and at least one waypoint, "
                             f"got {len(self.waypoints)} point(s)")
        for i, wp in enumerate(self.waypoints):
            _check_waypoint(wp, f"{self.source}: waypoint {i}")
        if self.takeoff_alt_m is not None and not (
                math.isfinite(self.takeoff_alt_m) and self.takeoff_alt_m >= 0):
            raise InputError(f"{self.source}: take-off altitude {self.takeoff_alt_m!r} must be "
                             "a finite number >= 0 m above home")

    def turning_without_slowing(self) -> Mission:
        """The same mission with every waypoint but the last passed without slowing (corner
        radius inf): the motion a plan's tour is modelled with."""
        wps = self.waypoints
        passed = [replace(w, corner_radius_m=math.inf) for w in wps[:-1]]
        return replace(self, waypoints=(*passed, wps[-1]))

    def above_home(self, ground_m) -> Mission:
        """The same mission with every altitude above home: a terrain-relative one plus
        ``ground_m(x, y)``, the ground's height above home there [m] (arrays in and out)."""
        on_terrain = [i for i, w in enumerate(self.waypoints) if w.above_terrain]
        if not on_terrain:
            return self
        wps = list(self.waypoints)
        x = np.array([wps[i].x_m for i in on_terrain], float)
        y = np.array([wps[i].y_m for i in on_terrain], float)
        for i, g in zip(on_terrain, np.atleast_1d(ground_m(x, y))):
            wps[i] = replace(wps[i], z_m=wps[i].z_m + float(g), above_terrain=False)
        return replace(self, waypoints=tuple(wps))

    @property
    def xyz_m(self) -> np.ndarray:
        """Waypoint positions, shape (n, 3) [m] (z as given: see ``above_home``)."""
        return np.array([(w.x_m, w.y_m, w.z_m) for w in self.waypoints], float)


def _check_waypoint(wp: MissionWaypoint, where: str) -> None:
    for name in ("x_m", "y_m", "z_m", "stay_s"):
        value = getattr(wp, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise InputError(f"{where}: {name} = {value!r} is not a finite number")
    if wp.above_terrain and wp.z_m < 0:
        raise InputError(f"{where}: altitude {wp.z_m:g} m above the terrain is below the ground")
    if wp.stay_s < 0:
        raise InputError(f"{where}: hold time {wp.stay_s:g} s must be >= 0")
    if wp.speed_mps is not None and not (math.isfinite(wp.speed_mps)
                                         and wp.speed_mps >= MIN_SPEED_MPS):
        raise InputError(f"{where}: speed {wp.speed_mps!r} m/s must be >= {MIN_SPEED_MPS:g} "
                         "(m/s)")
    if wp.corner_radius_m is not None and not wp.corner_radius_m >= 0:  # inf: no slowing
        raise InputError(f"{where}: corner radius {wp.corner_radius_m!r} m must be >= 0")


# --- reading ----------------------------------------------------------------------------------


def read_mission(path: str | Path, origin=None,
                 acceptance_radius_m: float = DEFAULT_ACCEPTANCE_RADIUS_M) -> Mission:
    """Read any supported mission file into the map frame.

    Parameters
    ----------
    path : a ``.plan``, a QGC WPL 110 text file (any name), a route ``.csv``, a GeoJSON
        LineString in longitude/latitude or a plan GeoJSON of ``orange-plan plan``
    origin : the map's WGS84 origin (``lat_deg``, ``lon_deg``, ``alt_m``), None: a local
        frame at the mission's home
    acceptance_radius_m : the autopilot's default acceptance radius for MAVLink waypoints that
        give none [m]

    Raises
    ------
    InputError
        One line naming the file and the item or row at fault.
    """
    path = Path(path)
    require_file(path, "mission")
    suffix = path.suffix.lower()
    if suffix in CSV_SUFFIXES:
        return read_route_csv(path)
    if suffix in GEOJSON_SUFFIXES:
        return read_geojson(path, origin)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text mission file") from None
    if text.startswith("QGC WPL"):
        home, items = _wpl_items(text, path)
    elif suffix in QGC_SUFFIXES:
        home, items = _plan_items(text, path)
    else:
        raise InputError(f"{path}: not a mission file check reads (a .plan, a 'QGC WPL 110' "
                         "text file, a route .csv or a .geojson)")
    return mission_from_items(home, items, origin, str(path), acceptance_radius_m)


def _plan_items(text: str, path: Path) -> tuple[tuple, list[MissionItem]]:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    mission = data.get("mission") if isinstance(data, dict) else None
    if not isinstance(mission, dict):
        raise InputError(f"{path}: no 'mission' object (a QGroundControl .plan has one)")
    home = mission.get("plannedHomePosition")
    if not (isinstance(home, list) and len(home) == 3):
        raise InputError(f"{path}: missing home: the mission has no plannedHomePosition "
                         "[lat, lon, alt]")
    items = []
    for k, it in enumerate(mission.get("items") or []):
        where = f"{path}: item {k + 1}"
        if not isinstance(it, dict):
            raise InputError(f"{where}: not an object")
        if it.get("type", "SimpleItem") != "SimpleItem":
            raise InputError(f"{where}: a {it.get('complexItemType', it.get('type'))!r} complex "
                             "item; save the mission with its waypoints as simple items")
        params = it.get("params")
        if not (isinstance(params, list) and len(params) == 7):
            raise InputError(f"{where}: params must be a list of 7 numbers or nulls")
        items.append(MissionItem(_int(it.get("command"), where, "command"),
                                 _int(it.get("frame"), where, "frame"),
                                 tuple(_number(p, where) for p in params)))
    home = tuple(_number(v, f"{path}: plannedHomePosition") for v in home)
    cruise = mission.get("hoverSpeed" if mission.get("vehicleType") == 2 else "cruiseSpeed")
    if isinstance(cruise, (int, float)) and math.isfinite(cruise) and cruise > 0:
        items.insert(0, MissionItem(DO_CHANGE_SPEED, 2, (1.0, float(cruise), -1.0, 0, 0, 0, 0)))
    return home, items


def _wpl_items(text: str, path: Path) -> tuple[tuple, list[MissionItem]]:
    rows = [line.split("\t") if "\t" in line else line.split()
            for line in text.splitlines()[1:] if line.strip()]
    if not rows:
        raise InputError(f"{path}: missing home: a QGC WPL file's first row (index 0) is home")
    for n, r in enumerate(rows, start=2):
        if len(r) != 12:
            raise InputError(f"{path}: line {n} has {len(r)} fields, a QGC WPL 110 row has 12")
    home = tuple(_number(v, f"{path}: line 2 (home)") for v in rows[0][8:11])
    items = [MissionItem(_int(r[3], f"{path}: line {n}", "command"),
                         _int(r[2], f"{path}: line {n}", "frame"),
                         tuple(_number(v, f"{path}: line {n}") for v in r[4:11]))
             for n, r in enumerate(rows[1:], start=3)]
    return home, items


def _int(value, where: str, name: str) -> int:
    try:
        out = int(value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {name} {value!r} is not an integer") from None
    if isinstance(value, float) and value != out:
        raise InputError(f"{where}: {name} {value!r} is not an integer")
    return out


def _number(value, where: str) -> float:
    if value is None:
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {value!r} is not a number") from None


def _check_count(n: int, source: str, what: str) -> None:
    """Refuse more than ``MAX_MISSION_WAYPOINTS`` items before building them."""
    if n > MAX_MISSION_WAYPOINTS:
        raise InputError(f"{source}: {n:,} {what}, more than the {MAX_MISSION_WAYPOINTS:,} "
                         "waypoints a check takes")


def mission_from_items(home, items, origin, source: str,
                       acceptance_radius_m: float = DEFAULT_ACCEPTANCE_RADIUS_M) -> Mission:
    """A Mission from MAVLink items (module docstring): ``home`` = (lat, lon, alt AMSL)."""
    _check_count(len(items), source, "mission items")
    home_lat, home_lon, home_alt = home
    if not all(math.isfinite(v) for v in home) or abs(home_lat) > 90 or abs(home_lon) > 180:
        raise InputError(f"{source}: missing home: home position {tuple(home)} is not a valid "
                         "latitude/longitude/altitude")
    frame_origin = origin or SimpleNamespace(lat_deg=home_lat, lon_deg=home_lon, alt_m=home_alt)
    hx, hy = (float(v) for v in latlon_to_xy(frame_origin, home_lat, home_lon))
    placed = _placed(items, frame_origin, source)
    points = [MissionWaypoint(hx, hy, 0.0)]
    speed, takeoff, returns, landed = None, None, False, False
    for k, it in enumerate(items, start=1):
        where = f"{source}: item {k}"
        if landed:
            if it.command in PASSIVE_COMMANDS or it.command == DO_CHANGE_SPEED:
                continue
            raise InputError(f"{where}: command {it.command} after the mission's end "
                             "(return-to-launch or landing)")
        if it.command == DO_CHANGE_SPEED:
            if it.params[1] > 0:
                speed = it.params[1]
                points[-1] = replace(points[-1], speed_mps=speed)
        elif it.command == NAV_TAKEOFF:  # at home: above the terrain there is above home
            takeoff, _ = _altitude(it, home_alt, where)
        elif it.command in (NAV_WAYPOINT, NAV_LOITER_TIME):
            (x, y), (z, on_terrain) = placed[k], _altitude(it, home_alt, where)
            hold = it.params[0] if np.isfinite(it.params[0]) else 0.0
            radius = it.params[1] if it.command == NAV_WAYPOINT else 0.0
            radius = radius if np.isfinite(radius) and radius > 0 else acceptance_radius_m
            points[-1] = replace(points[-1], speed_mps=speed)
            points.append(MissionWaypoint(x, y, z, speed, max(hold, 0.0), radius, on_terrain))
        elif it.command == NAV_RETURN_TO_LAUNCH:
            returns = landed = True
        elif it.command == NAV_LAND:
            if np.isfinite(it.params[4]) and np.isfinite(it.params[5]) and (
                    it.params[4], it.params[5]) != (0.0, 0.0):
                x, y = placed[k]
                last = points[-1]
                points.append(MissionWaypoint(x, y, last.z_m, speed, 0.0, None,
                                              last.above_terrain))
            landed = True
        elif it.command not in PASSIVE_COMMANDS:
            raise InputError(f"{where}: unknown or unsupported MAV_CMD {it.command} (check reads "
                             "waypoints, take-off, loiter-time, speed changes, return-to-launch, "
                             "landing and camera/gimbal commands)")
    if len(points) < 2:
        raise InputError(f"{source}: the mission has no waypoint (NAV_WAYPOINT items)")
    points[-1] = replace(points[-1], corner_radius_m=None)  # the end is a stop
    at_home = math.hypot(points[-1].x_m - hx, points[-1].y_m - hy) <= HOME_MATCH_M
    return Mission(tuple(points), takeoff, returns or at_home, source)


def _altitude(it: MissionItem, home_alt: float, where: str) -> tuple[float, bool]:
    """(altitude [m], whether it is above the terrain rather than above home) of an item."""
    alt = it.params[6]
    if not math.isfinite(alt):
        raise InputError(f"{where}: altitude is not a number")
    if it.frame in RELATIVE_FRAMES:
        return float(alt), False
    if it.frame in GLOBAL_FRAMES:
        return float(alt - home_alt), False
    if it.frame in TERRAIN_FRAMES:
        if alt < 0:
            raise InputError(f"{where}: altitude {alt:g} m above the terrain is below the "
                             "ground")
        return float(alt), True
    raise InputError(f"{where}: frame {it.frame} is not supported (use altitudes above home, "
                     "frame 3, above mean sea level, frame 0, or above the terrain, frame 10)")


def _placed(items, origin, source: str) -> dict[int, tuple[float, float]]:
    """Map-frame (x, y) of every item with a position (1-based item number -> [m]), in one
    conversion; a waypoint's latitude/longitude that is not a number is refused."""
    numbers, lat, lon = [], [], []
    for k, it in enumerate(items, start=1):
        if it.command in (NAV_WAYPOINT, NAV_LOITER_TIME) or (
                it.command == NAV_LAND and (it.params[4], it.params[5]) != (0.0, 0.0)
                and np.isfinite(it.params[4]) and np.isfinite(it.params[5])):
            a, b = it.params[4], it.params[5]
            if not (math.isfinite(a) and math.isfinite(b)):
                raise InputError(f"{source}: item {k}: latitude/longitude ({a}, {b}) is not a "
                                 "number")
            if abs(a) > 90 or abs(b) > 180:
                raise InputError(f"{source}: item {k}: latitude/longitude ({a}, {b}) is out "
                                 "of range")
            numbers.append(k)
            lat.append(a)
            lon.append(b)
    if not numbers:
        return {}
    x, y = latlon_to_xy(origin, np.array(lat), np.array(lon))
    return {k: (float(a), float(b)) for k, a, b in zip(numbers, np.atleast_1d(x),
                                                         np.atleast_1d(y))}


# --- map-frame and GeoJSON missions -------------------------------------------------------------


def read_route_columns(path: Path, optional: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The columns of a route CSV as float arrays: ``x_m``, ``y_m`` (required) and each of
    ``optional`` (all NaN where the file lacks it). The one reader of route CSV files, for
    ``check`` and ``simulate`` alike."""
    import pandas as pd

    try:
        frame = pd.read_csv(path)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable CSV ({exc})") from None
    missing = [c for c in ("x_m", "y_m") if c not in frame.columns]
    if missing:
        wanted = "".join(f", {c}" for c in optional)
        raise InputError(f"{path}: route CSV lacks column(s) {missing} (need x_m, y_m"
                         f"{'[' + wanted + ']' if wanted else ''})"
                         + csv_delimiter_hint(frame.columns))
    try:
        return {c: frame[c].to_numpy(dtype=float) if c in frame else np.full(len(frame), np.nan)
                for c in ("x_m", "y_m", *optional)}
    except ValueError:
        raise InputError(f"{path}: route columns must hold numbers") from None


def read_route_csv(path: Path) -> Mission:
    """A route CSV (``ROUTE_COLUMNS``): the first row is home; a route that does not end at
    home gets the way home added (``returns_home``)."""
    cols = read_route_columns(path, tuple(c for c in ROUTE_COLUMNS if c not in ("x_m", "y_m")))
    _check_count(len(cols["x_m"]), str(path), "rows")
    for c in ("x_m", "y_m"):
        bad = np.flatnonzero(~np.isfinite(cols[c]))
        if bad.size:
            raise InputError(f"{path}: row {bad[0] + 1}: {c} is not a number")
    points = []
    for i in range(len(cols["x_m"])):
        def opt(name, i=i):
            v = cols[name][i]
            return None if np.isnan(v) else float(v)
        points.append(_row_waypoint(opt, f"{path}: row {i + 1}"))
    points[-1] = replace(points[-1], corner_radius_m=None)
    return Mission(tuple(points), None, True, str(path))


def _row_waypoint(opt, where: str) -> MissionWaypoint:
    speed = opt("speed_mps")
    wp = MissionWaypoint(opt("x_m"), opt("y_m"), opt("z_m") or 0.0,
                         None if speed is None or speed == 0 else speed,
                         opt("stay_s") or 0.0, opt("corner_radius_m"))
    _check_waypoint(wp, where)
    return wp


def read_geojson(path: Path, origin) -> Mission:
    """A plan GeoJSON (its tour, in the map frame, at its speeds, flown through its vertices
    without stopping, as the plan models it) or a GeoJSON LineString in longitude/latitude
    [, altitude above home] (RFC 7946), a normal mission (stops at each vertex)."""
    data = read_json(path, "mission GeoJSON")
    features = data.get("features") if isinstance(data, dict) else None
    tours = [f for f in features or [] if isinstance(f, dict)
             and (f.get("properties") or {}).get("kind") == "tour"]
    if tours:
        return _plan_tour(tours[0], path)
    geom = data
    if isinstance(data, dict) and data.get("type") == "FeatureCollection":
        lines = [f.get("geometry") for f in features or [] if isinstance(f, dict)
                 and (f.get("geometry") or {}).get("type") == "LineString"]
        geom = lines[0] if lines else {}
    elif isinstance(data, dict) and data.get("type") == "Feature":
        geom = data.get("geometry") or {}
    if not isinstance(geom, dict) or geom.get("type") != "LineString":
        raise InputError(f"{path}: no LineString (a mission GeoJSON is a LineString in "
                         "longitude/latitude, or a plan with a tour)")
    _check_count(len(geom.get("coordinates") or []), str(path), "positions")
    coords = _coords(geom, path)
    if coords.shape[1] < 2 or len(coords) < 2:
        raise InputError(f"{path}: the LineString needs at least two [lon, lat] positions")
    lon, lat = coords[:, 0], coords[:, 1]
    bad = np.flatnonzero(~(np.isfinite(lat) & np.isfinite(lon)))
    if bad.size:
        raise InputError(f"{path}: position {bad[0]}: longitude/latitude is not a number")
    if np.any(np.abs(lat) > 90) or np.any(np.abs(lon) > 180):
        raise InputError(f"{path}: a position lies outside longitude [-180, 180] / latitude "
                         "[-90, 90]: is the LineString in map metres rather than degrees?")
    frame = origin or SimpleNamespace(lat_deg=float(lat[0]), lon_deg=float(lon[0]), alt_m=0.0)
    x, y = latlon_to_xy(frame, lat, lon)
    z = coords[:, 2] if coords.shape[1] > 2 else np.zeros(len(coords))
    points = [MissionWaypoint(float(a), float(b), float(c)) for a, b, c in zip(x, y, z)]
    for i, wp in enumerate(points):
        _check_waypoint(wp, f"{path}: position {i}")
    return Mission(tuple(points), None, True, str(path))


def _coords(geom: dict, path: Path) -> np.ndarray:
    try:
        rows = [[math.nan if v is None else float(v) for v in c] for c in geom.get("coordinates")]
        width = min(len(r) for r in rows) if rows else 2
        return np.array([r[:width] for r in rows], float).reshape(len(rows), width)
    except (TypeError, ValueError):
        raise InputError(f"{path}: LineString coordinates must be numbers") from None


def _plan_tour(tour: dict, path: Path) -> Mission:
    geom = tour.get("geometry") or {}
    if geom.get("type") != "LineString":
        raise InputError(f"{path}: the tour must be a LineString, got {geom.get('type')!r}")
    _check_count(len(geom.get("coordinates") or []), str(path), "tour vertices")
    xy = _coords(geom, path)[:, :2]
    if len(xy) < 2 or not np.all(np.isfinite(xy)):
        raise InputError(f"{path}: the tour needs at least two finite (x, y) vertices")
    speed = (tour.get("properties") or {}).get("speed_mps")
    speed = np.full(len(xy), np.nan) if speed is None else np.asarray(speed, float)
    if speed.shape != (len(xy),):
        raise InputError(f"{path}: tour speed_mps has {speed.size} values for {len(xy)} vertices")
    keep = np.r_[True, np.hypot(*np.diff(xy, axis=0).T) > 1e-9]
    xy, speed = xy[keep], speed[keep]
    points = [MissionWaypoint(float(x), float(y), 0.0,
                              float(v) if np.isfinite(v) and v > 0 else None, 0.0, math.inf)
              for (x, y), v in zip(xy, speed)]
    points[-1] = replace(points[-1], corner_radius_m=None)
    return Mission(tuple(points), None, True, str(path))
