"""Boustrophedon cell decomposition: sweeps with an angle per cell, cell by cell.

Problem: a whole-map sweep drives every lane at one angle, so on a map whose parts run
different ways (an L, rooms off a corridor, the gaps between obstacles) most parts are swept
across their length, with many short lanes and turns; and lanes that an obstacle splits are
driven piece by piece across the whole map, with long transits between the pieces.

How it is solved (the boustrophedon decomposition of Choset and Pignon, as in Fields2Cover):
the free space the robot moves in (``World.map``: the map grown by the robot's size) is
turned so that the decomposition direction runs along x, and cut along that direction at its
critical points: the vertices where the line through a vertex is tangent to the boundary (an
obstacle begins or ends, a bay opens or closes: local extremes of a ring across the
direction) and the edges that run along it (a step of the boundary: the corner of an L).
Each cut runs from the critical point to the boundary on either side
(``_cut_segments``); the cut lines and the boundary are polygonized into cells. Cells
thinner than the sensor's radius or smaller than a few footprints are merged into the
neighbour they share most boundary with, and at most ``MAX_CELLS`` are kept (the smallest
merged first), so no map's size can make the decomposition large.

Each cell is swept on its own: lanes at most ``2 r`` apart (the sensor footprint's spacing of
``planning.coverage``), at the angle that needs the fewest lane pieces in that cell
(``coverage`` rule, every 5 deg: the cell's long direction for a rectangle), or at the
decomposition direction (the classic decomposition). Cells are joined in an order that keeps
transits short (``cell_orders``): the nearest cell next, or outward from home, or inward to
end near home; each cell is entered at the end of its lane set nearer the robot.
``planning.sweeps`` scores these routes beside the whole-map sweeps under the same homing
rule.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np
import shapely
from shapely import affinity

from orange_plan.planning.coverage import (
    LANE_CLEARANCE_FRACTION,
    MIN_LANE_FRACTION,
    _best_angle,
    _clip_lines,
    _directions,
    _lane_offsets,
    _ring_edges,
)
from orange_plan.planning.lawnmower import ordered_pieces

MAX_CELLS = 48
"""Most cells kept from one decomposition: smaller ones are merged into their neighbours
until this many are left (bounds the cells' lanes and orders whatever the map)."""

MIN_CELL_FOOTPRINTS = 4.0
"""A cell smaller than this many squares of side ``2 r`` (the lane spacing) is merged."""

MIN_CELL_THICKNESS = 1.0
"""A cell thinner than this many sensor radii (``2 area / perimeter``) is merged."""


@dataclass(frozen=True)
class Cell:
    """One cell of a decomposition and its lanes.

    Attributes
    ----------
    polygon : the cell (shapely Polygon) [m]
    angle_deg : its lane direction, counter-clockwise from east, in [0, 180) [deg]
    lanes : lanes in sweep order, each a list of pieces (2, 2) along the lane direction [m]
    """

    polygon: object
    angle_deg: float
    lanes: list


# --- the decomposition ------------------------------------------------------------------------


def decompose(free, angle_deg: float, sensor_radius_m: float,
              max_cells: int = MAX_CELLS) -> list:
    """Boustrophedon cells of ``free`` cut along ``angle_deg`` (module docstring).

    Parameters
    ----------
    free : Polygon or MultiPolygon (the robot's free space) [m]
    angle_deg : decomposition direction, counter-clockwise from east [deg]
    sensor_radius_m : r [m]: sets the smallest cell kept (``MIN_CELL_FOOTPRINTS``,
        ``MIN_CELL_THICKNESS``)
    max_cells : most cells returned

    Returns
    -------
    list of Polygons covering ``free`` without overlap (their union is ``free``)
    """
    if free.is_empty:
        return []
    turned = affinity.rotate(free, -angle_deg, origin=(0.0, 0.0))
    faces = _faces(turned)
    cells = _merge_small(faces, sensor_radius_m, max_cells)
    return [affinity.rotate(c, angle_deg, origin=(0.0, 0.0)) for c in cells]


def _faces(free):
    """``free`` (turned: the decomposition direction along x) cut at its critical points."""
    cuts = _cut_segments(free)
    if not cuts:
        return list(shapely.get_parts(free))
    lines = shapely.union_all([shapely.boundary(free), *cuts])
    faces = shapely.get_parts(shapely.polygonize(shapely.get_parts(lines)))
    inside = shapely.contains_xy(free, shapely.get_coordinates(shapely.point_on_surface(faces)))
    return list(faces[inside])


def _critical_vertices(free) -> np.ndarray:
    """(k, 2) vertices where a line along x meets the boundary tangentially: a run of
    vertices at one y (one vertex, or a horizontal edge) whose neighbours on the ring are on
    the same side of that y, and every horizontal edge (a step of the boundary)."""
    out = []
    scale = max(1.0, float(np.max(np.abs(shapely.get_coordinates(free)))))
    tol = 1e-9 * scale
    for ring in shapely.get_rings(shapely.get_parts(free)):
        xy = shapely.get_coordinates(ring)[:-1]
        if len(xy) < 3:
            continue
        y = xy[:, 1]
        flat = np.abs(np.roll(y, -1) - y) <= tol  # edge i -> i+1 runs along x
        out.append(xy[flat | np.roll(flat, 1)])
        # local extremes across x: compare with the nearest vertex before and after at
        # another y (flat runs skipped)
        idx = np.flatnonzero(~flat)
        if len(idx) < 2:
            continue
        yk = y[idx]
        next_y = y[_off_level(y, idx, +1, tol)]
        prev_y = y[_off_level(y, idx, -1, tol)]
        extreme = (prev_y - yk) * (next_y - yk) > 0
        out.append(xy[idx[extreme]])
    return np.unique(np.concatenate(out), axis=0) if out else np.empty((0, 2))


def _off_level(y, idx, step: int, tol: float) -> np.ndarray:
    """For each vertex ``idx`` of a ring, the nearest vertex ``step`` (+1 forward, -1 back)
    along it whose y differs from its own by more than ``tol``."""
    n = len(y)
    at = (idx + step) % n
    for _ in range(n):
        level = np.abs(y[at] - y[idx]) <= tol
        if not level.any():
            break
        at = np.where(level, (at + step) % n, at)
    return at


def _cut_segments(free) -> list:
    """Cuts along x through each critical vertex, from the boundary on one side to the
    boundary on the other (the pieces of the line inside ``free`` that touch the vertex)."""
    crit = _critical_vertices(free)
    if len(crit) == 0:
        return []
    ys, which = np.unique(crit[:, 1], return_inverse=True)
    u, nrm = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    line, t_in, t_out = _clip_lines(_ring_edges(free), ys, u, nrm)
    scale = max(1.0, float(np.max(np.abs(crit))))
    tol = 1e-7 * scale
    keep = np.zeros(len(line), bool)
    for k in range(len(ys)):
        on = np.flatnonzero(line == k)
        if on.size == 0:
            continue
        x = crit[which == k, 0]
        touches = ((t_in[on, None] - tol <= x[None]) & (x[None] <= t_out[on, None] + tol)).any(1)
        keep[on[touches]] = True
    keep &= t_out - t_in > tol
    if not keep.any():
        return []
    y = ys[line[keep]]
    # a little past the boundary at both ends: the crossing is then noded, not a round-off gap
    a, b = t_in[keep] - 10 * tol, t_out[keep] + 10 * tol
    return list(shapely.linestrings(np.stack([np.c_[a, y], np.c_[b, y]], axis=1)))


def _merge_small(faces, r: float, max_cells: int) -> list:
    """Faces merged into the neighbour they share most boundary with: every face smaller
    than ``MIN_CELL_FOOTPRINTS`` lane squares or thinner than ``MIN_CELL_THICKNESS r``, then
    the smallest until at most ``max_cells`` are left."""
    n = len(faces)
    if n <= 1:
        return faces
    faces = np.asarray(faces, dtype=object)
    tree = shapely.STRtree(faces)
    a, b = tree.query(faces, predicate="intersects")
    pair = a < b
    a, b = a[pair], b[pair]
    shared = shapely.length(shapely.intersection(shapely.boundary(faces[a]),
                                                 shapely.boundary(faces[b])))
    touching = shared > 1e-9
    neighbours: list[dict[int, float]] = [{} for _ in range(n)]
    for i, j, s in zip(a[touching].tolist(), b[touching].tolist(), shared[touching].tolist(),
                       strict=True):
        neighbours[i][j] = neighbours[i].get(j, 0.0) + s
        neighbours[j][i] = neighbours[j].get(i, 0.0) + s
    area = shapely.area(faces).astype(float)
    perimeter = shapely.length(faces).astype(float)
    members = [[i] for i in range(n)]
    alive = set(range(n))

    def small(i) -> bool:
        thin = 2.0 * area[i] / max(perimeter[i], 1e-12) < MIN_CELL_THICKNESS * r
        return area[i] < MIN_CELL_FOOTPRINTS * (2.0 * r) ** 2 or thin

    def merge(i) -> int:
        """Cell i joins the neighbour it shares most boundary with; that neighbour."""
        j = max(neighbours[i], key=neighbours[i].get)
        perimeter[j] += perimeter[i] - 2.0 * neighbours[i][j]  # the shared edge is inside now
        area[j] += area[i]
        members[j] += members[i]
        for k, s in neighbours[i].items():
            if k != j:
                neighbours[j][k] = neighbours[j].get(k, 0.0) + s
                neighbours[k][j] = neighbours[k].get(j, 0.0) + s
            del neighbours[k][i]
        neighbours[i] = {}
        alive.discard(i)
        return j

    def smallest_first(only_small: bool):
        heap = [(area[i], i) for i in alive]
        heapq.heapify(heap)
        while heap and (only_small or len(alive) > max_cells):
            a_i, i = heapq.heappop(heap)
            if i not in alive or a_i != area[i] or not neighbours[i]:
                continue  # merged, grown since, or alone
            if only_small and not small(i):
                continue
            j = merge(i)
            heapq.heappush(heap, (area[j], j))

    smallest_first(only_small=True)
    smallest_first(only_small=False)
    return [_union(faces[members[i]]) for i in sorted(alive)]


def _union(parts):
    merged = shapely.union_all(parts) if len(parts) > 1 else parts[0]
    if merged.geom_type == "MultiPolygon":  # round-off left a crack: close it
        merged = merged.buffer(0)
    return merged


# --- lanes in a cell ----------------------------------------------------------------------------


def cell_lanes(cell, angle_deg: float, r: float, grow_m: float, segments_free,
               offsets=None):
    """Lanes of one cell at ``angle_deg``, grouped by lane as ``lawnmower.sweep_lanes``.

    Parameters
    ----------
    cell : the cell (Polygon) [m]
    angle_deg : lane direction [deg]
    r : sensor radius [m]; lanes at most 2 r apart, r in from the cell's extent grown by
        ``grow_m`` (the robot's keep-away: the sensor sees up to the true walls, as the
        whole-map lanes are placed)
    segments_free : collision test of segments (``lawnmower.FreeSegments``)
    offsets : the lanes' normal offsets [m] (the whole map's: its lanes cut into cells);
        None: the cell's own

    Returns
    -------
    list of lanes in sweep order, each a list of pieces (2, 2) ordered along the lane
    """
    u, nrm = _directions(angle_deg)
    clearance_m = LANE_CLEARANCE_FRACTION * r
    if offsets is None:
        s = shapely.get_coordinates(cell) @ nrm
        offsets = _lane_offsets(float(s.min()) - grow_m, float(s.max()) + grow_m, r)
    # the cell lies in the free space: eroding it keeps lanes off walls and obstacles (and
    # a hair off the cuts, which the neighbour's lanes and both footprints cover)
    region = cell.buffer(-clearance_m, quad_segs=2)
    if region.is_empty:
        return []
    line, t_in, t_out = _clip_lines(_ring_edges(region), offsets, u, nrm)
    keep = t_out - t_in >= MIN_LANE_FRACTION * r
    line, t_in, t_out = line[keep], t_in[keep], t_out[keep]
    a = offsets[line, None] * nrm + t_in[:, None] * u
    b = offsets[line, None] * nrm + t_out[:, None] * u
    ok = segments_free(a, b) if len(a) else np.zeros(0, bool)
    line, a, b = line[ok], a[ok], b[ok]
    return [[np.array([a[i], b[i]]) for i in np.flatnonzero(line == k)]
            for k in np.unique(line)]


def swept_cells(world, cells, r: float, angle_deg: float | None, segments_free,
                sensed=None) -> list[Cell]:
    """Each cell with its lanes (cells with none left out: their area is sensed from the
    lanes beside them, if at all).

    ``angle_deg`` None: each cell at its own angle, the one needing the fewest lane pieces
    in it (``coverage`` rule), lanes placed across the cell. Else every cell at that angle
    on the whole map's lanes (offsets over ``sensed``, the free space the sensor sees, as
    ``coverage_candidates`` places them): the whole-map sweep regrouped cell by cell.
    """
    offsets = None
    if angle_deg is not None:
        angle_deg = float(angle_deg) % 180.0
        s = shapely.get_coordinates(sensed) @ _directions(angle_deg)[1]
        offsets = _lane_offsets(float(s.min()), float(s.max()), r)
    if angle_deg is None:
        cells, angles = same_angle_merged(cells, r)
    else:
        angles = [angle_deg] * len(cells)
    out = []
    for cell, angle in zip(cells, angles, strict=True):
        lanes = cell_lanes(cell, angle, r, world.keep_away_m, segments_free, offsets)
        if lanes:
            out.append(Cell(cell, angle, lanes))
    return out


def same_angle_merged(cells, r: float) -> tuple[list, list[float]]:
    """Cells with their own angles, neighbours that share an angle (and at least a lane
    spacing of boundary) merged: one set of lanes across them, no cut between them to turn
    at, no footprints' overlap on either side of it.

    Returns (cells, angles [deg])."""
    cells = list(cells)
    angles = [_best_angle(c, r) for c in cells]
    merged = True
    while merged:  # a pass merges disjoint pairs; passes until none is left
        merged, gone, grown = False, set(), set()
        a, b = shapely.STRtree(cells).query(cells, predicate="intersects")
        for i, j in zip(a.tolist(), b.tolist(), strict=True):
            if i >= j or angles[i] != angles[j] or {i, j} & (gone | grown):
                continue
            if shapely.intersection(cells[i].boundary, cells[j].boundary).length < 2.0 * r:
                continue
            union = _union([cells[i], cells[j]])
            if union.geom_type != "Polygon":
                continue
            cells[i] = union
            gone.add(j)
            grown.add(i)
            merged = True
        keep = [k for k in range(len(cells)) if k not in gone]
        cells, angles = [cells[k] for k in keep], [angles[k] for k in keep]
    return cells, angles


# --- joining the cells ------------------------------------------------------------------------


def _ends(cell: Cell) -> tuple[np.ndarray, np.ndarray]:
    """The end points of the first and of the last lane (where the cell may be entered)."""
    first = np.array([cell.lanes[0][0][0], cell.lanes[0][-1][1]])
    last = np.array([cell.lanes[-1][0][0], cell.lanes[-1][-1][1]])
    return first, last


def _gap(at, cell: Cell) -> float:
    """Straight distance from ``at`` to the nearest place the cell may be entered [m]."""
    first, last = _ends(cell)
    return float(np.min(np.hypot(*(np.vstack([first, last]) - at).T)))


CELL_ORDERS = ("near", "out")
"""How the cells are joined: ``near``, the nearest cell next (from home: transits short);
``out``, by distance from home, nearest first (an anytime order: what is near home is
sensed before the robot must turn). (``cell_pieces`` also knows ``in``, farthest first: the
route ends near home; it never won on the benchmark maps and is not tried.)"""


def cell_pieces(cells: list[Cell], how: str, home_xy) -> list[np.ndarray]:
    """The cells' lane pieces in driving order (``CELL_ORDERS`` or ``in``): each cell entered at the
    end of its lane set nearer the robot, each lane driven from its nearer end
    (``lawnmower.ordered_pieces``)."""
    home = np.asarray(home_xy, float)
    by_distance = [int(i) for i in np.argsort([_gap(home, c) for c in cells], kind="stable")]
    queue = by_distance[::-1] if how == "in" else by_distance
    left, at, out = list(queue), home, []
    while left:
        k = min(left, key=lambda i: _gap(at, cells[i])) if how == "near" else left[0]
        left.remove(k)
        first, last = _ends(cells[k])
        n = len(cells[k].lanes)
        forward = np.min(np.hypot(*(first - at).T)) <= np.min(np.hypot(*(last - at).T))
        pieces = ordered_pieces(cells[k].lanes, range(n) if forward else range(n - 1, -1, -1),
                                at)
        out += pieces
        at = pieces[-1][1]
    return out
