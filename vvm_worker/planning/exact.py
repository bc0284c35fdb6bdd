"""Exact minimum-cost open paths: Held-Karp for small sets, branch and bound above.

The problem: start at node 0 of a `CostMatrix` (the vehicle), visit every other node once,
end anywhere, minimise the total cost. It is NP-hard; the gated-TSP planner solves it for at
most 30 tasks.

- Held-Karp dynamic programming, vectorised with numpy, costs O(2^n * n^2) time and
  O(2^n * n) memory: about 20 ms at 15 tasks, doubling with every further task, so it is
  used up to `HELD_KARP_LIMIT` tasks.
- Above that, a depth-first branch and bound over path prefixes. Its lower bound is the
  Held-Karp 1-tree bound (a minimum spanning tree plus a dummy end node, with node penalties
  tuned by subgradient optimisation), usually within 1% of the optimum at the root. The
  first incumbent comes from nearest neighbour + 2-opt/Or-opt with restarts, so the search
  mostly proves optimality. Prefixes that reach the same set and last node at no lower cost,
  or that a reversal of part of them would make cheaper, are pruned. Measured at 30 tasks
  with geographic costs: 10-150 ms and at most a few hundred search nodes; a `node_limit`
  stops pathological cases (then the result says it is not exact).

Asymmetric costs are handled exactly (see `_BranchAndBound` for how the bound copes with
them). "Exact" means up to floating-point rounding: subtrees whose bound is within 1e-9
(relative) of the incumbent are not explored.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .costs import CostMatrix
from .heuristics import greedy_chain, improve_with_restarts, path_cost

HELD_KARP_LIMIT = 15
"""Largest number of tasks solved by Held-Karp (about 20 ms; twice that per extra task)."""

NODE_LIMIT = 50_000
"""Safety net of the branch and bound: search nodes expanded before it gives up and returns
the best path found, marked not exact. Deterministic, unlike a wall-clock limit. Geometric
costs need at most a few hundred nodes at 30 tasks (measured); a node takes about 0.3 ms, so
the limit only ends searches over costs without geometry (e.g. random tables) after ~15 s."""

_LEAF_SIZE = 4  # remaining tasks that are cheaper to enumerate than to bound

# Subgradient schedule (Held, Wolfe and Crowder): step = scale * (incumbent - bound) / |g|^2,
# the scale halved after `patience` steps without a better bound. Halving too eagerly stalls
# the bound several percent short on clustered task sets (measured), so the root is patient.
_ROOT_ITERATIONS = 1000  # at most, at the root, where the penalties start from zero
_ROOT_PATIENCE = 30
_NODE_ITERATIONS = 30  # at most, per search node, warm-started from the parent's penalties
_NODE_PATIENCE = 5
_NODE_SCALE = 1.0
_MIN_SCALE = 1e-4

IntArray = NDArray[np.intp]
FloatArray = NDArray[np.float64]


@dataclass(frozen=True, slots=True)
class ExactResult:
    """An open path from node 0 and how it was found.

    `path` lists node indices starting with 0; `cost` is its total cost; `exact` is False only
    when the branch and bound hit its node limit (the path is then the best one found);
    `method` is "trivial", "held-karp" or "branch-and-bound"; `nodes` counts search nodes.
    """

    path: list[int]
    cost: float
    exact: bool
    method: str
    nodes: int = 0


def solve_open_path(
    matrix: CostMatrix,
    *,
    held_karp_limit: int = HELD_KARP_LIMIT,
    node_limit: int = NODE_LIMIT,
) -> ExactResult:
    """The minimum-cost open path from node 0 through every node of `matrix`.

    Uses Held-Karp up to `held_karp_limit` tasks and branch and bound above, which stops after
    `node_limit` search nodes (then `exact` is False). Deterministic. Among equally cheap
    paths, Held-Karp returns the one whose first node (then second, ...) has the lowest index;
    branch and bound keeps the first it finds.
    """
    n = matrix.size - 1
    if n <= 2:
        paths = [[0, *perm] for perm in itertools.permutations(range(1, n + 1))]
        best = min(paths, key=lambda path: path_cost(matrix, path))
        return ExactResult(best, path_cost(matrix, best), exact=True, method="trivial")
    if n <= held_karp_limit:
        path, cost = held_karp(matrix)
        return ExactResult(path, cost, exact=True, method="held-karp")
    search = _BranchAndBound(matrix, node_limit)
    search.run()
    return ExactResult(
        search.best_path,
        path_cost(matrix, search.best_path),
        exact=not search.stopped,
        method="branch-and-bound",
        nodes=search.nodes,
    )


def held_karp(matrix: CostMatrix) -> tuple[list[int], float]:
    """Held-Karp dynamic programming: the optimal open path from node 0 and its cost.

    rest[S, j] is the cheapest path that starts at task j and visits the task set S (j not
    in S), ending anywhere. Sets are processed by size, all sets of one size at once as a
    min-plus product. Built from the end, so that among equally cheap paths the one whose
    first task (then second, ...) has the lowest index wins. Needs about 10 * 2^n * n bytes
    (5 MB at 15 tasks) and doubles its time with every task: keep n at 16 or below.
    """
    values = matrix.values
    n = matrix.size - 1
    if n == 0:
        return [0], 0.0
    tasks = values[1:, 1:]
    full = 1 << n
    bits = 1 << np.arange(n, dtype=np.int64)
    rest = np.full((full, n), np.inf)
    rest[0, :] = 0.0
    choice = np.full((full, n), -1, dtype=np.int8)
    masks = np.arange(full, dtype=np.int64)
    member = (masks[:, None] & bits[None, :]) != 0
    sizes = member.sum(axis=1)
    for size in range(1, n):
        layer = masks[sizes == size]
        inside = member[layer]
        # reached[s, k]: best path from k through the rest of set s once k is taken out.
        reached = np.where(inside, rest[layer[:, None] ^ bits[None, :], np.arange(n)], np.inf)
        for j in range(n):
            # Paths may not start inside their own set.
            outside = ~inside[:, j]
            candidates = reached[outside] + tasks[j]
            picked = candidates.argmin(axis=1)
            sets = layer[outside]
            rest[sets, j] = candidates[np.arange(sets.size), picked]
            choice[sets, j] = picked
    totals = values[0, 1:] + rest[(full - 1) ^ bits, np.arange(n)]
    first = int(np.argmin(totals))
    path = [0, first + 1]
    remaining = (full - 1) ^ (1 << first)
    here = first
    while remaining:
        following = int(choice[remaining, here])
        path.append(following + 1)
        remaining ^= 1 << following
        here = following
    return path, float(totals[first])


def _prim(weights: FloatArray) -> tuple[float, IntArray]:
    """Minimum spanning tree of a dense graph: total weight and each node's parent (root 0)."""
    size = weights.shape[0]
    parent = np.zeros(size, dtype=np.intp)
    best = weights[0].copy()
    best[0] = np.inf
    done = np.zeros(size, dtype=bool)
    done[0] = True
    total = 0.0
    for _ in range(size - 1):
        j = int(np.argmin(best))
        total += float(best[j])
        done[j] = True
        best[j] = np.inf
        row = weights[j]
        closer = (row < best) & ~done
        best[closer] = row[closer]
        parent[closer] = j
    return total, parent


