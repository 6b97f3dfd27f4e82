"""``bench check``: how fast ``check`` answers on a long mission.

A lawnmower survey of ``n`` waypoints over the scenario's map (lanes across the boundary's
box, inset by a tenth; aerial robots at 20 m with a 2 m acceptance radius) is written as a
QGroundControl ``.plan`` in the map's latitude/longitude (a local frame at home without an
``origin``), then read and checked in-process ``repeats`` times (the median reported) and
once as the whole command in a fresh process (interpreter and imports included).
"""

from __future__ import annotations

import math
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from orange_plan.export.autopilot import (
    FIRMWARE_TYPES,
    FRAME_GLOBAL_RELATIVE_ALT,
    NAV_RETURN_TO_LAUNCH,
    NAV_TAKEOFF,
    NAV_WAYPOINT,
    VEHICLE_TYPES,
    AutopilotMission,
    MissionItem,
    enu_to_geodetic,
    write_mission,
)

TARGET_S = 2.0
"""A 500-waypoint mission is checked within this [s]."""
SURVEY_ALTITUDE_M = 20.0
ACCEPTANCE_RADIUS_M = 2.0


@dataclass(frozen=True)
class CheckBench:
    """Timings of ``check`` on one survey mission.

    Attributes
    ----------
    scenario : its name; waypoints : waypoints of the survey (home excluded)
    legs : stages checked; route_m : the route's length [m]
    read_s : reading the .plan (median) [s]; check_s : ``check_mission`` (median) [s]
    command_s : the whole ``orange-plan check --json`` in a fresh process, wall clock [s]
    command_cpu_s : its CPU time (user + system): what it costs on an idle machine [s]
    verdict : the check's verdict; energy_J : the mission's energy [J]
    repeats : in-process repeats; target_s : the target for ``read_s + check_s``
    """

    scenario: str
    waypoints: int
    legs: int
    route_m: float
    read_s: float
    check_s: float
    command_s: float
    command_cpu_s: float
    verdict: str
    energy_J: float
    repeats: int
    target_s: float = TARGET_S

    def to_dict(self) -> dict:
        return asdict(self)


def survey_xy(world, n: int) -> np.ndarray:
    """``n`` lawnmower waypoints (n, 2) over the map's boundary box, inset by a tenth [m]."""
    x0, y0, x1, y1 = world.true_map.boundary.bounds
    dx, dy = 0.1 * (x1 - x0), 0.1 * (y1 - y0)
    lanes = max(1, math.ceil(n / 2))
    y = np.linspace(y0 + dy, y1 - dy, lanes)
    xy = []
    for k, lane_y in enumerate(y):
        ends = (x0 + dx, x1 - dx) if k % 2 == 0 else (x1 - dx, x0 + dx)
        xy += [(ends[0], lane_y), (ends[1], lane_y)]
    return np.asarray(xy[:n], float)


def write_survey(ctx, n: int, path: Path) -> Path:
    """The survey as a QGroundControl .plan (module docstring)."""
    origin = getattr(ctx.world.map, "origin", None) or SimpleNamespace(
        lat_deg=0.0, lon_deg=0.0, alt_m=0.0)
    kind = ctx.scenario.robot.kind
    alt = SURVEY_ALTITUDE_M if kind == "aerial" else 0.0
    xy = survey_xy(ctx.world, n)
    lat, lon, _ = enu_to_geodetic(origin, xy[:, 0], xy[:, 1])
    home_lat, home_lon, _ = enu_to_geodetic(origin, *ctx.world.home_xy_m)
    items = [MissionItem(NAV_TAKEOFF, FRAME_GLOBAL_RELATIVE_ALT,
                         (0.0, 0.0, 0.0, math.nan, float(home_lat), float(home_lon), alt))
             ] if kind == "aerial" else []
    items += [MissionItem(NAV_WAYPOINT, FRAME_GLOBAL_RELATIVE_ALT,
                          (0.0, ACCEPTANCE_RADIUS_M, 0.0, math.nan, float(a), float(b), alt))
              for a, b in zip(lat, lon)]
    items.append(MissionItem(NAV_RETURN_TO_LAUNCH, 2, (0.0,) * 7))
    mission = AutopilotMission(float(home_lat), float(home_lon), origin.alt_m, tuple(items),
                               VEHICLE_TYPES[kind], FIRMWARE_TYPES["px4"],
                               ctx.cruise_speed_mps, xy)
    return write_mission(mission, path, "qgc")


def run_check_bench(scenario_path, n_waypoints: int = 500, repeats: int = 3) -> CheckBench:
    """Time ``check`` on an ``n_waypoints`` survey of the scenario's map (module docstring)."""
    from orange_plan.context import load_context
    from orange_plan.export.missions_in import read_mission
    from orange_plan.planning.mission_check import check_mission

    ctx = load_context(scenario_path)
    origin = getattr(ctx.world.map, "origin", None)
    with tempfile.TemporaryDirectory() as folder:
        path = write_survey(ctx, n_waypoints, Path(folder) / "survey.plan")
        check_mission(read_mission(path, origin), ctx, in_map_frame=origin is not None)  # warm
        reads, checks = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            mission = read_mission(path, origin)
            t1 = time.perf_counter()
            result = check_mission(mission, ctx, in_map_frame=origin is not None)
            reads.append(t1 - t0)
            checks.append(time.perf_counter() - t1)
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "orange_plan.cli", "check", str(path),
                        "--scenario", str(scenario_path), "--json"], check=True,
                       capture_output=True)
        command_s = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        command_cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return CheckBench(ctx.scenario.name, n_waypoints, len(result.legs),
                      float(result.legs[-1].distance_m), statistics.median(reads),
                      statistics.median(checks), command_s, command_cpu_s, result.verdict,
                      result.energy_J,
                      repeats)
