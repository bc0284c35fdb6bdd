"""Service levels, the figures (pure; the database side is services/service_levels.py): a
customer's class (a p95 target for the time from a task's request to its reading, and a
weight the planners give its requests), and the figures that show whether the fleet keeps it.

Pure Python (no Django): the services read tasks from the database and hand their latencies
here; `simulate` and the benchmark hand theirs from the simulation.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

__all__ = [
    "NO_CLASS",
    "NO_CLASS_TERMS",
    "ClassTerms",
    "LevelStats",
    "ServiceClassSpec",
    "level_stats",
    "misses_target",
    "percentile",
]


@dataclass(frozen=True)
class ServiceClassSpec:
    """A service class: ``name``, ``p95_s`` (target, seconds; None: no target) and ``weight``
    (> 0; 1 weighs a request like one of a customer without a class). Raises ValueError on a
    bad value, saying which."""

    name: str
    p95_s: float | None
    weight: float = 1.0

    def __post_init__(self) -> None:
        if not self.name or len(self.name) > 60:
            raise ValueError("name: 1 to 60 characters")
        if self.p95_s is not None and not (math.isfinite(self.p95_s) and self.p95_s > 0):
            raise ValueError(f"p95_s: a positive number of seconds, got {self.p95_s!r}")
        if not (math.isfinite(self.weight) and self.weight > 0):
            raise ValueError(f"weight: a positive number, got {self.weight!r}")


@dataclass(frozen=True)
class ClassTerms:
    """What a VV's customer's service class asks of an RV: how much a second of its waiting
    weighs, and the target its requests are to be read within (None: no class, no target);
    ``class_id``: which class it is (None: none), for the mapper's reserve."""

    weight: float = 1.0
    target_s: float | None = None
    class_id: int | None = None

    @classmethod
    def of(
        cls, weight: float | None, target_s: float | None, class_id: int | None = None
    ) -> ClassTerms:
        """From a class's columns as read (all None: the customer has no class)."""
        return cls(1.0 if weight is None else float(weight), target_s, class_id)

    def deadline(self, requested_s: float) -> float | None:
        """When a request made at ``requested_s`` is to be read by (None: no target)."""
        return None if self.target_s is None else requested_s + self.target_s

    def due_in(self, requested_s: float, now_s: float) -> float | None:
        """How long from ``now_s`` that request has until its deadline (None: no target)."""
        deadline = self.deadline(requested_s)
        return None if deadline is None else deadline - now_s


NO_CLASS_TERMS = ClassTerms()


# What a customer without a class gets: no target, the weight of everybody.
NO_CLASS = ServiceClassSpec("none", None, 1.0)


def percentile(values: Sequence[float], q: float) -> float:
    """The ``q``-th percentile (0-100) of ``values`` by the nearest-rank method (the smallest
    value with at least q % of the values at or below it): a latency some request really had.
    Raises ValueError on an empty sequence or a q outside 0-100."""
    if not values:
        raise ValueError("no values")
    if not 0 <= q <= 100:
        raise ValueError(f"q must be between 0 and 100, got {q!r}")
    ordered = sorted(values)
    rank = max(1, math.ceil(q / 100 * len(ordered)))
    return ordered[rank - 1]


@dataclass(frozen=True)
class LevelStats:
    """One customer's figures in one class over a period: ``requests`` read, ``median_s`` and
    ``p95_s`` of their latencies, ``within_target`` (the share read within the class's target,
    0-1; None without a target) and ``meets_target`` (p95 within target; None without one)."""

    customer: str
    service_class: str
    target_p95_s: float | None
    requests: int
    median_s: float
    p95_s: float
    within_target: float | None

    @property
    def meets_target(self) -> bool | None:
        if self.target_p95_s is None:
            return None
        return self.p95_s <= self.target_p95_s

    def as_dict(self) -> dict[str, object]:
        return {
            "customer": self.customer,
            "service_class": self.service_class,
            "target_p95_s": self.target_p95_s,
            "requests": self.requests,
            "median_s": round(self.median_s, 3),
            "p95_s": round(self.p95_s, 3),
            "within_target": None if self.within_target is None else round(self.within_target, 4),
            "meets_target": self.meets_target,
        }


def level_stats(
    latencies: Iterable[tuple[str, ServiceClassSpec, float]],
) -> list[LevelStats]:
    """Figures per (customer, class) from ``(customer, class, latency_s)`` rows, sorted by
    class name then customer. A latency is a task's reading time minus its request time."""
    groups: dict[tuple[str, ServiceClassSpec], list[float]] = {}
    for customer, spec, latency in latencies:
        groups.setdefault((customer, spec), []).append(latency)
    stats = []
    for (customer, spec), values in groups.items():
        within = None
        if spec.p95_s is not None:
            within = sum(1 for v in values if v <= spec.p95_s) / len(values)
        stats.append(
            LevelStats(
                customer=customer,
                service_class=spec.name,
                target_p95_s=spec.p95_s,
                requests=len(values),
                median_s=percentile(values, 50),
                p95_s=percentile(values, 95),
                within_target=within,
            )
        )
    stats.sort(key=lambda s: (s.service_class, s.customer))
    return stats


def misses_target(
    target_p95_s: float | None,
    *,
    recent_latencies: Sequence[float],
    open_ages: Sequence[float] = (),
    min_samples: int = 20,
) -> bool:
    """Whether the fleet is already missing a class's target, so admission should hold new
    VVs of the class: the p95 over the class's recent readings (``recent_latencies``) and its
    tasks still open (``open_ages``, how long each has waited so far: at least that late) is
    beyond the target. Fewer than ``min_samples`` of both together say nothing yet (False),
    as does a class without a target."""
    if target_p95_s is None:
        return False
    values = [*recent_latencies, *open_ages]
    if len(values) < min_samples:
        return False
    return percentile(values, 95) > target_p95_s
