"""Open-path heuristics: nearest-neighbour construction, then 2-opt and Or-opt improvement.

A path is a list of node indices of a `CostMatrix` that starts with node 0 (the vehicle) and
visits every other node once; it ends wherever it ends (no return). Everything here is
deterministic: equal matrices and paths give equal results.
"""

from __future__ import annotations

import random
import time
from collections import deque
from collections.abc import Sequence

import numpy as np

from .base import tie_tolerance
from .costs import CostMatrix, FloatArray

NEIGHBOURS = 10
"""Candidate list length of the improvement moves: only moves that make a node adjacent to
one of its NEIGHBOURS cheapest partners are tried (the usual neighbour-list restriction)."""


def path_cost(matrix: CostMatrix, path: Sequence[int]) -> float:
    """Total cost of following `path` (node indices) through `matrix`."""
    if len(path) < 2:
        return 0.0
    idx = np.asarray(path, dtype=np.intp)
    return float(matrix.values[idx[:-1], idx[1:]].sum())


def greedy_chain(matrix: CostMatrix, weights: FloatArray | None = None) -> list[int]:
    """The nearest-neighbour path from node 0: always the cheapest unvisited node next, or
    with `weights` (one per node, positive; entry 0 ignored) the least cost per unit of the
    node's weight.

    Costs within `tie_tolerance` of the cheapest count as ties and go to the lowest node index,
    which callers make the (requested_s, id) order.
    """
    values = matrix.values if weights is None else matrix.values / weights[None, :]
    m = matrix.size
    visited = np.zeros(m, dtype=bool)
    visited[0] = True
    path = [0]
    current = 0
    for _ in range(m - 1):
        current = first_cheapest(np.where(visited, np.inf, values[current]))
        visited[current] = True
        path.append(current)
    return path


def first_cheapest(costs: FloatArray) -> int:
    """Index of the cheapest entry; entries within `tie_tolerance` of it go to the lowest index.

    Raises ValueError on an empty array.
    """
    best = float(costs.min())
    return int(np.flatnonzero(costs <= best + tie_tolerance(best))[0])


def neighbour_lists(
    matrix: CostMatrix, k: int = NEIGHBOURS
) -> tuple[list[list[int]], list[list[float]]]:
    """For every node, its k cheapest partners (either direction) and those costs, ascending.

    Node 0 is a partner of every task with the cost of flying there from the vehicle, so that
    moves can also change which task comes first. Ties go to the lower index.
    """
    values = matrix.values
    m = matrix.size
    sym = values.copy()
    sym[1:, 0] = values[0, 1:]
    if not matrix.symmetric:
        sym[1:, 1:] = np.minimum(values[1:, 1:], values[1:, 1:].T)
    np.fill_diagonal(sym, np.inf)
    k = min(k, m - 1)
    if k <= 0:
        return [[] for _ in range(m)], [[] for _ in range(m)]
    if k == m - 1:
        candidates = np.argsort(sym, axis=1, kind="stable")[:, :k]
    else:
        candidates = np.argpartition(sym, k - 1, axis=1)[:, :k]
    costs = np.take_along_axis(sym, candidates, axis=1)
    order = np.lexsort((candidates, costs), axis=-1)
    candidates = np.take_along_axis(candidates, order, axis=1)
    costs = np.take_along_axis(costs, order, axis=1)
    return candidates.tolist(), costs.tolist()


