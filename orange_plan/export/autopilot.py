"""Plans out to the autopilots people already use: QGroundControl ``.plan`` and MAVLink
waypoint files (QGC WPL 110), in latitude/longitude.

Problem statement (kept apart from how it is solved): a plan is a tour in the map's local
metric frame (x east, y north) with a commanded speed per segment. An autopilot mission is a
list of MAVLink items in WGS84: waypoints (``MAV_CMD_NAV_WAYPOINT`` = 16), speed changes
(``MAV_CMD_DO_CHANGE_SPEED`` = 178), a take-off for aircraft (``MAV_CMD_NAV_TAKEOFF`` = 22)
and the end of the mission (``MAV_CMD_NAV_RETURN_TO_LAUNCH`` = 20). The exported mission must
drive the same path at the same speeds: every tour vertex within ``TOLERANCE_M`` of the
waypoint polyline, every segment's commanded speed within ``SPEED_STEP_MPS`` of the plan's.

How it is solved:

1. Local east-north-up <-> WGS84, exactly on the ellipsoid (no pyproj needed): a map point
   (x, y) is the point (e, n, u) = (x, y, 0) of the tangent plane at the map's ``origin``
   (lat0, lon0, h0); with ``N(lat) = a / sqrt(1 - e^2 sin^2 lat)``,

       ECEF(lat, lon, h) = ((N + h) cos lat cos lon, (N + h) cos lat sin lon, (N (1 - e^2) + h) sin lat)
       ECEF = ECEF(lat0, lon0, h0) + R' (e, n, u),
       R = [[-sin lon0, cos lon0, 0],
            [-sin lat0 cos lon0, -sin lat0 sin lon0, cos lat0],
            [ cos lat0 cos lon0,  cos lat0 sin lon0, sin lat0]]

   and ECEF -> (lat, lon, h) by fixed-point iteration on the latitude (converges to well
   below a micrometre in a few steps for any height near the surface). The inverse of a
   (lat, lon) is the tangent-plane point with that latitude/longitude, found by correcting
   (e, n) with the forward map until it agrees (two or three steps): a round trip is exact
   to round-off, not the 0.1 m the files need.
2. Waypoints: the tour's vertices, decimated. A vertex is kept where the commanded speed
   changes by more than ``SPEED_STEP_MPS`` from the speed last commanded or the heading
   turns by more than ``TURN_DEG``; between kept vertices, Douglas-Peucker keeps any vertex
   farther than ``TOLERANCE_M / 2`` from the chord. So every dropped vertex lies within
   ``TOLERANCE_M`` of the waypoint polyline, and every waypoint is a tour vertex.
3. Items: [take-off (aerial)], speed change, waypoints with a speed change before the
   waypoint that starts a segment of another speed, then return-to-launch. The tour's own
   way home is kept as waypoints (a straight RTL could cross an obstacle); RTL only ends the
   mission at home.

Why the files are safe to fly: positions are exact conversions of the plan's vertices (the
read-back test holds them to 0.1 m on a 2 km map), the path between waypoints is the plan's
within 0.1 m, and speeds are the plan's within ``SPEED_STEP_MPS``, so the planned energy
and homing margins still describe the flown mission. A map without an ``origin`` is refused:
metres cannot be placed on the Earth without it.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from orange_plan.atomic import atomic_path
from orange_plan.errors import InputError

WGS84_A_M = 6378137.0
"""WGS84 semi-major axis [m]."""
WGS84_F = 1.0 / 298.257223563
"""WGS84 flattening [-]."""
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
"""First eccentricity squared [-]."""

TOLERANCE_M = 0.1
"""Largest distance of a tour vertex from the exported waypoint polyline [m]."""
TURN_DEG = 3.0
"""Heading change above which a vertex is always a waypoint [deg]."""
SPEED_STEP_MPS = 0.01
"""A speed change smaller than this is not commanded (autopilot speed resolution) [m/s]."""

NAV_WAYPOINT, NAV_RETURN_TO_LAUNCH, NAV_TAKEOFF, DO_CHANGE_SPEED = 16, 20, 22, 178
FRAME_GLOBAL, FRAME_MISSION, FRAME_GLOBAL_RELATIVE_ALT = 0, 2, 3
SPEED_TYPE_GROUND = 1
"""DO_CHANGE_SPEED param1: 0 airspeed, 1 ground speed (the plan's speeds are ground speeds)."""
MAX_ALTITUDE_M = 10_000.0
"""Highest flight altitude above home accepted [m]: above the ceiling of any battery
aircraft, so a larger number is a slip (feet, millimetres), not a mission."""
VEHICLE_TYPES = {"ground": 10, "aerial": 2, "marine": 11}
"""MAV_TYPE per robot kind: ground rover, quadrotor, surface boat."""
FIRMWARE_TYPES = {"px4": 12, "ardupilot": 3}
"""MAV_AUTOPILOT: PX4, ArduPilotMega."""
FORMATS = {"qgc": (".plan",), "mavlink": (".waypoints", ".txt", ".mission")}
"""Export formats and the file name endings the ground stations open."""


def check_firmware(firmware: str, option: str = "firmware") -> None:
    """Raise InputError naming ``option`` unless ``firmware`` is one of ``FIRMWARE_TYPES``."""
    if firmware not in FIRMWARE_TYPES:
        raise InputError(f"{option} {firmware!r} must be one of {', '.join(FIRMWARE_TYPES)}")


# --- local ENU <-> WGS84 --------------------------------------------------------------------


def _ecef(lat_deg, lon_deg, h_m):
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    return np.stack([(n + h_m) * np.cos(lat) * np.cos(lon), (n + h_m) * np.cos(lat) * np.sin(lon),
                     (n * (1.0 - WGS84_E2) + h_m) * np.sin(lat)], axis=-1)


def _rotation(origin) -> np.ndarray:
    """ECEF -> ENU rotation at the origin (rows: east, north, up unit vectors)."""
    lat, lon = math.radians(origin.lat_deg), math.radians(origin.lon_deg)
    sl, cl, sp, cp = math.sin(lon), math.cos(lon), math.sin(lat), math.cos(lat)
    return np.array([[-sl, cl, 0.0], [-sp * cl, -sp * sl, cp], [cp * cl, cp * sl, sp]])


def _geodetic(xyz):
    """ECEF [m] -> (lat [deg], lon [deg], h [m]) by fixed-point iteration on the latitude."""
    x, y, z = xyz[..., 0], xyz[..., 1], xyz[..., 2]
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - WGS84_E2))
    for _ in range(8):  # each step gains ~3 orders of magnitude near the surface
        n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
        h = p * np.cos(lat) + z * np.sin(lat) - WGS84_A_M * np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    h = p * np.cos(lat) + z * np.sin(lat) - WGS84_A_M * np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    return np.degrees(lat), np.degrees(np.arctan2(y, x)), h


