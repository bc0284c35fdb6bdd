"""Orders that keep customers waiting least: the weighted traveling-repairman objective.

A path is a list of node indices of a `CostMatrix` that starts with node 0 (the vehicle) and
visits every task node once. Every task node belongs to a group (a point task is a group of
one; the tasks of one `executeAll` batch form a group, which is complete when its last task is
read) and every group has a weight. The objective of a path is

    F = sum over groups g of weight(g) * (arrival time at the last task of g)

with arrival times measured from now along the path. With groups of one and equal weights this
is the sum of completion times of the traveling repairman (minimum latency) problem; the
planner raises the weight of old tasks so that none starves.

Moves are evaluated in constant time with the concatenation algebra of sub-paths (duration T,
weight W, weighted arrival sum C; joining A and B gives T = T_A + d + T_B and C = C_A + C_B +
W_B * (T_A + d)): a move is a few stretches of the current path joined in a new order, and every
stretch's (T, W, C) comes from prefix sums. Where a group has several tasks the weight sits on
its last task, so a move that changes which task of a group is last is checked against the full
objective before it is taken.

Deterministic: equal matrices, weights and starting paths give equal results, unless a
`deadline` stops the search early.
"""

from __future__ import annotations

import itertools
import math
import random
import time
from collections import deque
from collections.abc import Sequence

import numpy as np

from fleet.geo import Position

from .base import CostFn
from .costs import CostMatrix
from .heuristics import neighbour_lists

NEIGHBOURS = 6
"""Moves considered per node: those that make it adjacent to one of its 6 cheapest partners."""

_Block = tuple[int, int, bool]  # positions x..y of the current path, reversed or not


def group_objective(
    matrix: CostMatrix, path: Sequence[int], weights: Sequence[float], groups: Sequence[int]
) -> float:
    """F of `path` (see the module's docstring). `weights` and `groups` are indexed by node
    (entry 0, the vehicle, is ignored); `weights` holds each group's weight on each member."""
    value = matrix.values.item
    last: dict[int, float] = {}
    weight: dict[int, float] = {}
    t = 0.0
    for a, b in itertools.pairwise(path):
        t += value(a, b)
        last[groups[b]] = t
        weight[groups[b]] = weights[b]
    return sum(weight[g] * arrival for g, arrival in last.items())


