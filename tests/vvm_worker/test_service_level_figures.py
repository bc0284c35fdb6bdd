"""The figures of service levels (vvm_worker.level_figures): percentiles, per-class stats, and
when admission should hold a class."""

from __future__ import annotations

import pytest

from vvm_worker.level_figures import (
    NO_CLASS,
    ServiceClassSpec,
    level_stats,
    misses_target,
    percentile,
)

PREMIUM = ServiceClassSpec("premium", 30.0, 5.0)


def test_a_percentile_is_a_latency_some_request_really_had() -> None:
    values = [float(v) for v in range(1, 101)]
    assert percentile(values, 50) == 50.0
    assert percentile(values, 95) == 95.0
    assert percentile([7.0], 95) == 7.0
    with pytest.raises(ValueError, match="no values"):
        percentile([], 50)


def test_a_class_refuses_a_bad_target_or_weight_saying_which() -> None:
    with pytest.raises(ValueError, match="p95_s: a positive number"):
        ServiceClassSpec("x", 0.0)
    with pytest.raises(ValueError, match="weight: a positive number"):
        ServiceClassSpec("x", 10.0, float("nan"))


def test_stats_per_customer_and_class_with_the_share_within_target() -> None:
    rows = [("acme", PREMIUM, float(s)) for s in (10, 20, 25, 40)]
    rows += [("bob", NO_CLASS, 100.0), ("bob", NO_CLASS, 300.0)]
    bob, acme = level_stats(rows)  # by class name ("none" before "premium"), then customer
    assert (acme.customer, acme.service_class, acme.requests) == ("acme", "premium", 4)
    assert (acme.median_s, acme.p95_s, acme.within_target) == (20.0, 40.0, 0.75)
    assert acme.meets_target is False
    assert (bob.within_target, bob.meets_target, bob.p95_s) == (None, None, 300.0)
    assert bob.as_dict()["target_p95_s"] is None


def test_admission_holds_a_class_only_when_enough_recent_figures_miss_its_target() -> None:
    fast = [5.0] * 30
    assert not misses_target(30.0, recent_latencies=fast)
    assert misses_target(30.0, recent_latencies=fast[:20], open_ages=[45.0] * 5)
    assert not misses_target(30.0, recent_latencies=[90.0] * 5)  # too few to say
    assert not misses_target(None, recent_latencies=[900.0] * 50)  # no target, never held
