"""What goes into a VV step and what comes out of it (plain data, no Django)."""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

JSON = Any


class Outcome(enum.StrEnum):
    """How a step ended."""

    SUSPENDED = "suspended"  # waiting for the answer to `pending`
    FINISHED = "finished"  # the program ran to its end
    FAILED = "failed"  # the program threw, has a syntax error, or is not deterministic
    KILLED = "killed"  # the program went over a quota


class ErrorKind(enum.StrEnum):
    SYNTAX = "syntax"
    RUNTIME = "runtime"
    QUOTA = "quota"
    NONDETERMINISM = "nondeterminism"
    PLATFORM = "platform"


# The VVM-API calls a customer's VVs may be limited to (the names prelude.js checks with
# allowed(...)).
VVM_API_CALLS = (
    "image.crop",
    "image.fraction",
    "image.resize",
    "image.stats",
    "log",
    "message.receive",
    "message.send",
    "sensor.get",
    "sensor.list",
    "storage.list",
    "storage.load",
    "storage.remove",
    "storage.store",
    "task.execute",
    "task.executeAll",
)


@dataclass(frozen=True, slots=True)
class Limits:
    """The quotas a step enforces (DESIGN.md section 2)."""

    cpu_s: float = 2.0  # CPU time of the new work in one step
    heap_bytes: int = 64 * 1024 * 1024
    storage_bytes: int = 10 * 1024 * 1024
    max_tasks: int = 10_000
    allowed_calls: frozenset[str] | None = None  # None: every VVM-API call
    max_messages: int = 1000  # messages a VV may send (VV.message.send)
    message_bytes: int = 65536  # UTF-8 bytes of one message's JSON text

    def __post_init__(self) -> None:
        if (
            self.cpu_s <= 0
            or self.heap_bytes <= 0
            or self.storage_bytes < 0
            or self.max_tasks < 0
            or self.max_messages < 0
            or self.message_bytes < 0
        ):
            raise ValueError(f"invalid limits: {self!r}")


@dataclass(frozen=True, slots=True)
class StepInput:
    """Everything a step needs: the checkpoint (program + journal) and the VV's context.

    ``journal`` holds the answers the VVM-API gave so far, in order (as objects or as JSON
    text, as a database keeps them); ``effects_applied`` is how
    many of the program's effects (storage writes, log lines) the platform has already applied.
    ``start_ms`` is the VV's logical time before its first answer; ``replay_s`` how long
    running the program from its first line to where it waits takes (``StepResult.replay_time``
    of the last step): a step that has to replay gets that long again, twice, on top of its
    CPU quota; a step that resumes where the program waits gets the quota alone.
    ``cpu_spent_s`` is the CPU the VV already used since it last waited for the outside world
    (its steps in between and the host's work for its image calls and messages): it is taken
    off the quota (``cpu_allowance_s``). It is not part of what a warm context compares to
    decide whether it may resume. ``picture_bytes`` is what the pictures the VV made take: its
    storage may use the quota's ``storage_bytes`` less that.
    """

    vv_id: str
    vv_name: str
    source: str
    seed: int
    start_ms: int
    catalog: Sequence[Mapping[str, JSON]]
    journal: Sequence[Mapping[str, JSON] | str] = ()  # entries, or their JSON text
    effects_applied: int = 0
    limits: Limits = field(default_factory=Limits)
    replay_s: float = 0.0
    cpu_spent_s: float = 0.0
    picture_bytes: int = 0

    @property
    def cpu_allowance_s(self) -> float:
        """The CPU time the step's new work may take: the quota less what the VV already used
        since it last waited for the outside world, never below 1 ms."""
        return max(self.limits.cpu_s - self.cpu_spent_s, 0.001)


@dataclass(frozen=True, slots=True)
class TaskRequest:
    """One point task as the program asked for it."""

    lat: float
    lng: float
    alt: float
    tolerance_m: float
    sensors: tuple[str, ...]

    @classmethod
    def from_json(cls, data: Mapping[str, JSON]) -> TaskRequest:
        pos = data["position"]
        return cls(
            lat=float(pos["lat"]),
            lng=float(pos["lng"]),
            alt=float(pos["alt"]),
            tolerance_m=float(data["tolerance"]),
            sensors=tuple(str(s) for s in data["sensors"]),
        )