def improve_path(
    matrix: CostMatrix,
    path: Sequence[int],
    *,
    neighbours: tuple[list[list[int]], list[list[float]]] | None = None,
    max_moves: int | None = None,
    start: Sequence[int] | None = None,
) -> list[int]:
    """`path` improved by 2-opt and Or-opt moves for open paths until none helps.

    2-opt reverses a stretch of the path (including the tail, which costs one edge only on an
    open path); Or-opt moves a run of 1-3 nodes elsewhere, possibly reversed. Moves are
    restricted to `neighbours` (default `neighbour_lists(matrix)`) and processed from a queue
    of nodes whose surroundings changed, so the work grows about linearly with the path length.
    `max_moves` (default 50 per node) bounds the number of applied moves. `start` lists the
    nodes to look at first (default: all of them; after a local change, the nodes around it).
    Reversal costs are exact for asymmetric matrices too. Returns a new list; never a costlier
    path.
    """
    m = matrix.size
    p = list(path)
    if m <= 2:
        return p
    nbrs, ncosts = neighbours if neighbours is not None else neighbour_lists(matrix)
    if max_moves is None:
        max_moves = 50 * m
    c = matrix.values.item
    symmetric = matrix.symmetric
    last = m - 1
    pos = [0] * m
    for index, node in enumerate(p):
        pos[node] = index
    # A move must gain more than rounding noise, otherwise equal-cost moves could cycle.
    eps = 1e-9 * path_cost(matrix, p) / last + 1e-12
    # rev[k]: cost change of reversing the edges p[0..k]; rev[j] - rev[i] is the change when
    # p[i..j] is reversed. Only asymmetric costs need it.
    rev = [0.0] * m

    def rebuild_rev(start: int) -> None:
        for t in range(max(start, 0), last):
            a, b = p[t], p[t + 1]
            rev[t + 1] = rev[t] + c(b, a) - c(a, b)

    if not symmetric:
        rebuild_rev(0)

    def reverse(i: int, j: int) -> None:
        p[i : j + 1] = p[i : j + 1][::-1]
        for t in range(i, j + 1):
            pos[p[t]] = t
        if not symmetric:
            rebuild_rev(i - 1)

    def two_opt(a: int) -> tuple[int, ...] | None:
        i = pos[a]
        d_succ: float = c(a, p[i + 1]) if i < last else np.inf
        d_pred: float = c(p[i - 1], a) if i > 0 else 0.0
        limit = max(d_succ, d_pred)
        for cand, cand_cost in zip(nbrs[a], ncosts[a], strict=True):
            if cand_cost >= limit:
                break
            j = pos[cand]
            ix, iy, x, y = (i, j, a, cand) if j > i else (j, i, cand, a)
            if iy - ix < 2:
                continue
            xy: float = c(x, y)
            xs = p[ix + 1]
            # Reverse p[ix+1..iy]: x -> y and xs -> (successor of y).
            if iy < last:
                ys = p[iy + 1]
                delta: float = xy + c(xs, ys) - c(x, xs) - c(y, ys)
            else:
                ys = y
                delta = xy - c(x, xs)
            if not symmetric:
                delta += rev[iy] - rev[ix + 1]
            if delta < -eps:
                reverse(ix + 1, iy)
                return (x, y, xs, ys)
            if ix >= 1:
                # Reverse p[ix..iy-1]: (predecessor of x) -> (predecessor of y) and x -> y.
                xp, yp = p[ix - 1], p[iy - 1]
                delta = c(xp, yp) + xy - c(xp, x) - c(yp, y)
                if not symmetric:
                    delta += rev[iy - 1] - rev[ix]
                if delta < -eps:
                    reverse(ix, iy - 1)
                    return (x, y, xp, yp)
        return None

    def or_opt(a: int) -> tuple[int, ...] | None:
        i = pos[a]
        if i == 0:
            return None
        prev = p[i - 1]
        for length in (1, 2, 3):
            e = i + length - 1
            if e > last:
                break
            s1, sl = a, p[e]
            nxt = p[e + 1] if e < last else -1
            gain: float = c(prev, s1) + (c(sl, nxt) - c(prev, nxt) if nxt >= 0 else 0.0)
            seg_rev: float = 0.0 if symmetric else rev[e] - rev[i]
            for end in (s1,) if length == 1 else (s1, sl):
                for cand, cand_cost in zip(nbrs[end], ncosts[end], strict=True):
                    if cand_cost >= gain:
                        break
                    j = pos[cand]
                    if i <= j <= e:
                        continue
                    # Insert right after cand, `end` next to it.
                    u = cand
                    w = p[j + 1] if j < last else -1
                    if w == s1:
                        w = nxt
                    moved = insert_if_better(u, w, end == s1, s1, sl, gain, seg_rev)
                    if moved is None and j >= 1:
                        # Insert right before cand, `end` next to it.
                        w = cand
                        u = p[j - 1]
                        if u == sl:
                            u = prev
                        moved = insert_if_better(u, w, end == sl, s1, sl, gain, seg_rev)
                    if moved is not None:
                        u, w, forward = moved
                        seg = p[i : e + 1]
                        if not forward:
                            seg.reverse()
                        del p[i : e + 1]
                        k = pos[u] if pos[u] < i else pos[u] - length
                        p[k + 1 : k + 1] = seg
                        lo, hi = min(i, k + 1), max(e, k + length)
                        for t in range(lo, hi + 1):
                            pos[p[t]] = t
                        if not symmetric:
                            rebuild_rev(lo - 1)
                        return (prev, nxt, s1, sl, u, w)
        return None

    def insert_if_better(
        u: int, w: int, forward: bool, s1: int, sl: int, gain: float, seg_rev: float
    ) -> tuple[int, int, bool] | None:
        if forward:
            add: float = c(u, s1) + (c(sl, w) - c(u, w) if w >= 0 else 0.0)
        else:
            add = c(u, sl) + (c(s1, w) - c(u, w) if w >= 0 else 0.0) + seg_rev
        if add - gain < -eps:
            return u, w, forward
        return None

    queue = deque(p if start is None else dict.fromkeys(start))
    queued = [False] * m
    for node in queue:
        queued[node] = True
    moves = 0
    while queue and moves < max_moves:
        a = queue.popleft()
        queued[a] = False
        touched = two_opt(a) or or_opt(a)
        if touched is None:
            continue
        moves += 1
        for node in (a, *touched):
            if node >= 0 and not queued[node]:
                queued[node] = True
                queue.append(node)
    return p


