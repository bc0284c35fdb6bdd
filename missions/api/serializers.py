"""Input and output shapes of the VV endpoints."""

from __future__ import annotations

import datetime as dt
import uuid
from typing import Any

from django.urls import reverse
from django.utils import timezone
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import extend_schema_field
from rest_framework import serializers

from cpcc_site.api import StrictCharField
from cpcc_site.names import BIDI_CONTROLS
from missions.models import (
    PROGRAM_MAX_CHARS,
    PROGRAM_TOO_LONG,
    LogEntry,
    StorageDocument,
    Task,
    VirtualVehicle,
    VVStatus,
    validate_vv_name,
)
from missions.readings import image_file, map_camera_readings
from missions.selectors import with_task_counts
from missions.waiting import QueuePlace, queue_places, vv_waiting

# The ``waiting`` object of a VV, for the schema.
WAITING_SCHEMA = {
    "type": "object",
    "nullable": True,
    "description": "What the VV waits for, in your words; null when it runs without waiting "
    "or has ended. `reason`: `no_vehicle` (no vehicle in service covers its next task; it "
    "continues when one does), `no_pilot` (the vehicles in service that cover its next task "
    "have no pilot on duty, where the provider requires one; it continues when one comes on "
    "duty), `queue` (behind your other VVs: your limit of VVs in "
    "parallel), `service_level` (queued and held back "
    "while another service class misses its target and yours keeps its own with room to "
    "spare, never longer than your class's target allows), `flying` (a vehicle flies to its task) or `message` (its program waits "
    "in VV.message.receive, at most until its timeout). `since`: when it started waiting "
    "(null when not known); `next_task_eta_s`: seconds until the vehicle is expected at its "
    "next task, by its plan (null when not known).",
    "properties": {
        "reason": {
            "type": "string",
            "enum": ["no_vehicle", "no_pilot", "queue", "service_level", "flying", "message"],
        },
        "message": {"type": "string"},
        # (OpenAPI 3.1: drf-spectacular makes only the field itself nullable.)
        "since": {"type": ["string", "null"], "format": "date-time"},
        "next_task_eta_s": {"type": ["number", "null"]},
    },
    "required": ["reason", "message", "since", "next_task_eta_s"],
}


# A VV's name as the schema says it: plain text (no control character, no bidirectional
# formatting: missions.models.vv_name_problem) with something besides white space.
_NOT_PLAIN = r"\x00-\x1f\x7f-\x9f" + "".join(
    f"\\u{ord(char):04x}" for char in sorted(BIDI_CONTROLS)
)
VV_NAME_PATTERN = rf"^[^{_NOT_PLAIN}]*[^{_NOT_PLAIN}\s][^{_NOT_PLAIN}]*$"


@extend_schema_field(
    {
        "type": "string",
        "minLength": 1,
        "maxLength": 120,
        "pattern": VV_NAME_PATTERN,
        "description": "Plain text: no control or bidirectional formatting characters.",
    }
)
class VVNameField(StrictCharField):
    """A new VV's name."""


class VVCreateSerializer(serializers.Serializer):
    name = VVNameField(
        max_length=120,
        validators=[validate_vv_name],
        help_text="Plain text: no control or bidirectional formatting characters.",
    )
    program = StrictCharField(
        trim_whitespace=False,
        max_length=PROGRAM_MAX_CHARS,
        error_messages={"max_length": PROGRAM_TOO_LONG},
    )


