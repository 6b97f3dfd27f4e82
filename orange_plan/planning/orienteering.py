"""Orienteering with coverage values: which candidates to visit, in which order and direction.

Problem statement (``Orienteering``), apart from how it is solved: points ``0..P-1`` with a
travel energy ``D[a, b]`` and travel time ``T[a, b]`` between any two (minimum-energy roadmap
legs; asymmetric); candidates ``i`` that are entered at ``entry[i, o]`` and left at
``exit[i, o]`` in one of two directions ``o`` (a viewpoint has the same point both ways, a
sweep lane is driven one way or the other) at a service energy ``service_J[i, o]`` and time
``service_s[i, o]``; each candidate senses a set of grid cells (``cells``: a sparse 0/1 matrix,
candidates x cells). Choose a sequence ``(i_1, o_1) .. (i_k, o_k)`` that

    maximises   the area of the union of the visited candidates' cells (overlap counted once)
    subject to  D[start, entry_1] + sum_j service_j + sum_j D[exit_j, entry_j+1]
                + D[exit_k, end]  <=  budget_J
                (the same sum with T and service_s) <= budget_s

How it is solved (``solve``): greedy insertion by new area per joule of insertion cost, then
local search on the energy of the chosen set (2-opt with direction flips, or-opt relocation
with the best direction), then greedy insertion again with the energy the local search freed,
until nothing improves. Every sequence it returns satisfies both budgets as stated (each
accepted move is checked against them), so feasibility does not rest on the heuristic.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix

MAX_ROUNDS = 8
"""Insertion / local-search rounds (each round is stopped early when nothing improves)."""


@dataclass(frozen=True)
class Orienteering:
    """The statement (see the module docstring); energies [J], times [s], areas [m^2]."""

    travel_J: np.ndarray  # (P, P)
    travel_s: np.ndarray  # (P, P)
    entry: np.ndarray  # (N, 2) int point indices
    exit: np.ndarray  # (N, 2)
    service_J: np.ndarray  # (N, 2)
    service_s: np.ndarray  # (N, 2)
    cells: csr_matrix  # (N, M) 0/1
    cell_area_m2: float
    start: int
    end: int
    budget_J: float
    budget_s: float = np.inf
    covered: np.ndarray | None = None  # (M,) cells already sensed

    @property
    def n(self) -> int:
        return len(self.entry)


@dataclass
class Tour:
    """A sequence of (candidate, direction) with its energy, time and area."""

    nodes: list[tuple[int, int]] = field(default_factory=list)
    energy_J: float = 0.0
    time_s: float = 0.0
    area_m2: float = 0.0


def tour_cost(p: Orienteering, nodes) -> tuple[float, float]:
    """Energy [J] and time [s] of a sequence, start to end."""
    if not nodes:
        return float(p.travel_J[p.start, p.end]), float(p.travel_s[p.start, p.end])
    i = np.array([n for n, _ in nodes])
    o = np.array([d for _, d in nodes])
    a, b = p.entry[i, o], p.exit[i, o]
    frm = np.r_[p.start, b]
    to = np.r_[a, p.end]
    return (float(p.travel_J[frm, to].sum() + p.service_J[i, o].sum()),
            float(p.travel_s[frm, to].sum() + p.service_s[i, o].sum()))


def covered_mask(p: Orienteering, nodes) -> np.ndarray:
    """Cells sensed by the start state and the visited candidates (M,) bool."""
    mask = np.zeros(p.cells.shape[1], bool) if p.covered is None else p.covered.copy()
    if nodes:
        seen = p.cells[[n for n, _ in nodes]].indices
        mask[seen] = True
    return mask


def area_m2(p: Orienteering, nodes) -> float:
    """New area sensed by a sequence beyond the start state's [m^2]."""
    base = 0 if p.covered is None else int(p.covered.sum())
    return float((covered_mask(p, nodes).sum() - base) * p.cell_area_m2)


def solve(p: Orienteering, progress=None) -> Tour:
    """Greedy insertion + local search (see the module docstring)."""
    nodes: list[tuple[int, int]] = []
    for round_ in range(MAX_ROUNDS):
        before = (len(nodes), tour_cost(p, nodes)[0])
        nodes = insert_greedily(p, nodes)
        nodes = improve(p, nodes)
        if progress is not None:
            progress(f"tour search round {round_ + 1}: {len(nodes)} candidates")
        after = (len(nodes), tour_cost(p, nodes)[0])
        if after[0] == before[0] and after[1] >= before[1] - 1e-9:
            break
    energy, time = tour_cost(p, nodes)
    return Tour(nodes, energy, time, area_m2(p, nodes))


