"""Drive a VV program through its steps the way the VVM does, with made-up readings."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from vvm_worker.runtime import (
    Limits,
    Outcome,
    PendingRequest,
    StepInput,
    StepResult,
    answer_part,
    answer_reject,
    answer_task,
    run_step,
)

CATALOG = [
    {"name": "CO2", "kind": "scalar", "unit": "ppm", "params": {"quantity": "co2"}},
    {"name": "Thermometer", "kind": "scalar", "unit": "°C", "params": {"quantity": "temperature"}},
    {"name": "GPS", "kind": "gps", "unit": "deg", "params": {}},
    {
        "name": "Camera 640x480",
        "kind": "camera",
        "unit": "",
        "params": {"width": 640, "height": 480},
    },
]
START_MS = 1_735_689_600_000

Answer = Callable[[PendingRequest, int], dict[str, Any]]


def reading(sensor: str, k: int, task: Any) -> dict[str, Any]:
    return {
        "sensor": sensor,
        "kind": "scalar",
        "time": "t",
        "position": {"lat": task.lat, "lng": task.lng, "alt": task.alt},
        "value": k,
    }


def answer_with_readings(pending: PendingRequest, time_ms: int) -> dict[str, Any]:
    """Answer a task with readings whose value is the request's ordinal."""
    if pending.kind == "batch":
        i = pending.open[-1]  # serve batches from the back: the VVM picks the order
        task = pending.tasks[i]
        data = [reading(s, i, task) for s in task.sensors]
        return answer_part(pending, index=i, time_ms=time_ms, data=data)
    task = pending.tasks[0]
    return answer_task(
        pending, time_ms=time_ms, data=[reading(s, pending.q, task) for s in task.sensors]
    )


@dataclass
class Run:
    """A VV's checkpoint and what the platform applied of its effects."""

    source: str
    seed: int = 7
    limits: Limits = field(default_factory=Limits)
    journal: list[dict[str, Any]] = field(default_factory=list)
    effects_applied: int = 0
    storage: dict[str, Any] = field(default_factory=dict)
    log: list[str] = field(default_factory=list)
    results: list[StepResult] = field(default_factory=list)
    replay_s: float = 0.0

    def step(self) -> StepResult:
        result = run_step(
            StepInput(
                vv_id="vv-1",
                vv_name="VV 1",
                source=self.source,
                seed=self.seed,
                start_ms=START_MS,
                catalog=CATALOG,
                journal=list(self.journal),
                effects_applied=self.effects_applied,
                limits=self.limits,
                replay_s=self.replay_s,
            )
        )
        for effect in result.effects:
            assert effect.seq >= self.effects_applied, "an effect was reported twice"
            if effect.op == "store":
                self.storage[effect.key] = json.loads(effect.value_json)
            elif effect.op == "remove":
                self.storage.pop(effect.key, None)
            else:
                self.log.append(effect.message)
        self.effects_applied = max(self.effects_applied, result.effects_total)
        self.replay_s = result.replay_time(self.replay_s)
        self.results.append(result)
        return result

    def run(
        self,
        *,
        answer: Answer = answer_with_readings,
        max_steps: int = 500,
        migrate: Callable[[Run], Run] | None = None,
    ) -> StepResult:
        """Step until the program ends; answer each pending request one second apart."""
        for n in range(max_steps):
            result = self.step()
            if result.outcome is not Outcome.SUSPENDED:
                return result
            assert result.pending is not None
            self.journal.append(answer(result.pending, START_MS + 1000 * (n + 1)))
            if migrate is not None:
                moved = migrate(self)
                self.__dict__.update(moved.__dict__)
        raise AssertionError("the program did not end")


def reject_all(message: str = "outside every operation area") -> Answer:
    def answer(pending: PendingRequest, time_ms: int) -> dict[str, Any]:
        return answer_reject(pending, time_ms=time_ms, message=message)

    return answer


def through_json(run: Run) -> Run:
    """A migration: the checkpoint goes through the database as JSON to another host."""
    return Run(
        source=run.source,
        seed=run.seed,
        limits=run.limits,
        journal=json.loads(json.dumps(run.journal)),
        effects_applied=run.effects_applied,
        storage=run.storage,
        log=run.log,
        results=run.results,
        replay_s=run.replay_s,
    )
