"""The journal entries the host writes when it answers a VV's pending request."""

from __future__ import annotations

from typing import Any

from vvm_worker.runtime.types import PendingRequest


def answer_task(pending: PendingRequest, *, time_ms: int, data: list[Any]) -> dict[str, Any]:
    """The journal entry answering a pending ``execute`` with its readings."""
    return _entry(pending, "done", time_ms, data=data)


def answer_reject(pending: PendingRequest, *, time_ms: int, message: str) -> dict[str, Any]:
    """The journal entry rejecting a pending ``execute`` or a whole ``executeAll`` batch."""
    return _entry(pending, "reject", time_ms, message=message)


def answer_part(
    pending: PendingRequest, *, index: int, time_ms: int, data: list[Any]
) -> dict[str, Any]:
    """The journal entry answering one task of a pending ``executeAll`` batch."""
    return _entry(pending, "part", time_ms, i=index, data=data)


def _entry(pending: PendingRequest, kind: str, time_ms: int, **fields: Any) -> dict[str, Any]:
    entry: dict[str, Any] = {"q": pending.q, "k": kind, "t": int(time_ms), **fields}
    if pending.fingerprint is not None:
        entry["r"] = pending.fingerprint
    return entry