def enu_to_geodetic(origin, east_m, north_m, up_m=0.0):
    """Local east-north-up [m] -> WGS84 (lat [deg], lon [deg], ellipsoidal height [m]).

    Parameters
    ----------
    origin : object with ``lat_deg``, ``lon_deg``, ``alt_m`` (the map's origin: docs/formats.md, Map)
    east_m, north_m, up_m : tangent-plane coordinates (any broadcastable shapes) [m]

    Notes
    -----
    ``ECEF = ECEF(origin) + R' (e, n, u)`` (module docstring), then ECEF -> geodetic.
    """
    enu = np.stack(np.broadcast_arrays(np.asarray(east_m, float), np.asarray(north_m, float),
                                       np.asarray(up_m, float)), axis=-1)
    xyz = _ecef(origin.lat_deg, origin.lon_deg, origin.alt_m) + enu @ _rotation(origin)
    return _geodetic(xyz)


def geodetic_to_enu(origin, lat_deg, lon_deg, h_m):
    """WGS84 (lat [deg], lon [deg], height [m]) -> local (east, north, up) [m] (exact)."""
    d = _ecef(np.asarray(lat_deg, float), np.asarray(lon_deg, float), np.asarray(h_m, float))
    enu = (d - _ecef(origin.lat_deg, origin.lon_deg, origin.alt_m)) @ _rotation(origin).T
    return enu[..., 0], enu[..., 1], enu[..., 2]


def latlon_to_xy(origin, lat_deg, lon_deg):
    """The map point (x, y) [m] whose tangent-plane point has this latitude/longitude.

    Inverse of ``enu_to_geodetic(origin, x, y, 0)[:2]``: the tangent plane lies below the
    ellipsoid away from the origin (x^2 / 2R: 0.3 m at 2 km), so a first guess at the
    origin's height is corrected by the forward map until both agree.
    """
    lat, lon = np.asarray(lat_deg, float), np.asarray(lon_deg, float)
    x, y, _ = geodetic_to_enu(origin, lat, lon, origin.alt_m)
    for _ in range(3):
        back_lat, back_lon, back_h = enu_to_geodetic(origin, x, y, 0.0)
        bx, by, _ = geodetic_to_enu(origin, back_lat, back_lon, back_h)
        gx, gy, _ = geodetic_to_enu(origin, lat, lon, back_h)
        x, y = x + (gx - bx), y + (gy - by)
    return x, y


