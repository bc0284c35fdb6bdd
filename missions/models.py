"""Virtual vehicles (VVs): their programs, checkpoints, tasks, storage, logs and migrations."""

from __future__ import annotations

import datetime as dt
import uuid

from django.core.exceptions import ValidationError
from django.db import models

from accounts.models import Customer
from cpcc_site.names import plain_name_problem
from fleet.geo import Position
from fleet.models import GroundStation, Vehicle


class VVStatus(models.TextChoices):
    QUEUED = "queued", "Queued"
    RUNNING = "running", "Running"
    MIGRATING = "migrating", "Migrating"
    FINISHED = "finished", "Finished"
    FAILED = "failed", "Failed"
    KILLED = "killed", "Killed"
    CANCELLED = "cancelled", "Cancelled"


class WaitReason(models.TextChoices):
    """What a VV that has not ended waits for, in the API's words (``waiting.reason``).
    NO_VEHICLE, NO_PILOT and SERVICE_LEVEL are kept on the VV's row; the others follow from
    where it is."""

    NO_VEHICLE = "no_vehicle", "No vehicle in service covers its next task"
    # CPCC_REQUIRE_PILOT: the RVs that cover it are in service but no pilot is on duty for them.
    NO_PILOT = "no_pilot", "No pilot on duty for the vehicles that cover its next task"
    QUEUE = "queue", "In the customer's queue"
    FLYING = "flying", "A vehicle flies to its task"
    MESSAGE = "message", "Its program waits for a message (VV.message.receive)"
    SERVICE_LEVEL = "service_level", "Held back to keep other service levels"


ACTIVE_STATUSES = (VVStatus.RUNNING, VVStatus.MIGRATING)
ENDED_STATUSES = (VVStatus.FINISHED, VVStatus.FAILED, VVStatus.KILLED, VVStatus.CANCELLED)

# The longest program a VV may have, however it comes (the REST API, the editor, its check).
PROGRAM_MAX_CHARS = 1_000_000
PROGRAM_TOO_LONG = (
    f"A program has at most {PROGRAM_MAX_CHARS:,} characters: split the work into several VVs "
    "or make the program shorter."
)


def vv_name_problem(name: str) -> str | None:
    """What is wrong with a VV's name, or None (``cpcc_site.names.plain_name_problem``)."""
    return plain_name_problem(name)


def validate_vv_name(name: str) -> None:
    """A validator of forms and serializers: ValidationError saying what vv_name_problem says."""
    problem = vv_name_problem(name)
    if problem is not None:
        raise ValidationError(problem, code="invalid_name")