# --- greedy insertion --------------------------------------------------------------------


def insertion_deltas(p: Orienteering, nodes, candidates: np.ndarray):
    """Insertion cost of each candidate in each direction and gap: (delta_J, delta_s), each
    of shape (candidates, 2, gaps), gap ``g`` being the one before stop ``g``.

    The extra energy is ``D[prev, entry] + service + D[exit, next] - D[prev, next]`` (and the
    same with times).
    """
    prev = np.r_[p.start, [p.exit[i, o] for i, o in nodes]].astype(int)
    nxt = np.r_[[p.entry[i, o] for i, o in nodes], p.end].astype(int)
    return _gap_deltas(p, prev, nxt, candidates)


def _gap_deltas(p: Orienteering, prev: np.ndarray, nxt: np.ndarray, candidates: np.ndarray):
    """``insertion_deltas`` for the gaps ``prev[g] -> nxt[g]``."""
    base_J = p.travel_J[prev, nxt]
    base_s = p.travel_s[prev, nxt]
    a = p.entry[candidates]  # (c, 2)
    b = p.exit[candidates]
    d_J = (p.travel_J[prev[None, None, :], a[:, :, None]] + p.service_J[candidates][:, :, None]
           + p.travel_J[b[:, :, None], nxt[None, None, :]] - base_J[None, None, :])
    d_s = (p.travel_s[prev[None, None, :], a[:, :, None]] + p.service_s[candidates][:, :, None]
           + p.travel_s[b[:, :, None], nxt[None, None, :]] - base_s[None, None, :])
    return d_J, d_s


def insert_greedily(p: Orienteering, nodes) -> list[tuple[int, int]]:
    """Insert candidates by new area per joule while both budgets hold.

    The insertion costs of every candidate are priced once, then kept: an insertion only
    replaces its gap by the two gaps around the new stop, so only those two are priced again
    (each entry is the same expression, so the same number, as pricing all gaps anew).
    """
    nodes = list(nodes)
    energy, time = tour_cost(p, nodes)
    mask = covered_mask(p, nodes)
    in_tour = np.zeros(p.n, bool)
    in_tour[[n for n, _ in nodes]] = True
    every = np.arange(p.n)
    all_J, all_s = insertion_deltas(p, nodes, every)
    while True:
        value = p.cells @ (~mask).astype(float) * p.cell_area_m2
        cand = np.flatnonzero(~in_tour & (value > 0))
        if len(cand) == 0:
            return nodes
        d_J, d_s = all_J[cand], all_s[cand]
        ok = (energy + d_J <= p.budget_J) & (time + d_s <= p.budget_s)
        d_J = np.where(ok, d_J, np.inf)
        flat = d_J.reshape(len(cand), -1)
        best = np.argmin(flat, axis=1)
        best_J = flat[np.arange(len(cand)), best]
        feasible = np.isfinite(best_J)
        if not feasible.any():
            return nodes
        ratio = np.where(feasible, value[cand] / np.maximum(best_J, 1e-9), -np.inf)
        k = int(np.argmax(ratio))
        i = int(cand[k])
        o, pos = divmod(int(best[k]), len(nodes) + 1)
        prev = p.start if pos == 0 else p.exit[nodes[pos - 1][0], nodes[pos - 1][1]]
        nxt = p.end if pos == len(nodes) else p.entry[nodes[pos][0], nodes[pos][1]]
        nodes.insert(pos, (i, o))
        energy += float(best_J[k])
        time += float(d_s[k, o, pos])
        in_tour[i] = True
        mask[p.cells[i].indices] = True
        new_J, new_s = _gap_deltas(p, np.array([prev, p.exit[i, o]]),
                                   np.array([p.entry[i, o], nxt]), every)
        all_J = np.concatenate([all_J[:, :, :pos], new_J, all_J[:, :, pos + 1:]], axis=2)
        all_s = np.concatenate([all_s[:, :, :pos], new_s, all_s[:, :, pos + 1:]], axis=2)


# --- local search on energy -------------------------------------------------------------


def improve(p: Orienteering, nodes) -> list[tuple[int, int]]:
    """2-opt with direction flips and or-opt relocation until neither lowers the energy."""
    nodes = list(nodes)
    for _ in range(50):
        changed = False
        better = two_opt(p, nodes)
        if better is not None:
            nodes, changed = better, True
        better = or_opt(p, nodes)
        if better is not None:
            nodes, changed = better, True
        if not changed:
            break
    return nodes