class RepairmanSearch:
    """Local search and perturbation for the objective above, on one matrix.

    `weights[node]` is the weight of the node's group (equal for all members), `groups[node]`
    its group id. Build once per planning round; `improve` and `perturb` return better paths.
    """

    def __init__(
        self,
        matrix: CostMatrix,
        weights: Sequence[float],
        groups: Sequence[int],
        *,
        deadline: float | None = None,
    ) -> None:
        self.matrix = matrix
        self.weights = list(weights)
        self.groups = list(groups)
        self.deadline = deadline
        self.batched = len(set(self.groups[1:])) < len(self.groups) - 1
        self.rows: list[list[float]] = matrix.values.tolist()
        self.neighbours = neighbour_lists(matrix, NEIGHBOURS)[0]
        self.evaluations = 0
        scale = float(matrix.values.max()) * max(self.weights[1:], default=1.0) * matrix.size
        self.eps = 1e-9 * scale + 1e-12

    # --- the objective ------------------------------------------------------------------------

    def objective(self, path: Sequence[int]) -> float:
        return group_objective(self.matrix, path, self.weights, self.groups)

    def _load(self, path: list[int]) -> None:
        """Prefix sums of `path`: arrival times, effective weights (the group's weight on its
        last task, 0 on the others) and weighted arrival times."""
        rows = self.rows
        n = len(path)
        self.path = path
        self.pos = [0] * self.matrix.size
        effective = [0.0] * n
        seen: set[int] = set()
        for k in range(n - 1, 0, -1):
            node = path[k]
            self.pos[node] = k
            group = self.groups[node]
            if group not in seen:
                seen.add(group)
                effective[k] = self.weights[node]
        arrival = [0.0] * n
        wsum = [0.0] * (n + 1)
        csum = [0.0] * (n + 1)
        t = 0.0
        for k in range(1, n):
            t += rows[path[k - 1]][path[k]]
            arrival[k] = t
            wsum[k + 1] = wsum[k] + effective[k]
            csum[k + 1] = csum[k] + effective[k] * t
        self.arrival, self.wsum, self.csum = arrival, wsum, csum
        self.current = csum[n]

    def _joined(self, blocks: Sequence[_Block]) -> float:
        """F of the path made of `blocks` of the current path, by concatenation (O(blocks))."""
        self.evaluations += 1
        rows = self.rows
        p, arrival, wsum, csum = self.path, self.arrival, self.wsum, self.csum
        total_t = total_c = 0.0
        last = -1
        for x, y, reverse in blocks:
            t = arrival[y] - arrival[x]
            w = wsum[y + 1] - wsum[x]
            c = csum[y + 1] - csum[x] - arrival[x] * w
            if reverse:
                first, end, c = p[y], p[x], w * t - c
            else:
                first, end = p[x], p[y]
            if last >= 0:
                lead = total_t + rows[last][first]
                total_c += c + w * lead
                total_t = lead + t
            else:
                total_c, total_t = c, t
            last = end
        return total_c

    def _materialise(self, blocks: Sequence[_Block]) -> list[int]:
        path: list[int] = []
        for x, y, reverse in blocks:
            stretch = self.path[x : y + 1]
            path.extend(reversed(stretch) if reverse else stretch)
        return path

    # --- moves ----------------------------------------------------------------------------------

    def _moves(self, a: int) -> list[list[_Block]]:
        """Candidate rearrangements that bring node `a` next to one of its neighbours: move a
        stretch of 1-3 nodes starting at `a` next to it (either way round), or reverse the
        stretch between them (2-opt)."""
        n = len(self.path) - 1
        i = self.pos[a]
        symmetric = self.matrix.symmetric
        moves: list[list[_Block]] = []
        row = self.rows[a]
        # Only partners nearer than one of a's present neighbours on the path (the usual
        # neighbour-list pruning: a move that makes a longer edge rarely pays).
        reach = max(self.rows[self.path[i - 1]][a], row[self.path[i + 1]] if i < n else 0.0)
        for b in self.neighbours[a]:
            if (row[b] if b != 0 else self.rows[0][a]) >= reach:
                continue
            j = self.pos[b] if b != 0 else 0
            for length in (1, 2, 3):
                e = i + length - 1
                if e > n:
                    break
                for reverse in (False, True) if symmetric and length > 1 else (False,):
                    segment = (i, e, reverse)
                    for after in (j, j - 1):  # the stretch goes right after this position
                        if after < 0 or i - 1 <= after <= e:
                            continue
                        if after < i:
                            blocks = [(0, after, False), segment]
                            if after + 1 <= i - 1:
                                blocks.append((after + 1, i - 1, False))
                            if e < n:
                                blocks.append((e + 1, n, False))
                        else:
                            blocks = [(0, i - 1, False), (e + 1, after, False), segment]
                            if after < n:
                                blocks.append((after + 1, n, False))
                        moves.append(blocks)
            if symmetric and b != 0:
                x, y = min(i, j), max(i, j)
                if y - x >= 2:
                    for lo, hi in ((x + 1, y), (x, y - 1)):
                        if lo < 1:
                            continue
                        blocks = [(0, lo - 1, False), (lo, hi, True)]
                        if hi < n:
                            blocks.append((hi + 1, n, False))
                        moves.append(blocks)
        return moves

    def improve(self, path: Sequence[int], start: Sequence[int] | None = None) -> list[int]:
        """First-improvement local search from `path`, looking at the nodes in `start` first
        (default all) and again at every node a taken move touched. Never returns a worse path."""
        self._load(list(path))
        if len(self.path) <= 2:
            return list(self.path)
        queue = deque(dict.fromkeys(start if start is not None else self.path[1:]))
        queued = [False] * self.matrix.size
        for node in queue:
            queued[node] = True
        while queue:
            if self.deadline is not None and time.perf_counter() > self.deadline:
                break
            a = queue.popleft()
            queued[a] = False
            if a == 0:
                continue
            for blocks in self._moves(a):
                if self._joined(blocks) >= self.current - self.eps:
                    continue
                candidate = self._materialise(blocks)
                if self.batched and self.objective(candidate) >= self.current - self.eps:
                    continue  # the move changed which task ends a batch and is no better
                touched = {self.path[x] for block in blocks for x in block[:2]}
                for x, y, _ in blocks:
                    for k in (x - 1, y + 1):
                        if 0 < k < len(self.path):
                            touched.add(self.path[k])
                self._load(candidate)
                for node in touched:
                    if node != 0 and not queued[node]:
                        queued[node] = True
                        queue.append(node)
                break
        return list(self.path)

    def perturb(self, path: Sequence[int], *, kicks: int, seed: int = 0) -> list[int]:
        """Up to `kicks` rounds of: swap two short neighbouring stretches, repair with
        `improve` from the nodes at the cuts, keep the result if it is no worse."""
        best = list(path)
        self._load(best)
        best_value = self.current
        m = len(best)
        if m < 5:
            return best
        rng = random.Random(seed)
        for _ in range(kicks):
            if self.deadline is not None and time.perf_counter() > self.deadline:
                break
            a = rng.randrange(1, m - 2)
            c_max = min(m, a + 12)
            b = rng.randrange(a + 1, c_max)
            c = rng.randrange(b + 1, c_max + 1) if b + 1 <= c_max else c_max
            kicked = best[:a] + best[b:c] + best[a:b] + best[c:]
            touched = [kicked[k] for k in (a - 1, a, a + c - b - 1, a + c - b, c - 1, c) if k < m]
            candidate = self.improve(kicked, start=touched)
            if self.current <= best_value + self.eps:
                best, best_value = candidate, self.current
        self._load(best)
        return best

    def insert(self, path: Sequence[int], node: int) -> list[int]:
        """`path` with `node` inserted where it raises the objective least."""
        n = len(path) - 1
        # Evaluated with the node appended at the end, then moved: reuse the block algebra.
        self._load([*path, node])
        best_value, best_after = self.current, n
        segment = (n + 1, n + 1, False)
        for after in range(n):
            blocks = [(0, after, False), segment, (after + 1, n, False)]
            value = self._joined(blocks)
            if value < best_value - self.eps:
                best_value, best_after = value, after
        return [*self.path[: best_after + 1], node, *self.path[best_after + 1 : n + 1]]