@dataclass(frozen=True, slots=True)
class PendingRequest:
    """The VVM-API call the program is blocked in.

    ``kind`` is "task" (``VV.task.execute``), "batch" (``VV.task.executeAll``), "call" (a
    call the host answers at once: ``op`` is "message.send", "image.stats", "image.fraction",
    "image.crop" or "image.resize" and ``args`` its arguments as the prelude checked them) or
    "message" (``VV.message.receive``, waiting at most ``timeout_s`` seconds); ``q`` the
    request's ordinal, which its journal answers carry; ``fingerprint`` the request as the
    program made it, kept in the journal to detect a non-deterministic program on replay (None
    when a batch already has answers); ``tasks`` the tasks asked for (none for "call" and
    "message"); ``open`` the batch indexes still without an answer; ``line`` and ``column``
    where in the program the call is made, when the step that made the request reports it
    (the row keeps neither: ``to_json``).
    """

    kind: str
    q: int
    fingerprint: str | None
    tasks: tuple[TaskRequest, ...]
    open: tuple[int, ...]
    op: str | None = None
    # A dict cannot be hashed: equal requests still hash alike without it.
    args: dict[str, Any] | None = field(default=None, hash=False)
    timeout_s: float | None = None
    # Where it was asked for says nothing of what was asked: not compared.
    line: int | None = field(default=None, compare=False)
    column: int | None = field(default=None, compare=False)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> PendingRequest:
        """The request as the prelude reports it and the VV's row keeps it (``to_json``)."""
        tasks = tuple(TaskRequest.from_json(t) for t in data.get("tasks", ()))
        op = data.get("op")
        args = data.get("args")
        timeout_s = data.get("timeout_s")
        return cls(
            kind=str(data["kind"]),
            q=int(data["q"]),
            fingerprint=data.get("r"),
            tasks=tasks,
            open=tuple(int(i) for i in data.get("open", range(len(tasks)))),
            op=None if op is None else str(op),
            args=None if args is None else dict(args),
            timeout_s=None if timeout_s is None else float(timeout_s),
        )

    def to_json(self) -> dict[str, Any]:
        # A task's or a batch's JSON stays as it was before calls and messages existed.
        extra: dict[str, Any] = {}
        if self.op is not None:
            extra["op"] = self.op
        if self.args is not None:
            extra["args"] = self.args
        if self.timeout_s is not None:
            extra["timeout_s"] = self.timeout_s
        return {
            "kind": self.kind,
            "q": self.q,
            "r": self.fingerprint,
            "tasks": [
                {
                    "position": {"lat": t.lat, "lng": t.lng, "alt": t.alt},
                    "tolerance": t.tolerance_m,
                    "sensors": list(t.sensors),
                }
                for t in self.tasks
            ],
            "open": list(self.open),
            **extra,
        }


@dataclass(frozen=True, slots=True)
class Effect:
    """Something the program did that the platform must apply once: store, remove or log."""

    seq: int
    op: str
    time_ms: int
    key: str | None = None
    value_json: str | None = None
    message: str | None = None


@dataclass(frozen=True, slots=True)
class VVError:
    """Why a VV failed or was killed, with the place in the user's program when known."""

    kind: ErrorKind
    message: str
    line: int | None = None
    column: int | None = None
    quota: str | None = None

    def __str__(self) -> str:
        if self.line is None:
            return self.message
        return f"{self.message} ({place_text(self.line, self.column)})"


def place_text(line: int, column: int | None) -> str:
    """A place in the user's program as an error names it: "line 3, column 9" ("line 3"
    without a column)."""
    return f"line {line}" + (f", column {column}" if column else "")


@dataclass(frozen=True, slots=True)
class StepResult:
    """What a step did: how it ended, what it is waiting for and the effects to apply."""

    outcome: Outcome
    pending: PendingRequest | None = None
    effects: tuple[Effect, ...] = ()
    effects_total: int = 0
    error: VVError | None = None
    duration_s: float = 0.0
    requests: int = 0
    storage_bytes: int = 0
    # Journal answers the program read in this step: all it has had when the step re-ran it
    # from its first line (replay), only the new ones when it resumed where it waited.
    answers_read: int = 0
    replayed: bool = True  # the program ran from its first line (not resumed where it waited)

    def replay_time(self, replay_s: float) -> float:
        """How long a replay of the program up to where it waits now takes, from the time
        before this step (``StepInput.replay_s``): this step's, when it ran the program from
        its first line, else that time and this step's own added."""
        return self.duration_s if self.replayed else replay_s + self.duration_s