class VirtualVehicle(models.Model):
    """A customer's VV: its program and its checkpoint (journal), where it runs, how it ended.

    Times ending in ``_s`` are seconds on the platform clock (the Unix epoch in a live system,
    the scenario's simulated time in ``simulate``).
    """

    id = models.UUIDField(primary_key=True, default=uuid.uuid4, editable=False)
    # A foreign key here and below has no index of its own where a composite index or a unique
    # constraint starts with it: every index is one more write per row, at every task.
    customer = models.ForeignKey(
        Customer, on_delete=models.CASCADE, related_name="vvs", db_index=False
    )
    name = models.CharField(max_length=120, validators=[validate_vv_name])
    program = models.TextField()
    status = models.CharField(max_length=10, choices=VVStatus.choices, default=VVStatus.QUEUED)
    host_gs = models.ForeignKey(
        GroundStation,
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="vvs",
        db_index=False,
    )
    host_rv = models.ForeignKey(
        Vehicle, null=True, blank=True, on_delete=models.SET_NULL, related_name="vvs"
    )
    # The checkpoint: program + journal of every answer the VVM-API gave, and how many of the
    # program's effects are applied (DESIGN.md section 2, deterministic replay).
    seed = models.BigIntegerField()
    start_ms = models.BigIntegerField(help_text="Logical time before the first answer.")
    catalog = models.JSONField(default=list, help_text="SDC entries this VV may use.")
    journal_length = models.PositiveIntegerField(default=0, help_text="Entries in its journal.")
    journal_bytes = models.PositiveBigIntegerField(default=0)
    effects_applied = models.PositiveIntegerField(default=0)
    pending = models.JSONField(null=True, blank=True, help_text="The request it is blocked in.")
    steps = models.PositiveIntegerField(default=0)
    last_step_s = models.FloatField(default=0.0)
    storage_bytes = models.PositiveBigIntegerField(default=0)
    # Bytes of the pictures it made (VV.image.crop and resize): they count against its
    # storage quota together with ``storage_bytes``.
    picture_bytes = models.PositiveBigIntegerField(default=0)
    error = models.TextField(blank=True)
    error_line = models.PositiveIntegerField(null=True, blank=True)
    error_column = models.PositiveIntegerField(null=True, blank=True)
    submitted_s = models.FloatField()
    started_s = models.FloatField(null=True, blank=True)
    finished_s = models.FloatField(null=True, blank=True)
    # Why it waits while no RV in service (or none with a pilot on duty) could serve its next
    # task (routing parks it on a ground station), in the customer's words, and since when;
    # blank once it moves on.
    waiting_reason = models.CharField(
        max_length=20, choices=WaitReason.choices, blank=True, default=""
    )
    waiting_message = models.CharField(max_length=300, blank=True, default="")
    waiting_since_s = models.FloatField(null=True, blank=True)
    # When the RV it is aboard expects to reach its next task (its control loop's plan).
    next_task_eta_s = models.FloatField(null=True, blank=True)
    created = models.DateTimeField(auto_now_add=True)
    finished = models.DateTimeField(null=True, blank=True)
    updated = models.DateTimeField(auto_now=True)

    # CPU time (seconds) the VV has used since it last waited for the outside world (a task,
    # a message): its steps and the host's work for its calls that answer at once (images,
    # sending a message). The quota ``cpu_ms_per_step`` bounds it.
    call_cpu_s = models.FloatField(default=0.0)

    class Meta:
        ordering = ["submitted_s", "created"]
        verbose_name = "virtual vehicle"
        constraints = [
            models.CheckConstraint(
                condition=~(models.Q(host_gs__isnull=False) & models.Q(host_rv__isnull=False)),
                name="vv_one_host",
            ),
        ]
        indexes = [
            models.Index(fields=["customer", "status"]),
            # A ground station's load (the VVs on it that have not ended), read at admission:
            # the VVs that ended there do not count and are not read.
            models.Index(fields=["host_gs", "status"], name="vv_gs_load"),
        ]

    def __str__(self) -> str:
        return f"{self.name} ({self.customer})"

    @property
    def host_name(self) -> str | None:
        host = self.host_rv or self.host_gs
        return host.name if host else None

    @property
    def is_ended(self) -> bool:
        return self.status in ENDED_STATUSES

    def platform_datetime(self, t_s: float | None) -> dt.datetime | None:
        """A time on the platform clock (this VV's ``*_s`` fields and its tasks', log lines'
        and migrations') as a date in UTC; None for None.

        The platform clock is the Unix epoch in a live system; ``simulate`` counts from 0 and
        gives its VVs dates from 2025-01-01. The VV's logical start (``start_ms``, a date)
        against its submission (``submitted_s``, platform clock) says which, so these times
        line up with the ``time`` of its readings in both cases.
        """
        if t_s is None:
            return None
        return dt.datetime.fromtimestamp(t_s + self.platform_offset_s, tz=dt.UTC)

    @property
    def platform_offset_s(self) -> int:
        """What turns this VV's platform clock into Unix time (``platform_datetime`` says
        why): 0 in a live system."""
        return round(self.start_ms / 1000.0 - self.submitted_s)