def greedy_path(matrix: CostMatrix, weights: Sequence[float]) -> list[int]:
    """From node 0, repeatedly the task with the least travel time per unit of weight (the
    lowest node among equals)."""
    inverse = 1.0 / np.maximum(np.asarray(weights, dtype=np.float64), 1e-12)
    inverse[0] = 1.0  # node 0 is on the path from the start
    path = [0]
    here = 0
    for _ in range(matrix.size - 1):
        ratio = matrix.values[here] * inverse
        ratio[path] = np.inf
        here = int(np.argmin(ratio))
        path.append(here)
    return path


def exact_path(
    matrix: CostMatrix, weights: Sequence[float], groups: Sequence[int]
) -> tuple[list[int], float]:
    """The path of least objective and its value, by dynamic programming over subsets: the
    edge leaving a set S of visited tasks delays every group not complete in S, so
    F = sum over edges of travel time * weight of the groups not yet complete. O(2^n n^2):
    meant for n <= 10."""
    n = matrix.size - 1
    if n == 0:
        return [0], 0.0
    values = matrix.values
    members: dict[int, int] = {}
    group_weight: dict[int, float] = {}
    for node in range(1, n + 1):
        members[groups[node]] = members.get(groups[node], 0) | (1 << (node - 1))
        group_weight[groups[node]] = weights[node]
    full = (1 << n) - 1
    masks = np.arange(full + 1)
    # Weight still waiting once the tasks in `mask` are done.
    waiting = np.zeros(full + 1, dtype=np.float64)
    for group, bits in members.items():
        waiting += group_weight[group] * ((masks & bits) != bits)
    best = np.full((full + 1, n), np.inf)
    parent = np.full((full + 1, n), -1, dtype=np.intp)
    columns = np.arange(n)
    bit = 1 << columns
    best[bit, columns] = values[0, 1:] * waiting[0]
    tasks = values[1:, 1:]
    # Every entry of best[S] comes from S less one task, so a whole layer of sets of k tasks
    # can go at once, from every last task i to every next task j (the lowest i among equals):
    # each (S + j, j) has the one source S.
    size = np.zeros(full + 1, dtype=np.intp)
    for j in range(n):
        size += (masks >> j) & 1
    for k in range(1, n):
        layer = masks[size == k]
        through = best[layer][:, :, None] + tasks[None, :, :] * waiting[layer][:, None, None]
        via = through.argmin(axis=1)
        reached = np.take_along_axis(through, via[:, None, :], axis=1)[:, 0, :]
        targets = layer[:, None] | bit[None, :]
        js = np.broadcast_to(columns, targets.shape)
        better = ((layer[:, None] & bit[None, :]) == 0) & (reached < best[targets, js])
        best[targets[better], js[better]] = reached[better]
        parent[targets[better], js[better]] = via[better]
    last = int(np.argmin(best[full]))
    value = float(best[full, last])
    path = []
    mask = full
    while last >= 0:
        path.append(last + 1)
        previous = int(parent[mask, last])
        mask &= ~(1 << last)
        last = previous
    return [0, *reversed(path)], value


def insertion_cost(
    cost: CostFn, start: Position, route: Sequence[Position], position: Position
) -> float:
    """What adding a task at `position` to a vehicle at `start` that will serve `route` in this
    order costs the customers, in the units of `cost` (seconds for `TravelTime`): the new task's
    own wait plus the delay it causes the tasks after it, at the place in the route where that
    sum is least (the route's order is kept)."""
    return best_insertion(cost, start, route, position)[0]


def best_insertion(
    cost: CostFn, start: Position, route: Sequence[Position], position: Position
) -> tuple[float, float]:
    """`insertion_cost`, and the new task's own wait at that place (when the vehicle would
    reach it, in the units of `cost`)."""
    stops = [start, *route]
    arrival = 0.0
    best, wait = math.inf, math.inf
    for k, here in enumerate(stops):
        if k > 0:
            arrival += cost(stops[k - 1], here)
        to_new = cost(here, position)
        if k + 1 < len(stops):
            after = stops[k + 1]
            detour = to_new + cost(position, after) - cost(here, after)
            value = arrival + to_new + detour * (len(stops) - k - 1)
        else:
            value = arrival + to_new
        if value < best:
            best, wait = value, arrival + to_new
    return best, wait