class VVSerializer(serializers.ModelSerializer):
    host = serializers.SerializerMethodField(
        help_text="Where the VV is: a ground station or a vehicle."
    )
    tasks_done = serializers.SerializerMethodField()
    tasks_open = serializers.SerializerMethodField()
    error = StrictCharField()
    waiting = serializers.SerializerMethodField()

    class Meta:
        model = VirtualVehicle
        fields = [
            "id",
            "name",
            "status",
            "host",
            "tasks_done",
            "tasks_open",
            "error",
            "error_line",
            "error_column",
            "created",
            "finished",
            "waiting",
        ]

    def get_host(self, vv: VirtualVehicle) -> str | None:
        # Customers never learn which vehicles exist; staff see the host's name.
        request = self.context.get("request")
        if request is not None and request.user.is_staff:
            return vv.host_name
        if vv.host_rv_id is not None:
            return "vehicle"
        if vv.host_gs_id is not None:
            return "ground station"
        return None

    # A list counts a page's tasks at once (``with_task_counts``), one VV its own.
    def get_tasks_done(self, vv: VirtualVehicle) -> int:
        return _task_counts(vv)[0]

    def get_tasks_open(self, vv: VirtualVehicle) -> int:
        return _task_counts(vv)[1]

    @extend_schema_field(WAITING_SCHEMA)
    def get_waiting(self, vv: VirtualVehicle) -> dict[str, Any] | None:
        waiting = vv_waiting(vv, tasks_open=_task_counts(vv)[1], place=self._queue_place(vv))
        if waiting is None:
            return None
        return {
            "reason": waiting.reason,
            "message": waiting.message,
            "since": platform_time(vv, waiting.since_s),
            "next_task_eta_s": waiting.next_task_eta_s,
        }

    def _queue_place(self, vv: VirtualVehicle) -> QueuePlace | None:
        """A queued VV's place in its queue: for every VV of the list it is in at once (one
        statement for a page, or for a bulk submission's answer), as the task counts."""
        if vv.status != VVStatus.QUEUED:
            return None
        if not hasattr(vv, "queue_place"):
            listed = getattr(self.parent, "instance", None)
            vvs = listed if isinstance(listed, list) and vv in listed else [vv]
            places = queue_places(vvs=vvs)
            for one in vvs:
                one.queue_place = places.get(one.pk)  # type: ignore[attr-defined]
        return vv.queue_place  # type: ignore[attr-defined, no-any-return]

    def to_representation(self, instance: VirtualVehicle) -> dict[str, Any]:
        # What the declared fields give (tests/missions/api/test_vvs.py compares the two), written
        # out: a ModelSerializer builds its fields from the model anew for every instance it
        # is given, which cost an API request about a millisecond.
        vv = instance
        done, open_ = _task_counts(vv)
        return {
            "id": str(vv.pk),
            "name": vv.name,
            "status": vv.status,
            "host": self.get_host(vv),
            "tasks_done": done,
            "tasks_open": open_,
            "error": str(vv.error),
            "error_line": vv.error_line,
            "error_column": vv.error_column,
            "created": api_datetime(vv.created),
            "finished": api_datetime(vv.finished),
            "waiting": self.get_waiting(vv),
        }


def _task_counts(vv: VirtualVehicle) -> tuple[int, int]:
    """The VV's tasks done and open: as a list counted them (``with_task_counts``), or
    counted now."""
    if not hasattr(vv, "tasks_done"):
        with_task_counts([vv])
    return vv.tasks_done, vv.tasks_open  # type: ignore[attr-defined]


def api_datetime(moment: dt.datetime | None) -> str | None:
    """A date as the API shows it: ISO 8601 in the platform's time zone, ``Z`` for UTC (what
    DRF's DateTimeField gives, without looking up the request's time zone each time)."""
    if moment is None:
        return None
    text = moment.astimezone(timezone.get_default_timezone()).isoformat()
    return text[:-6] + "Z" if text.endswith("+00:00") else text


def platform_datetime(vv: VirtualVehicle, t_s: float | None) -> dt.datetime | None:
    """A time on the platform clock (``*_s`` fields) as a date: ``vv.platform_datetime``."""
    return vv.platform_datetime(t_s)


def platform_time(vv: VirtualVehicle, t_s: float | None) -> str | None:
    """A time on the platform clock as the API shows dates (ISO 8601, UTC)."""
    moment = platform_datetime(vv, t_s)
    return api_datetime(moment)