class JournalEntry(models.Model):
    """One answer the VVM-API gave a VV (a task's readings or a rejection), in order.

    Append-only: the journal and the program are the VV's checkpoint, which a new context replays.
    """

    vv = models.ForeignKey(
        VirtualVehicle, on_delete=models.CASCADE, related_name="journal", db_index=False
    )
    seq = models.PositiveIntegerField()
    entry = models.JSONField()

    class Meta:
        ordering = ["vv", "seq"]
        verbose_name_plural = "journal entries"
        constraints = [models.UniqueConstraint(fields=["vv", "seq"], name="journal_unique_seq")]

    def __str__(self) -> str:
        return f"{self.vv.name} #{self.seq}"


class TaskStatus(models.TextChoices):
    OPEN = "open", "Open"
    DONE = "done", "Done"
    REJECTED = "rejected", "Rejected"
    CANCELLED = "cancelled", "Cancelled"


class Task(models.Model):
    """A point task a VV asked for: go there within the tolerance and read these sensors."""

    vv = models.ForeignKey(
        VirtualVehicle, on_delete=models.CASCADE, related_name="tasks", db_index=False
    )
    q = models.PositiveIntegerField(help_text="Ordinal of the VVM-API request.")
    index = models.PositiveIntegerField(default=0, help_text="Index in an executeAll batch.")
    lat = models.FloatField()
    lng = models.FloatField()
    alt = models.FloatField()
    tolerance_m = models.FloatField()
    sensors = models.JSONField()
    status = models.CharField(max_length=10, choices=TaskStatus.choices, default=TaskStatus.OPEN)
    vehicle = models.ForeignKey(
        Vehicle,
        null=True,
        blank=True,
        on_delete=models.SET_NULL,
        related_name="tasks",
        db_index=False,
    )
    requested_s = models.FloatField()
    assigned_s = models.FloatField(null=True, blank=True, help_text="When an RV took it on.")
    done_s = models.FloatField(null=True, blank=True)
    readings = models.JSONField(null=True, blank=True)
    message = models.TextField(blank=True)

    class Meta:
        ordering = ["vv", "q", "index"]
        constraints = [
            models.UniqueConstraint(fields=["vv", "q", "index"], name="task_unique_per_request"),
        ]
        indexes = [
            models.Index(fields=["vehicle", "status"]),
            # The tasks requested lately (which service classes are being served: routing's
            # look every 10 s, services/service_levels.classes_giving_way).
            models.Index(fields=["requested_s"], name="task_requested"),
        ]

    def __str__(self) -> str:
        return f"task {self.q}.{self.index} of {self.vv.name}"

    @property
    def position(self) -> Position:
        return Position(self.lat, self.lng, self.alt)


class StorageDocument(models.Model):
    """One key of a VV's private storage and its JSON value."""

    vv = models.ForeignKey(
        VirtualVehicle, on_delete=models.CASCADE, related_name="storage", db_index=False
    )
    key = models.CharField(max_length=128)
    value = models.JSONField()
    size_bytes = models.PositiveIntegerField()
    updated_s = models.FloatField()

    class Meta:
        ordering = ["vv", "key"]
        constraints = [models.UniqueConstraint(fields=["vv", "key"], name="storage_unique_key")]

    def __str__(self) -> str:
        return self.key


class Picture(models.Model):
    """A picture the platform keeps (``sensing.save_image``) as one customer's: a camera
    reading one of its VVs received, or a picture one of its VVs made. Only that customer's VVs
    may use it (``VV.image``), and only once they have received it (a reading, a call's
    answer, a message from another of its VVs). The same content taken for two customers is
    one file and a row for each."""

    customer = models.ForeignKey(Customer, on_delete=models.CASCADE, related_name="+")
    reference = models.CharField(max_length=64, help_text="The file under MEDIA_ROOT.")
    vv = models.ForeignKey(
        VirtualVehicle,
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="+",
        help_text="The VV that first received or made it.",
    )
    made = models.BooleanField(
        default=False, help_text="Made by VV.image.crop or resize (counts against storage)."
    )
    bytes = models.PositiveIntegerField(default=0)

    class Meta:
        constraints = [
            models.UniqueConstraint(fields=["customer", "reference"], name="picture_per_customer")
        ]

    def __str__(self) -> str:
        return self.reference


