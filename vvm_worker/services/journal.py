"""A VV's journal: the append-only answers of the VVM-API, which a new context replays, and its limits."""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any, overload

from django.conf import settings
from django.db.models import QuerySet, TextField
from django.db.models.functions import Cast

from missions.models import (
    JournalEntry,
    LogEntry,
    VirtualVehicle,
)
from vvm_worker.services.base import VVM


class JournalView(Sequence[str]):
    """A VV's journal as the runtime reads it, each entry as the JSON text the database holds:
    a warm context asks only for the entries it does not have (and the last one it has, to
    check it is the same), a new one for all."""

    def __init__(self, vv: VirtualVehicle) -> None:
        self.vv = vv

    def __len__(self) -> int:
        return self.vv.journal_length

    def _texts(self) -> QuerySet[JournalEntry, str]:
        return (
            JournalEntry.objects.filter(vv_id=self.vv.pk)
            .annotate(text=Cast("entry", output_field=TextField()))
            .values_list("text", flat=True)
        )

    @overload
    def __getitem__(self, index: int) -> str: ...

    @overload
    def __getitem__(self, index: slice) -> list[str]: ...

    def __getitem__(self, index: int | slice) -> str | list[str]:
        if isinstance(index, slice):
            start, stop, step = index.indices(len(self))
            assert step == 1
            return list(self._texts().filter(seq__gte=start, seq__lt=stop).order_by("seq"))
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(index)
        return self._texts().get(seq=index)


def journal_append(vv: VirtualVehicle, entry: dict[str, Any], vvm: VVM) -> None:
    """Add an answer to the VV's journal (the caller saves the VV in the same transaction)."""
    JournalEntry.objects.create(vv=vv, seq=vv.journal_length, entry=entry)
    vv.journal_length += 1
    vv.journal_bytes += len(json.dumps(entry, separators=(",", ":")))
    if vv.journal_length == settings.CPCC_JOURNAL_WARN_ENTRIES:
        LogEntry.objects.create(
            vv=vv,
            at_s=vvm.clock.now_s(),
            level="warning",
            message=f"the journal holds {vv.journal_length:,} answers; a VV stops at "
            f"{settings.CPCC_JOURNAL_MAX_ENTRIES:,} answers or "
            f"{settings.CPCC_JOURNAL_MAX_BYTES // 1_000_000} MB (a VV that moves replays it)",
        )


def journal_full(vv: VirtualVehicle) -> str | None:
    if vv.journal_length > settings.CPCC_JOURNAL_MAX_ENTRIES:
        return (
            f"the journal holds {vv.journal_length:,} answers, more than the "
            f"{settings.CPCC_JOURNAL_MAX_ENTRIES:,} allowed (quota: journal)"
        )
    if vv.journal_bytes > settings.CPCC_JOURNAL_MAX_BYTES:
        return (
            f"the journal holds {vv.journal_bytes:,} bytes, more than the "
            f"{settings.CPCC_JOURNAL_MAX_BYTES:,} allowed (quota: journal)"
        )
    return None