def image_url(context: dict[str, Any], vv_id: uuid.UUID, file: str) -> str:
    """The absolute URL of ``GET /api/v1/vvs/{id}/images/{file}`` (relative without a request)."""
    path = reverse("vv-image", kwargs={"id": str(vv_id), "file": file})
    request = context.get("request")
    return request.build_absolute_uri(path) if request is not None else path


def with_image_urls(value: Any, *, context: dict[str, Any], vv_id: uuid.UUID) -> Any:
    """A copy of a JSON value where every camera reading also has ``image_url``."""

    def link(reading: dict[str, Any]) -> dict[str, Any]:
        reading["image_url"] = image_url(context, vv_id, image_file(reading["image"]))
        return reading

    return map_camera_readings(value, link)


class StorageDocumentOutSerializer(serializers.ModelSerializer):
    """One key of a VV's storage. A camera reading in the value (at any depth) also has
    ``image_url``, where its picture is."""

    value = serializers.SerializerMethodField()
    updated = serializers.SerializerMethodField()

    class Meta:
        model = StorageDocument
        fields = ["key", "value", "updated"]

    @extend_schema_field(OpenApiTypes.ANY)
    def get_value(self, doc: StorageDocument) -> Any:
        return with_image_urls(doc.value, context=self.context, vv_id=doc.vv_id)

    @extend_schema_field(OpenApiTypes.DATETIME)
    def get_updated(self, doc: StorageDocument) -> str | None:
        return platform_time(doc.vv, doc.updated_s)


class TaskOutSerializer(serializers.ModelSerializer):
    """A point task the VV asked for, and its readings once an RV has been there."""

    position = serializers.SerializerMethodField(
        help_text="[lat, lng, alt], alt in m above ground."
    )
    requested = serializers.SerializerMethodField()
    done = serializers.SerializerMethodField(help_text="When it was read or rejected.")
    readings = serializers.SerializerMethodField(
        help_text="One reading per sensor, in the order asked; camera readings have image_url."
    )
    sensors = serializers.ListField(child=StrictCharField(), help_text="SDC entry names.")
    message = StrictCharField(help_text="Why the task was rejected, if it was.")

    class Meta:
        model = Task
        fields = [
            "q",
            "index",
            "position",
            "tolerance_m",
            "sensors",
            "status",
            "requested",
            "done",
            "readings",
            "message",
        ]

    def get_position(self, task: Task) -> list[float]:
        return [task.lat, task.lng, task.alt]

    @extend_schema_field(OpenApiTypes.DATETIME)
    def get_requested(self, task: Task) -> str | None:
        return platform_time(task.vv, task.requested_s)

    @extend_schema_field({"type": "string", "format": "date-time", "nullable": True})
    def get_done(self, task: Task) -> str | None:
        return platform_time(task.vv, task.done_s)

    @extend_schema_field(
        {"type": "array", "items": {"type": "object", "additionalProperties": {}}, "nullable": True}
    )
    def get_readings(self, task: Task) -> Any:
        if task.readings is None:
            return None
        return with_image_urls(task.readings, context=self.context, vv_id=task.vv_id)


class StaffTaskOutSerializer(TaskOutSerializer):
    """A task as staff see it: also which vehicle served (or serves) it."""

    vehicle = StrictCharField(source="vehicle.name", default=None, allow_null=True)

    class Meta(TaskOutSerializer.Meta):
        fields = [*TaskOutSerializer.Meta.fields, "vehicle"]


class LogEntryOutSerializer(serializers.ModelSerializer):
    """A line of the VV's log."""

    at = serializers.SerializerMethodField()

    class Meta:
        model = LogEntry
        fields = ["at", "level", "message"]

    @extend_schema_field(OpenApiTypes.DATETIME)
    def get_at(self, entry: LogEntry) -> str | None:
        return platform_time(entry.vv, entry.at_s)