def _accept(p: Orienteering, old, new) -> bool:
    e_old, _ = tour_cost(p, old)
    e_new, t_new = tour_cost(p, new)
    return e_new < e_old - 1e-9 and e_new <= p.budget_J and t_new <= p.budget_s


def two_opt(p: Orienteering, nodes):
    """Best single segment reversal (directions of reversed lanes flipped), or None.

    Reversing stops ``i..j`` replaces the legs into and out of the segment and drives each
    leg inside it the other way; with prefix sums of forward and reversed legs every (i, j)
    is evaluated at once.
    """
    n = len(nodes)
    if n < 2:
        return None
    idx = np.array([i for i, _ in nodes])
    o = np.array([d for _, d in nodes])
    a, b = p.entry[idx, o], p.exit[idx, o]
    ra, rb = p.entry[idx, 1 - o], p.exit[idx, 1 - o]  # the same stop driven the other way
    fwd_leg = p.travel_J[b[:-1], a[1:]]  # leg k -> k+1
    rev_leg = p.travel_J[rb[1:], ra[:-1]]  # leg k+1 -> k, both flipped
    fwd_svc, rev_svc = p.service_J[idx, o], p.service_J[idx, 1 - o]
    cf = np.r_[0.0, np.cumsum(fwd_leg)]
    cr = np.r_[0.0, np.cumsum(rev_leg)]
    sf = np.r_[0.0, np.cumsum(fwd_svc)]
    sr = np.r_[0.0, np.cumsum(rev_svc)]
    prev = np.r_[p.start, b]  # exit before stop k is prev[k]
    nxt = np.r_[a, p.end]  # entry after stop k is nxt[k + 1]
    i, j = np.triu_indices(n, 0)
    old = (p.travel_J[prev[i], a[i]] + (cf[j] - cf[i]) + (sf[j + 1] - sf[i])
           + p.travel_J[b[j], nxt[j + 1]])
    new = (p.travel_J[prev[i], ra[j]] + (cr[j] - cr[i]) + (sr[j + 1] - sr[i])
           + p.travel_J[rb[i], nxt[j + 1]])
    gain = old - new
    k = int(np.argmax(gain))
    if gain[k] <= 1e-9:
        return None
    ii, jj = int(i[k]), int(j[k])
    seg = [(s, 1 - d) for s, d in reversed(nodes[ii:jj + 1])]
    new_nodes = nodes[:ii] + seg + nodes[jj + 1:]
    return new_nodes if _accept(p, nodes, new_nodes) else None


def or_opt(p: Orienteering, nodes):
    """Best relocation of one stop to another gap or direction (vectorised), or None.

    Inserting stop k into a gap that is not next to it costs the same in the tour with k
    removed, so every (stop, gap, direction) is priced at once from the current tour; the two
    gaps beside k are priced as turning k round in place.
    """
    n = len(nodes)
    if n == 0:
        return None
    idx = np.array([i for i, _ in nodes])
    o = np.array([d for _, d in nodes])
    a, b = p.entry[idx, o], p.exit[idx, o]
    prev = np.r_[p.start, b[:-1]]
    nxt = np.r_[a[1:], p.end]
    removal = (p.travel_J[prev, a] + p.service_J[idx, o] + p.travel_J[b, nxt]
               - p.travel_J[prev, nxt])
    d_J, _ = insertion_deltas(p, nodes, idx)  # (n, 2, n + 1): gap g is before stop g
    rows = np.arange(n)
    d_J[rows, :, rows] = np.inf  # the gaps beside k: handled as a flip in place below
    d_J[rows, :, rows + 1] = np.inf
    flip = (p.travel_J[prev, p.entry[idx, 1 - o]] + p.service_J[idx, 1 - o]
            + p.travel_J[p.exit[idx, 1 - o], nxt] - p.travel_J[prev, nxt])
    d_J[rows, 1 - o, rows] = flip
    flat = d_J.reshape(n, -1)
    best = np.argmin(flat, axis=1)
    gain = removal - flat[rows, best]
    k = int(np.argmax(gain))
    if not gain[k] > 1e-9:
        return None
    d, gap = divmod(int(best[k]), n + 1)
    rest = nodes[:k] + nodes[k + 1:]
    pos = gap - 1 if gap > k else gap
    cand = [*rest[:pos], (nodes[k][0], d), *rest[pos:]]
    return cand if _accept(p, nodes, cand) else None