class LogEntry(models.Model):
    """A line of a VV's log, shown to its owner."""

    vv = models.ForeignKey(
        VirtualVehicle, on_delete=models.CASCADE, related_name="log", db_index=False
    )
    seq = models.PositiveIntegerField(
        null=True, blank=True, help_text="The program's effect number; empty for the platform's."
    )
    at_s = models.FloatField()
    level = models.CharField(max_length=10, default="info")
    message = models.TextField()

    class Meta:
        ordering = ["vv", "at_s", "seq"]
        # Not "log entries": the admin lists the audit log under that name.
        verbose_name = "VV log line"
        verbose_name_plural = "VV log lines"
        constraints = [models.UniqueConstraint(fields=["vv", "seq"], name="log_unique_seq")]

    def __str__(self) -> str:
        return self.message[:80]


class HostKind(models.TextChoices):
    GS = "gs", "Ground station"
    RV = "rv", "Real vehicle"


class Migration(models.Model):
    """A VV moving with its whole state from one host to another."""

    vv = models.ForeignKey(VirtualVehicle, on_delete=models.CASCADE, related_name="migrations")
    from_kind = models.CharField(max_length=2, choices=HostKind.choices)
    from_name = models.CharField(max_length=80)
    to_kind = models.CharField(max_length=2, choices=HostKind.choices)
    to_name = models.CharField(max_length=80)
    at_s = models.FloatField()
    reason = models.CharField(max_length=200, blank=True)
    # Where the two hosts were at that moment (the map's red line); empty for a host whose
    # position was not known (an RV that never reported one).
    from_lat = models.FloatField(null=True, blank=True)
    from_lng = models.FloatField(null=True, blank=True)
    to_lat = models.FloatField(null=True, blank=True)
    to_lng = models.FloatField(null=True, blank=True)

    class Meta:
        ordering = ["at_s", "id"]

    def __str__(self) -> str:
        return f"{self.vv.name}: {self.from_name} -> {self.to_name}"


class TrackPoint(models.Model):
    """Where a VV was while an RV carried it: a point at every start and end of a flight leg,
    so the straight legs between them are its path (the map's green line, a mission's replay)."""

    vv = models.ForeignKey(
        VirtualVehicle, on_delete=models.CASCADE, related_name="track", db_index=False
    )
    t_s = models.FloatField()
    lat = models.FloatField()
    lng = models.FloatField()
    alt = models.FloatField()

    class Meta:
        ordering = ["vv", "t_s", "id"]
        indexes = [models.Index(fields=["vv", "t_s"])]

    def __str__(self) -> str:
        return f"{self.vv_id} at {self.t_s:.1f} s"


class Message(models.Model):
    """A message to a VV from another VV of the same customer (``VV.message.send``) or from
    the customer's own system over the API (no sender VV). The recipient takes messages in
    the order they were sent (by ``id``), each once (``VV.message.receive``); the answer that
    hands one over is in the recipient's journal, and ``received_s`` marks it taken in the
    same transaction."""

    customer = models.ForeignKey(Customer, on_delete=models.CASCADE, related_name="messages")
    sender = models.ForeignKey(
        VirtualVehicle,
        on_delete=models.SET_NULL,
        null=True,
        blank=True,
        related_name="messages_out",
        help_text="The VV that sent it; none: sent over the API.",
    )
    # The sender's name when it sent it ("" over the API): what the recipient reads as `from`.
    sender_name = models.CharField(max_length=120, blank=True)
    recipient = models.ForeignKey(
        VirtualVehicle, on_delete=models.CASCADE, related_name="messages_in", db_index=False
    )
    value = models.TextField(help_text="The value as JSON text.")
    bytes = models.PositiveIntegerField()
    sent_s = models.FloatField(help_text="Platform clock.")
    received_s = models.FloatField(null=True, blank=True, help_text="Platform clock.")

    class Meta:
        ordering = ["id"]
        indexes = [models.Index(fields=["recipient", "received_s", "id"])]

    def __str__(self) -> str:
        return f"message {self.pk} to {self.recipient_id}"