class _BranchAndBound:
    """Depth-first branch and bound over path prefixes with the Held-Karp 1-tree bound.

    A search node is a prefix: the last node v, the set U still to visit and the cost g so
    far. Its bound is g plus a lower bound on the cheapest path from v through U: a minimum
    spanning tree over {v} + U plus a dummy end node joined to v and to one node of U, with
    Lagrangian node penalties that push every degree towards 2.

    Asymmetric costs are first brought as close to symmetric as a node potential phi allows:
    c'(a, b) = c(a, b) + phi(a) - phi(b) changes a path's cost only by phi(start) - phi(end),
    which the dummy end's edges carry. Costs that are asymmetric because climbing costs more
    than descending become exactly symmetric this way; what is left is symmetrised with
    min(c'(a, b), c'(b, a)).
    """

    def __init__(self, matrix: CostMatrix, node_limit: int) -> None:
        values = matrix.values
        self.values = values
        self.symmetric = matrix.symmetric
        size = matrix.size
        self.potential = np.zeros(size)
        reduced = values.copy()
        if not matrix.symmetric:
            block = values[1:, 1:]
            # Least-squares potential: phi(a) = -mean over b of (c(a, b) - c(b, a)) / 2.
            self.potential[1:] = -((block - block.T) / 2.0).sum(axis=1) / (size - 1)
            reduced = values + self.potential[:, None] - self.potential[None, :]
            reduced[1:, 1:] = np.minimum(reduced[1:, 1:], reduced[1:, 1:].T)
        self.reduced = reduced
        self.node_limit = node_limit
        self.nodes = 0
        self.stopped = False
        self.best_path = improve_with_restarts(matrix, greedy_chain(matrix), rounds=20)
        self.best_cost = path_cost(matrix, self.best_path)
        self.tol = 1e-9 * self.best_cost + 1e-12
        self.seen: dict[tuple[int, int], float] = {}

    def run(self) -> None:
        size = self.values.shape[0]
        penalties = np.zeros(size)
        self._search(0, list(range(1, size)), 0, 0.0, penalties, [0], [0.0], root=True)

    def _offer(self, path: list[int], cost: float) -> None:
        if cost < self.best_cost - self.tol:
            self.best_path, self.best_cost = path, cost

    def _search(
        self,
        v: int,
        rest: list[int],
        mask: int,
        g: float,
        penalties: FloatArray,
        prefix: list[int],
        prefix_rev: list[float],
        *,
        root: bool = False,
    ) -> None:
        self.nodes += 1
        if self.nodes > self.node_limit:
            self.stopped = True
            return
        values = self.values
        if len(rest) <= _LEAF_SIZE:
            self._solve_leaf(v, rest, g, prefix)
            return
        idx = np.asarray([v, *rest], dtype=np.intp)
        tightened = self._tighten(idx, g, penalties[idx].copy(), prefix, root=root)
        if tightened is None:
            return
        node_penalties = penalties.copy()
        node_penalties[idx] = tightened

        # Children bounds from one spanning tree over `rest` with the tuned penalties: a child
        # that starts at u pays c(v, u), the tree, u's link to the dummy end and the cheapest
        # other link to it.
        rest_idx = idx[1:]
        p = tightened[1:]
        phi = self.potential[rest_idx]
        weights = self.reduced[np.ix_(rest_idx, rest_idx)] + p[:, None] + p[None, :]
        tree, _ = _prim(weights)
        end_links = phi + p
        two_lowest = np.partition(end_links, 1)[:2]
        other_end = np.where(end_links == two_lowest[0], two_lowest[1], two_lowest[0])
        child_bounds = values[v, rest_idx] + tree + (p - phi) + other_end - 2.0 * p.sum()
        order = np.lexsort((np.arange(len(rest)), child_bounds))
        for k in order.tolist():
            if self.stopped:
                return
            if g + float(child_bounds[k]) >= self.best_cost - self.tol:
                break
            u = rest[k]
            g_child = g + float(values[v, u])
            key = (mask | (1 << u), u)
            if self.seen.get(key, np.inf) <= g_child:
                continue
            self.seen[key] = g_child
            if self._reversal_shortens(prefix, prefix_rev, u):
                continue
            self._search(
                u,
                rest[:k] + rest[k + 1 :],
                mask | (1 << u),
                g_child,
                node_penalties,
                [*prefix, u],
                [*prefix_rev, prefix_rev[-1] + float(values[u, v] - values[v, u])],
            )

    def _tighten(
        self, idx: IntArray, g: float, p: FloatArray, prefix: list[int], *, root: bool
    ) -> FloatArray | None:
        """Subgradient optimisation of the penalties at one node.

        Returns the best penalties found, or None when the node is done: its bound reaches the
        incumbent, or the bound's tree is itself a path that is optimal for the node.
        """
        base = self.reduced[np.ix_(idx, idx)]
        v_potential = float(self.potential[idx[0]])
        # Edges out of the prefix's last node are flown in that direction only.
        base[0, 1:] = base[1:, 0] = self.reduced[idx[0], idx[1:]]
        phi = self.potential[idx[1:]]
        best_bound = -np.inf
        best_p = p
        iterations, patience, step_scale = (
            (_ROOT_ITERATIONS, _ROOT_PATIENCE, 2.0)
            if root
            else (_NODE_ITERATIONS, _NODE_PATIENCE, _NODE_SCALE)
        )
        since_better = 0
        for _ in range(iterations):
            tree, parent = _prim(base + p[:, None] + p[None, :])
            end = 1 + int(np.argmin(phi + p[1:]))
            bound = (
                tree
                + float(p[0] - v_potential)
                + float(phi[end - 1] + p[end])
                - 2.0 * float(p.sum())
            )
            if bound > best_bound + self.tol:
                best_bound, best_p, since_better = bound, p.copy(), 0
            else:
                since_better += 1
                if since_better >= patience:
                    step_scale /= 2.0
                    since_better = 0
                    if step_scale < _MIN_SCALE:
                        break
            if g + best_bound >= self.best_cost - self.tol:
                return None
            degrees = np.bincount(parent[1:], minlength=idx.size)
            degrees[1:] += 1
            degrees[0] += 1
            degrees[end] += 1
            gradient = degrees - 2
            if not gradient.any():
                path = self._tree_path(parent, idx)
                cost = g + path_cost_of(self.values, [int(idx[0]), *path])
                self._offer([*prefix, *path], cost)
                if cost <= g + bound + self.tol:
                    return None
                # Only asymmetric costs get here: the path is not proven optimal.
                break
            norm = float(gradient @ gradient)
            p = p + step_scale * (self.best_cost - g - bound) / norm * gradient
        return best_p

    @staticmethod
    def _tree_path(parent: IntArray, idx: IntArray) -> list[int]:
        """The nodes after the root of a spanning tree that is a path from its root."""
        size = idx.size
        child = [-1] * size
        for node in range(1, size):
            child[int(parent[node])] = node
        path = []
        node = child[0]
        while node >= 0:
            path.append(int(idx[node]))
            node = child[node]
        return path

    def _reversal_shortens(self, prefix: list[int], prefix_rev: list[float], u: int) -> bool:
        """Whether reversing a stretch of prefix + [u] (both ends kept) makes it cheaper.

        Such a prefix reaches the same set and the same last node at a lower cost, so no
        optimal path starts with it. prefix_rev[t] is the cost change of reversing the edges
        of prefix[0..t] (all zero for symmetric costs).
        """
        if len(prefix) < 3:
            return False
        values = self.values
        nodes = np.asarray(prefix, dtype=np.intp)
        v = prefix[-1]
        before, first = nodes[:-2], nodes[1:-1]
        delta = values[before, v] + values[first, u] - values[before, first] - values[v, u]
        if not self.symmetric:
            rev = np.asarray(prefix_rev)
            delta = delta + (rev[-1] - rev[1:-1])
        return bool((delta < -self.tol).any())

    def _solve_leaf(self, v: int, rest: list[int], g: float, prefix: list[int]) -> None:
        values = self.values
        for perm in itertools.permutations(rest):
            cost = g
            here = v
            for node in perm:
                cost += values[here, node]
                here = node
            if cost < self.best_cost - self.tol:
                self._offer([*prefix, *perm], float(cost))


def path_cost_of(values: FloatArray, path: list[int]) -> float:
    """Total cost of a path of node indices through a raw cost array."""
    if len(path) < 2:
        return 0.0
    idx = np.asarray(path, dtype=np.intp)
    return float(values[idx[:-1], idx[1:]].sum())
