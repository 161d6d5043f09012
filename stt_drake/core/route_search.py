"""The guide's route search: an earliest-arrival A* in space and time over a grid whose
cells are occupied, at a given time, by the obstacles' *predicted* beliefs.

:func:`search_route` is written once, in the subset of Python that numba compiles: the
compiled kernel (:mod:`stt_drake.core._guide`) is this function under ``numba.njit``, and
the numpy path (:mod:`stt_drake.core.backend`) runs it as plain Python (slow, for tests and
machines without numba). It imports nothing of numba and nothing of the package.

Arrays, for m obstacles in dimension n and K prediction knots t_k = t0 + k·dt: ``means``
(K, m, n) metres; ``soft_radius`` and ``hard_radius`` (K, m) metres — a point closer than
``soft_radius_kj`` to mean μ_j(t_k) lies in obstacle j's avoid-level set (where the guide
does not want the tube's centre), closer than ``hard_radius_kj`` in its ε set (where the
tube's centre can never be, Theorem 3.2 (ii)); a radius of 0 never blocks (an inactive
slot). A time is read at its nearest knot, and times past the last knot at the last one.
"""

from __future__ import annotations

import heapq
import math

import numpy as np

#: Status codes of :func:`search_route`: the goal's cell was reached; the expansion budget
#: ran out (the route leads to the expanded cell nearest the goal).
REACHED, BUDGET = 0, 1