# --- waypoints --------------------------------------------------------------------------------


def waypoint_indices(xy_m, speed_mps, tolerance_m: float = TOLERANCE_M,
                     turn_deg: float = TURN_DEG) -> np.ndarray:
    """Tour vertices kept as waypoints (sorted indices, first and last included).

    Parameters
    ----------
    xy_m : tour vertices (n, 2) [m]
    speed_mps : speed on the segment leaving each vertex (n,) [m/s]
    tolerance_m : largest distance of a dropped vertex from the waypoint polyline [m]
    turn_deg : a heading change larger than this keeps the vertex [deg]

    Notes
    -----
    Kept: the ends; a vertex whose leaving speed differs from the speed last commanded by
    more than ``SPEED_STEP_MPS``; a vertex where the heading turns by more than
    ``turn_deg``; then Douglas-Peucker at ``tolerance_m / 2`` between kept vertices.
    """
    xy = np.asarray(xy_m, float)
    v = np.asarray(speed_mps, float)
    n = len(xy)
    keep = np.zeros(n, bool)
    keep[[0, n - 1]] = True
    commanded = v[0]
    for i in range(1, n - 1):
        if abs(v[i] - commanded) > SPEED_STEP_MPS:
            keep[i], commanded = True, v[i]
    d = np.diff(xy, axis=0)
    heading = np.arctan2(d[:, 1], d[:, 0])
    moving = np.hypot(*d.T) > 1e-9
    turn = np.abs(np.angle(np.exp(1j * (heading[1:] - heading[:-1]))))
    keep[1:-1] |= (turn > math.radians(turn_deg)) & moving[1:] & moving[:-1]
    kept = np.flatnonzero(keep)
    for a, b in itertools.pairwise(kept):
        _douglas_peucker(xy, int(a), int(b), 0.5 * tolerance_m, keep)
    return np.flatnonzero(keep)