def improve_with_restarts(
    matrix: CostMatrix, path: Sequence[int], *, rounds: int, seed: int = 0
) -> list[int]:
    """`improve_path`, then `rounds` kicks (a double-bridge segment swap) each followed by
    `improve_path`, keeping the best path. A seeded RNG keeps it deterministic. Meant for small
    sets (tens of tasks), where it is the incumbent of the exact search."""
    neighbours = neighbour_lists(matrix)
    best = improve_path(matrix, path, neighbours=neighbours)
    best_cost = path_cost(matrix, best)
    m = matrix.size
    if m < 5:
        return best
    rng = random.Random(seed)
    eps = 1e-9 * best_cost
    for _ in range(rounds):
        a, b, c = sorted(rng.sample(range(1, m), 3))
        kicked = best[:a] + best[b:c] + best[a:b] + best[c:]
        candidate = improve_path(matrix, kicked, neighbours=neighbours)
        cost = path_cost(matrix, candidate)
        if cost < best_cost - eps:
            best, best_cost = candidate, cost
    return best


KICK_WINDOW = 100
"""Positions spanned by one perturbation of `iterated_local_search`. The repair after a kick
starts from the six nodes at its cuts, so it stays cheap however long the path. Measured on
200 random points: windows of 8, 30, 100 and 200 positions end 1.9 %, 1.3 %, 0.4 % and 0.6 %
above the best known tour after 2,000 kicks."""


def iterated_local_search(
    matrix: CostMatrix,
    path: Sequence[int],
    *,
    kicks: int,
    seed: int = 0,
    deadline: float | None = None,
) -> list[int]:
    """A path close to the shortest: `improve_path`, then up to `kicks` perturbations, each a
    double bridge (two neighbouring stretches of the path swapped) within `KICK_WINDOW`
    positions, repaired by `improve_path` from the nodes at the cuts; a result no costlier than
    the best so far replaces it. Deterministic for a given `seed`; `deadline` (a
    `time.perf_counter()` value) stops early, which makes the result depend on the machine's
    speed, so reproducible callers leave it None.
    """
    neighbours = neighbour_lists(matrix)
    best = improve_path(matrix, path, neighbours=neighbours)
    m = matrix.size
    if m < 5:
        return best
    best_cost = path_cost(matrix, best)
    rng = random.Random(seed)
    for kick in range(kicks):
        if deadline is not None and kick % 16 == 0 and time.perf_counter() > deadline:
            break
        first = rng.randrange(1, m - 2)
        last = min(m, first + KICK_WINDOW)
        a, b, c = sorted(rng.sample(range(first, last + 1), 3))
        if b == a or c == b:
            continue
        kicked = best[:a] + best[b:c] + best[a:b] + best[c:]
        touched = [kicked[k] for k in (a - 1, a, a + c - b - 1, a + c - b, c - 1, c) if k < m]
        candidate = improve_path(matrix, kicked, neighbours=neighbours, start=touched)
        cost = path_cost(matrix, candidate)
        if cost <= best_cost * (1.0 + 1e-12):
            best, best_cost = candidate, cost
    return best