def search_route(
    origin: np.ndarray,
    cell: float,
    shape: np.ndarray,
    start: np.ndarray,
    goal: np.ndarray,
    t0: float,
    dt: float,
    means: np.ndarray,
    soft_radius: np.ndarray,
    hard_radius: np.ndarray,
    speed: float,
    max_wait_knots: int,
    soft_cost: float,
    hard_cost: float,
    avoid_centers: np.ndarray,
    avoid_radius: np.ndarray,
    avoid_cost: float,
    greed: float,
    max_expansions: int,
) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Earliest-arrival A* from `start` to `goal` over the grid of cells of side `cell`
    (metres) whose centres are origin + (index + ½)·cell, index < `shape`, with the 3^n − 1
    neighbours of a cell, the tube moving at `speed` (m/s).

    A label is (arrival time, cost). Moving into a cell costs its travel time times
    1 + (occupancy rate) + (`avoid_cost` inside a ball of `avoid_centers`/`avoid_radius`:
    the regions where the tube stalled), the occupancy rate being `hard_cost` inside some ε
    set, else `soft_cost` inside some avoid-level set, else 0 — read at the move's end and
    at its midpoint. Occupied cells are expensive, not forbidden, so a route always exists;
    when none is free the search returns the least occupied one. Before a move into an
    occupied cell it may wait, up to `max_wait_knots` knots, for one at which that cell is
    free (a crossing obstacle passes), if its own cell stays free meanwhile; the wait costs
    its time. The heuristic ‖x − goal‖/speed never exceeds the remaining cost (every cost
    is at least the travel time); weighted by `greed` ≥ 1 (weighted A*), the route found
    costs at most `greed` times the least cost, for far fewer expansions.

    The route is then pulled straight: a run of cells is replaced by one segment where the
    segment, sampled every half cell at times interpolated between its ends' arrival
    times, meets no more occupancy than the cells it replaces.

    Returns:
        (points (L, n), times (L,), status, expansions): the route's corners from the
        start's cell to the goal's and their arrival times (s), status `REACHED`; or,
        when `max_expansions` ran out first, the route to the expanded cell nearest the
        goal, status `BUDGET`.
    """
    n = origin.shape[0]
    knots, count = means.shape[0], means.shape[1]

    def rate_at(point: np.ndarray, t: float) -> float:
        k = min(max(int((t - t0) / dt + 0.5), 0), knots - 1)
        rate = 0.0
        for j in range(count):
            squared = 0.0
            for i in range(n):
                squared += (point[i] - means[k, j, i]) ** 2
            if squared < hard_radius[k, j] ** 2:
                return hard_cost
            if squared < soft_radius[k, j] ** 2:
                rate = soft_cost
        return rate

    total = 1
    for i in range(n):
        total *= shape[i]
    stride = np.ones(n, dtype=np.int64)
    for i in range(n - 2, -1, -1):
        stride[i] = stride[i + 1] * shape[i + 1]

    def index_of(point: np.ndarray) -> int:
        flat = 0
        for i in range(n):
            k = min(max(int((point[i] - origin[i]) / cell), 0), shape[i] - 1)
            flat += k * stride[i]
        return flat

    # The 3^n − 1 neighbour offsets and their lengths (m).
    neighbours = 3**n - 1
    offsets = np.zeros((neighbours, n), dtype=np.int64)
    lengths = np.zeros(neighbours)
    row = 0
    for code in range(3**n):
        rest, squared = code, 0.0
        for i in range(n):
            offsets[row, i] = rest % 3 - 1
            rest //= 3
            squared += offsets[row, i] ** 2
        if squared > 0.0:
            lengths[row] = cell * math.sqrt(squared)
            row += 1
    stop, first = index_of(goal), index_of(start)
    arrival = np.full(total, np.inf)
    cost = np.full(total, np.inf)
    parent = np.full(total, -1, dtype=np.int64)
    closed = np.zeros(total, dtype=np.bool_)
    coordinates = np.zeros(n, dtype=np.int64)
    here, there, middle = np.zeros(n), np.zeros(n), np.zeros(n)
    arrival[first], cost[first] = t0, 0.0
    heap = [(0.0, first)]
    best, best_gap, expansions, status = first, np.inf, 0, BUDGET
    while len(heap) > 0:
        u = heapq.heappop(heap)[1]
        if closed[u]:
            continue
        closed[u] = True
        rest, gap = u, 0.0
        for i in range(n):
            coordinates[i] = rest // stride[i]
            rest -= coordinates[i] * stride[i]
            here[i] = origin[i] + (coordinates[i] + 0.5) * cell
            gap += (here[i] - goal[i]) ** 2
        if gap < best_gap:
            best, best_gap = u, gap
        if u == stop:
            status = REACHED
            break
        expansions += 1
        if expansions > max_expansions:
            break
        for row in range(neighbours):
            v, inside = 0, True
            for i in range(n):
                k = coordinates[i] + offsets[row, i]
                if k < 0 or k >= shape[i]:
                    inside = False
                    break
                v += k * stride[i]
                there[i] = origin[i] + (k + 0.5) * cell
                middle[i] = 0.5 * (here[i] + there[i])
            if not inside or closed[v]:
                continue
            travel = lengths[row] / speed
            depart = arrival[u]
            rate = max(rate_at(there, depart + travel), rate_at(middle, depart + 0.5 * travel))
            waited = 0
            while rate > 0.0 and waited < max_wait_knots and rate_at(here, depart + dt) == 0.0:
                depart += dt
                waited += 1
                rate = max(rate_at(there, depart + travel), rate_at(middle, depart + 0.5 * travel))
            if rate > 0.0 and waited > 0:  # no free moment within the wait: move at once
                depart = arrival[u]
                rate = max(rate_at(there, depart + travel), rate_at(middle, depart + 0.5 * travel))
            avoid = 0.0
            for a in range(avoid_radius.shape[0]):
                squared = 0.0
                for i in range(n):
                    squared += (there[i] - avoid_centers[a, i]) ** 2
                if squared < avoid_radius[a] ** 2:
                    avoid = avoid_cost
            new_cost = cost[u] + (depart - arrival[u]) + travel * (1.0 + rate + avoid)
            if new_cost < cost[v]:
                cost[v], arrival[v], parent[v] = new_cost, depart + travel, u
                remaining = 0.0
                for i in range(n):
                    remaining += (there[i] - goal[i]) ** 2
                heapq.heappush(heap, (new_cost + greed * math.sqrt(remaining) / speed, v))
    end = stop if status == REACHED else best
    length, walk = 1, end
    while parent[walk] >= 0:
        walk = parent[walk]
        length += 1
    points, times = np.zeros((length, n)), np.zeros(length)
    walk = end
    for row in range(length - 1, -1, -1):
        rest = walk
        for i in range(n):
            k = rest // stride[i]
            rest -= k * stride[i]
            points[row, i] = origin[i] + (k + 0.5) * cell
        times[row] = arrival[walk]
        walk = parent[walk]
    # String pulling: from each kept point, jump to the farthest later point the straight
    # segment reaches without meeting more occupancy than the cells it skips (sampled every
    # half cell at times interpolated between the two points' arrival times).
    keep = np.zeros(length, dtype=np.bool_)
    keep[0], keep[length - 1] = True, True
    sample = np.zeros(n)
    i = 0
    while i < length - 1:
        worst, j = 0.0, i + 1
        for k in range(i + 1, length):
            worst = max(worst, rate_at(points[k], times[k]))
            gap = 0.0
            for a in range(n):
                gap += (points[k, a] - points[i, a]) ** 2
            samples = int(math.sqrt(gap) / (0.5 * cell)) + 1
            clear = True
            for m in range(1, samples):
                fraction = m / samples
                for a in range(n):
                    sample[a] = points[i, a] + fraction * (points[k, a] - points[i, a])
                if rate_at(sample, times[i] + fraction * (times[k] - times[i])) > worst:
                    clear = False
                    break
            if not clear:
                break
            j = k
        keep[j] = True
        i = j
    return points[keep], times[keep], status, expansions
