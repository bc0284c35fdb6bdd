"""Flight logs: a flight's ``.tlog`` kept through Django's storage, and deleted after
``CPCC_FLIGHT_LOG_DAYS``.

The bytes come from ``fleet.mavlink.tlog`` (a MAVLink RV's recorded stream, ``TlogRecorder``)
or ``fleet.mavlink.tlog_sim`` (what a simulated RV's simulator would have sent). Files are
written outside any transaction's control: a log saved for a flight whose row is then rolled
back stays as an orphan file, which is harmless (the next save of that flight replaces it).
"""

from __future__ import annotations

import datetime
import logging
from typing import IO

from django.conf import settings
from django.core.files import File
from django.core.files.base import ContentFile
from django.utils import timezone
from django.utils.text import slugify

from fleet.mavlink.tlog_sim import simulated_tlog
from fleet.models import Flight

logger = logging.getLogger("cpcc.flight_logs")

__all__ = ["flight_log_name", "flight_log_save", "flight_logs_prune"]

_PRUNE_BATCH = 500


def flight_log_name(*, flight: Flight) -> str:
    """The storage name of a flight's log: ``flights/<vehicle>-<flight id>.tlog`` (the
    vehicle's name as a slug, its id if the name has no letters or digits)."""
    vehicle = slugify(flight.vehicle.name) or f"vehicle-{flight.vehicle.pk}"
    return f"flights/{vehicle}-{flight.pk}.tlog"


def flight_log_save(*, flight: Flight, data: bytes | IO[bytes]) -> None:
    """Store ``data`` (the .tlog's bytes, or a binary file read from its start, e.g.
    ``TlogRecorder.finish()``'s; the caller closes it) as the flight's log through
    ``default_storage`` and set ``Flight.log`` (that column only: the control loop may be
    writing the row's others). Saving again replaces the flight's previous log, so a retried
    close is harmless. The flight must be saved (it has an id). Raises OSError when the
    storage cannot write.
    """
    if flight.pk is None:
        raise ValueError("save the flight before its log")
    previous = flight.log.name
    content = ContentFile(data) if isinstance(data, bytes) else File(data)
    name = flight_log_name(flight=flight)
    if previous == name:
        flight.log.storage.delete(previous)  # replaced under its own name, not beside it
    # The FileField's upload_to puts it under flights/; the storage picks another name if one
    # is taken (an orphan of a rolled-back flight).
    flight.log.save(name.removeprefix("flights/"), content, save=False)
    Flight.objects.filter(pk=flight.pk).update(log=flight.log.name)
    if previous and previous != flight.log.name:
        flight.log.storage.delete(previous)
    logger.info(
        "flight log saved",
        extra={"vehicle": flight.vehicle.name, "flight": flight.pk, "log": flight.log.name},
    )


def flight_logs_prune(*, now: datetime.datetime | None = None) -> int:
    """Delete the logs (file and ``Flight.log``) of the flights that ended more than
    ``CPCC_FLIGHT_LOG_DAYS`` before ``now`` (default: now); the flights stay. Returns how many
    logs were deleted. Safe to run twice, or in two workers at once: a file already gone is
    not an error.
    """
    cutoff = (now or timezone.now()) - datetime.timedelta(days=settings.CPCC_FLIGHT_LOG_DAYS)
    old = Flight.objects.filter(ended__lt=cutoff).exclude(log="").order_by("pk")
    storage = Flight._meta.get_field("log").storage  # type: ignore[union-attr]
    deleted = 0
    while batch := list(old.values_list("pk", "log")[:_PRUNE_BATCH]):
        for _, name in batch:
            storage.delete(name)
        deleted += Flight.objects.filter(pk__in=[pk for pk, _ in batch]).update(log="")
    if deleted:
        logger.info("flight logs pruned", extra={"deleted": deleted, "before": cutoff.isoformat()})
    return deleted


def flight_log_kept(*, flight: Flight, now: datetime.datetime | None = None) -> bool:
    """Whether a log of the flight can be had: the one its worker recorded (a MAVLink RV's),
    or, for a flight with a track and no recording (a simulated RV's), the simulator's
    messages along it, made when asked (``flight_log_simulated``) while the flight is within
    CPCC_FLIGHT_LOG_DAYS, as a recorded one is kept."""
    if flight.log:
        return True
    if len(flight.track) < 2:
        return False
    cutoff = (now or timezone.now()) - datetime.timedelta(days=settings.CPCC_FLIGHT_LOG_DAYS)
    return flight.ended is None or flight.ended >= cutoff


def flight_log_simulated(*, flight: Flight) -> bytes:
    """The .tlog of a flight that has a track and no recording: the messages the simulator
    would have sent along it (``fleet.mavlink.tlog_sim``), at the flight's dates, with its
    battery as measured or estimated (full when neither). Made from the flight's row when it
    is asked for: an RV's worker spends nothing on it. Raises ValueError for a track it cannot
    fly."""
    epoch_s = flight.started.timestamp() - flight.started_s
    track = [(t, lat, lng, alt) for t, lat, lng, alt, *_ in flight.track]
    start = 1.0 if flight.battery_start_pct is None else flight.battery_start_pct / 100.0
    end = start if flight.battery_end_pct is None else flight.battery_end_pct / 100.0
    return simulated_tlog(track, epoch_s=epoch_s, system_id=1, battery_start=start, battery_end=end)
