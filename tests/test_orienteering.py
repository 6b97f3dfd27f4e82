"""The orienteering search against brute force on small instances.

Why stated this way: the heuristic cannot be checked for optimality on the planner's real
instances, but on instances of up to five candidates every subset, order and direction can
be enumerated. Two things must then hold: whatever the heuristic returns keeps both budgets
(feasibility must never rest on the heuristic), and its area is close to the enumerated
optimum (quality, measured over a fixed set of random instances).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import csr_matrix

from orange_plan.planning import orienteering as ort


def random_instance(seed: int, n: int = 5, budget_share: float = 0.5, lanes: bool = True):
    """Candidates on a plane (Euclidean legs, asymmetric by a grade-like term), random cells."""
    rng = np.random.default_rng(seed)
    m_cells = 60
    start = rng.uniform(0, 10, 2)
    a = rng.uniform(0, 10, (n, 2))
    b = a + (rng.uniform(-2, 2, (n, 2)) if lanes else 0.0)
    pts = np.vstack([start, start, a, b])  # 0 = start, 1 = end (home = start)
    z = rng.uniform(0, 1, len(pts))
    diff = pts[None, :, :] - pts[:, None, :]
    dist = np.hypot(diff[..., 0], diff[..., 1])
    travel_J = dist + np.maximum(z[None, :] - z[:, None], 0.0)  # climbing costs extra
    travel_s = dist / 1.5
    entry = np.stack([2 + np.arange(n), 2 + n + np.arange(n)], axis=1)
    exit_ = entry[:, ::-1].copy()
    length = np.hypot(*(b - a).T)
    service_J = np.stack([length + 0.1, length + 0.2], axis=1)
    service_s = np.stack([length, length], axis=1) / 1.5
    cells = np.zeros((n, m_cells))
    for i in range(n):
        lo = rng.integers(0, m_cells - 15)
        cells[i, lo:lo + rng.integers(3, 15)] = 1
    full = ort.Orienteering(travel_J, travel_s, entry, exit_, service_J, service_s,
                            csr_matrix(cells), 1.0, 0, 1, budget_J=np.inf)
    total = max(ort.tour_cost(full, [(i, 0) for i in range(n)])[0], 1e-9)
    return ort.Orienteering(travel_J, travel_s, entry, exit_, service_J, service_s,
                            csr_matrix(cells), 1.0, 0, 1, budget_J=budget_share * total)


def brute_force_area(p: ort.Orienteering) -> float:
    best = 0.0
    for k in range(1, p.n + 1):
        for subset in itertools.combinations(range(p.n), k):
            area = ort.area_m2(p, [(i, 0) for i in subset])
            if area <= best:
                continue
            for order in itertools.permutations(subset):
                for dirs in itertools.product((0, 1), repeat=k):
                    nodes = list(zip(order, dirs))
                    energy, time = ort.tour_cost(p, nodes)
                    if energy <= p.budget_J and time <= p.budget_s:
                        best = area
                        break
                else:
                    continue
                break
    return best


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), share=st.floats(0.05, 1.5), lanes=st.booleans())
def test_heuristic_tour_always_keeps_the_budget(seed, share, lanes):
    p = random_instance(seed, n=6, budget_share=share, lanes=lanes)
    tour = ort.solve(p)
    energy, time = ort.tour_cost(p, tour.nodes)
    assert energy <= p.budget_J + 1e-9
    assert time <= p.budget_s + 1e-9
    assert tour.area_m2 == pytest.approx(ort.area_m2(p, tour.nodes))
    assert len({i for i, _ in tour.nodes}) == len(tour.nodes)  # no candidate twice


def test_heuristic_area_is_close_to_the_enumerated_optimum():
    ratios = []
    for seed in range(40):
        p = random_instance(seed, n=5, budget_share=0.45)
        best = brute_force_area(p)
        if best == 0:
            continue
        ratios.append(ort.solve(p).area_m2 / best)
    ratios = np.array(ratios)
    assert np.median(ratios) >= 0.95
    assert ratios.min() >= 0.5


def test_two_opt_undoes_a_crossing():
    # Four viewpoints on a square visited in crossing order: 2-opt must uncross them.
    pts = np.array([[0, 0], [0, 0], [0, 0], [1, 1], [1, 0], [0, 1]], float)
    pts[2] = [0.0, 0.1]
    dist = np.hypot(*(pts[None] - pts[:, None]).transpose(2, 0, 1))
    entry = np.stack([np.arange(2, 6)] * 2, axis=1)
    p = ort.Orienteering(dist, dist, entry, entry.copy(), np.zeros((4, 2)), np.zeros((4, 2)),
                         csr_matrix(np.eye(4)), 1.0, 0, 1, budget_J=100.0)
    crossing = [(0, 0), (1, 0), (2, 0), (3, 0)]  # (0,.1) -> (1,1) -> (1,0) -> (0,1)
    better = ort.improve(p, crossing)
    assert ort.tour_cost(p, better)[0] < ort.tour_cost(p, crossing)[0] - 0.5


def test_nothing_fits_gives_an_empty_tour():
    p = random_instance(3, budget_share=0.0)
    assert ort.solve(p).nodes == []


def insert_greedily_repricing(p: ort.Orienteering, nodes):
    """The greedy insertion pricing every gap anew after each insertion (the rule
    ``insert_greedily`` keeps its prices by): the reference of the test below."""
    nodes = list(nodes)
    energy, time = ort.tour_cost(p, nodes)
    mask = ort.covered_mask(p, nodes)
    in_tour = np.zeros(p.n, bool)
    in_tour[[n for n, _ in nodes]] = True
    while True:
        value = p.cells @ (~mask).astype(float) * p.cell_area_m2
        cand = np.flatnonzero(~in_tour & (value > 0))
        if len(cand) == 0:
            return nodes
        d_J, d_s = ort.insertion_deltas(p, nodes, cand)
        d_J = np.where((energy + d_J <= p.budget_J) & (time + d_s <= p.budget_s), d_J, np.inf)
        flat = d_J.reshape(len(cand), -1)
        best = np.argmin(flat, axis=1)
        best_J = flat[np.arange(len(cand)), best]
        if not np.isfinite(best_J).any():
            return nodes
        k = int(np.argmax(np.where(np.isfinite(best_J),
                                   value[cand] / np.maximum(best_J, 1e-9), -np.inf)))
        o, pos = divmod(int(best[k]), len(nodes) + 1)
        nodes.insert(pos, (int(cand[k]), o))
        energy += float(best_J[k])
        time += float(d_s[k, o, pos])
        in_tour[cand[k]] = True
        mask[p.cells[cand[k]].indices] = True


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 12), share=st.floats(0.05, 1.5),
       time_share=st.floats(0.3, 2.0), lanes=st.booleans(), start_with=st.integers(0, 3))
def test_kept_insertion_prices_choose_what_repricing_chooses(seed, n, share, time_share, lanes,
                                                             start_with):
    """From an empty or partial tour, under energy and time budgets: the same insertions in
    the same order and directions as pricing every gap anew."""
    p = random_instance(seed, n=n, budget_share=share, lanes=lanes)
    p = ort.Orienteering(**{**p.__dict__, "budget_s": time_share * p.budget_J / 1.5})
    nodes = [(i, i % 2) for i in range(min(start_with, n))]
    assert ort.insert_greedily(p, nodes) == insert_greedily_repricing(p, nodes)