def _douglas_peucker(xy, a: int, b: int, tol: float, keep) -> None:
    stack = [(a, b)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            continue
        dist = _distance_to_segment(xy[i + 1:j], xy[i], xy[j])
        k = int(np.argmax(dist))
        if dist[k] > tol:
            keep[i + 1 + k] = True
            stack += [(i, i + 1 + k), (i + 1 + k, j)]


def _distance_to_segment(p, a, b) -> np.ndarray:
    ab = b - a
    length2 = float(ab @ ab)
    t = np.zeros(len(p)) if length2 == 0 else np.clip((p - a) @ ab / length2, 0.0, 1.0)
    return np.hypot(*(p - (a + t[:, None] * ab)).T)


# --- the mission ------------------------------------------------------------------------------


@dataclass(frozen=True)
class MissionItem:
    """One MAVLink mission item (MISSION_ITEM fields; lat/lon in params 5 and 6).

    Attributes
    ----------
    command : MAV_CMD id
    frame : MAV_FRAME id
    params : param1..param7 (NaN: "unchanged", written as null in a .plan)
    """

    command: int
    frame: int
    params: tuple


@dataclass(frozen=True)
class AutopilotMission:
    """A plan as autopilot items, with the home the ground station shows.

    Attributes
    ----------
    home_lat_deg, home_lon_deg, home_alt_m : home (altitude: the origin's, AMSL) [deg], [m]
    items : mission items after home
    vehicle_type, firmware_type : MAV_TYPE and MAV_AUTOPILOT ids
    cruise_speed_mps : the tour's median commanded speed [m/s]
    waypoints_xy_m : the kept tour vertices in the map frame [m]
    fence_inclusion, fence_exclusion : geofence polygons as (lat, lon) rings [deg]
    """

    home_lat_deg: float
    home_lon_deg: float
    home_alt_m: float
    items: tuple
    vehicle_type: int
    firmware_type: int
    cruise_speed_mps: float
    waypoints_xy_m: np.ndarray
    fence_inclusion: tuple = ()
    fence_exclusion: tuple = ()


def build_mission(world, kind: str, xy_m, speed_mps, altitude_m: float | None = None,
                  firmware: str = "px4", source: str = "tour") -> AutopilotMission:
    """The autopilot mission of a tour (module docstring, steps 2 and 3).

    Parameters
    ----------
    world : World whose map has an ``origin``
    kind : robot kind ("ground", "aerial", "marine")
    xy_m, speed_mps : tour vertices (n, 2) [m] and speed leaving each vertex (n,) [m/s]
    altitude_m : flight altitude above home [m]; required for aerial robots, else 0
    firmware : "px4" or "ardupilot"
    source : where the tour came from (its file), for messages

    Raises
    ------
    InputError
        Map without ``origin``, an aerial robot without an altitude in (0, MAX_ALTITUDE_M],
        an unknown firmware, a tour of fewer than two vertices, a tour that leaves the map's
        free space (a plan made on another map).
    """
    origin = getattr(world.map, "origin", None)
    if origin is None:
        raise InputError(f"{world.map.path}: the map has no 'origin' (the WGS84 point at "
                         "x = y = 0), so the plan cannot be placed in latitude/longitude; add "
                         '"origin": {"lat_deg": ..., "lon_deg": ..., "alt_m": ...} to the map')
    check_firmware(firmware)
    alt = _altitude(kind, altitude_m)
    xy = np.asarray(xy_m, float).reshape(-1, 2)
    v = np.asarray(speed_mps, float)
    if len(xy) < 2 or v.shape != (len(xy),):
        raise InputError("a tour needs at least two vertices and one speed per vertex")
    world.check_route(xy, source)
    keep = waypoint_indices(xy, v)
    lat, lon, _ = enu_to_geodetic(origin, xy[keep, 0], xy[keep, 1])
    home_lat, home_lon, _ = enu_to_geodetic(origin, *world.home_xy_m)
    items = []
    if kind == "aerial":
        items.append(MissionItem(NAV_TAKEOFF, FRAME_GLOBAL_RELATIVE_ALT,
                                 (0.0, 0.0, 0.0, math.nan, float(lat[0]), float(lon[0]), alt)))
    commanded = None
    for k in range(1, len(keep)):
        speed = float(v[keep[k - 1]])  # the segment arriving at waypoint k
        if commanded is None or abs(speed - commanded) > SPEED_STEP_MPS:
            items.append(MissionItem(DO_CHANGE_SPEED, FRAME_MISSION,
                                     (SPEED_TYPE_GROUND, speed, -1.0, 0.0, 0.0, 0.0, 0.0)))
            commanded = speed
        items.append(MissionItem(NAV_WAYPOINT, FRAME_GLOBAL_RELATIVE_ALT,
                                 (0.0, 0.0, 0.0, math.nan, float(lat[k]), float(lon[k]), alt)))
    items.append(MissionItem(NAV_RETURN_TO_LAUNCH, FRAME_MISSION, (0.0,) * 7))
    inclusion, exclusion = _fence(world, origin)
    return AutopilotMission(float(home_lat), float(home_lon), origin.alt_m, tuple(items),
                            VEHICLE_TYPES[kind], FIRMWARE_TYPES[firmware],
                            float(np.median(v[:-1])), xy[keep], inclusion, exclusion)


def _altitude(kind: str, altitude_m) -> float:
    if kind == "aerial":
        if altitude_m is None:
            raise InputError("an aerial robot needs its flight altitude above home: give "
                             f"--altitude-m (metres, > 0 and <= {MAX_ALTITUDE_M:g})")
        if not (math.isfinite(altitude_m) and 0 < altitude_m <= MAX_ALTITUDE_M):
            raise InputError(f"--altitude-m = {altitude_m!r}: the flight altitude above home "
                             f"must be > 0 and <= {MAX_ALTITUDE_M:g} m")
        return float(altitude_m)
    if altitude_m not in (None, 0, 0.0):
        raise InputError(f"--altitude-m = {altitude_m!r} applies to aerial robots only "
                         f"(this one is {kind})")
    return 0.0


def _fence(world, origin):
    """Boundary as the inclusion fence, obstacles and no-go zones as exclusions (lat, lon)."""
    def rings(geom):
        polys = getattr(geom, "geoms", [geom])
        out = []
        for p in polys:
            if p.is_empty:
                continue
            xy = np.asarray(p.exterior.coords)[:-1]  # QGC fences are open rings
            lat, lon, _ = enu_to_geodetic(origin, xy[:, 0], xy[:, 1])
            out.append(tuple(zip(lat.tolist(), lon.tolist())))
        return out

    m = world.true_map  # fences on the geometry as given: a breach means a real collision
    exclusion = [r for zone in (*m.obstacles, *m.no_go) for r in rings(zone)]
    return tuple(rings(m.boundary)), tuple(exclusion)


# --- files ------------------------------------------------------------------------------------


def qgc_plan(mission: AutopilotMission) -> dict:
    """The QGroundControl ``.plan`` JSON (file format version 1, mission version 2)."""
    items = [{"type": "SimpleItem", "command": it.command, "frame": it.frame,
              "params": [None if math.isnan(p) else p for p in it.params],
              "autoContinue": True, "doJumpId": k + 1}
             for k, it in enumerate(mission.items)]
    polygons = ([{"inclusion": True, "polygon": [list(p) for p in ring], "version": 1}
                 for ring in mission.fence_inclusion]
                + [{"inclusion": False, "polygon": [list(p) for p in ring], "version": 1}
                   for ring in mission.fence_exclusion])
    return {
        "fileType": "Plan",
        "version": 1,
        "groundStation": "orange-plan",
        "mission": {
            "version": 2,
            "firmwareType": mission.firmware_type,
            "vehicleType": mission.vehicle_type,
            "globalPlanAltitudeMode": 1,  # relative to home
            "cruiseSpeed": mission.cruise_speed_mps,
            "hoverSpeed": mission.cruise_speed_mps,
            "plannedHomePosition": [mission.home_lat_deg, mission.home_lon_deg,
                                    mission.home_alt_m],
            "items": items,
        },
        "geoFence": {"version": 2, "circles": [], "polygons": polygons},
        "rallyPoints": {"version": 2, "points": []},
    }


def wpl_text(mission: AutopilotMission) -> str:
    """The MAVLink plain-text mission (QGC WPL 110): tab-separated, line 0 = home (AMSL)."""
    rows = [(0, 1, FRAME_GLOBAL, NAV_WAYPOINT, 0.0, 0.0, 0.0, 0.0, mission.home_lat_deg,
             mission.home_lon_deg, mission.home_alt_m, 1)]
    for k, it in enumerate(mission.items, start=1):
        # A NaN param (the yaw: keep the heading) is written "nan", as QGroundControl writes
        # it in its own .waypoints files and reads it back (so do pymavlink and MAVProxy); a 0
        # would command "face north" on PX4, unlike the same mission's .plan (null).
        rows.append((k, 0, it.frame, it.command, *it.params, 1))
    lines = ["QGC WPL 110"]
    lines += ["\t".join(_wpl_field(x) for x in row) for row in rows]
    return "\n".join(lines) + "\n"


def _wpl_field(x) -> str:
    if isinstance(x, int):
        return str(x)
    return repr(float(x))  # shortest exact decimal (NaN: "nan"): positions keep every bit


def write_mission(mission: AutopilotMission, path: str | Path, fmt: str) -> Path:
    """Write the mission as ``fmt`` ("qgc" or "mavlink") atomically."""
    if fmt not in FORMATS:
        raise InputError(f"--format {fmt!r} must be one of {', '.join(FORMATS)}")
    path = Path(path)
    text = (json.dumps(qgc_plan(mission), indent=2, allow_nan=False) + "\n" if fmt == "qgc"
            else wpl_text(mission))
    with atomic_path(path, suffix=path.suffix or ".tmp") as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


def check_extension(path: Path, fmt: str) -> None:
    """Refuse a file name the ground station would not open for this format."""
    if fmt not in FORMATS:
        raise InputError(f"--format {fmt!r} must be one of {', '.join(FORMATS)}")
    if path.suffix.lower() not in FORMATS[fmt]:
        raise InputError(f"-o {path}: a {fmt} mission file name must end in "
                         f"{' or '.join(FORMATS[fmt])}")


def read_items(path: str | Path) -> tuple[tuple, list[MissionItem]]:
    """Read a ``.plan`` or WPL 110 file back: (home (lat, lon, alt), items after home).

    Meant for checks (the round-trip test, a user verifying a file); it reads what
    ``write_mission`` writes and what QGroundControl saves for simple missions.
    """
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    if text.startswith("QGC WPL"):
        rows = [line.split("\t") for line in text.splitlines()[1:] if line.strip()]
        home = tuple(float(v) for v in rows[0][8:11])
        items = [MissionItem(int(r[3]), int(r[2]), tuple(float(v) for v in r[4:11]))
                 for r in rows[1:]]
        return home, items
    data = json.loads(text)
    mission = data["mission"]
    items = [MissionItem(int(it["command"]), int(it["frame"]),
                         tuple(math.nan if p is None else float(p) for p in it["params"]))
             for it in mission["items"]]
    return tuple(float(v) for v in mission["plannedHomePosition"]), items
