from collections.abc import Callable
from typing import Any

from django.contrib import admin
from django.db.models import QuerySet
from django.http import HttpRequest

from cpcc_site.admin_display import PositionShown, moment, number_text
from cpcc_site.admin_site import ExplainedWhenEmpty
from missions.models import LogEntry, Message, Migration, StorageDocument, Task, VirtualVehicle


def _vv_time(
    field: str, description: str, *, vv: Callable[[Any], VirtualVehicle] = lambda obj: obj.vv
) -> Any:
    """A display method of a time on a VV's platform clock (the VV's own, or a task's, a log
    line's, a migration's: ``obj.vv``) as a UTC date and time."""
    return moment(
        field, description=description, to_datetime=lambda obj, t: vv(obj).platform_datetime(t)
    )


class MadeByThePlatform:
    """Tasks, log lines, stored documents and migrations come from running VVs only: the
    admin shows them and offers no "Add"."""

    def has_add_permission(self, request: HttpRequest, *args: Any) -> bool:
        return False


class TaskInline(PositionShown, admin.TabularInline):
    model = Task
    fields = [
        "q", "index", "lat_shown", "lng_shown", "alt_shown", "status", "vehicle", "requested",
        "done",
    ]  # fmt: skip
    readonly_fields = fields
    requested = _vv_time("requested_s", "requested")
    done = _vv_time("done_s", "done")
    extra = 0
    can_delete = False
    show_change_link = True


class MigrationInline(admin.TabularInline):
    model = Migration
    fields = ["from_name", "to_name", "at", "reason"]
    readonly_fields = fields
    at = _vv_time("at_s", "at")
    extra = 0
    can_delete = False


@admin.register(VirtualVehicle)
class VirtualVehicleAdmin(ExplainedWhenEmpty):
    empty_list_help = (
        "A VV (virtual vehicle) is a customer's JavaScript program flown aboard the RVs: it "
        "asks for readings and moves from RV to RV to get them. Customers submit them in the "
        "editor, over the API or with cpcc."
    )
    list_display = ["name", "customer", "status", "host_gs", "host_rv", "steps", "submitted"]
    list_filter = ["status", "customer"]
    search_fields = ["name", "customer__name"]
    readonly_fields = [
        "id",
        "seed",
        "start_ms",
        "journal_length",
        "journal_bytes",
        "effects_applied",
        "pending",
        "steps",
        "last_step",
        "storage_bytes",
        "picture_bytes",
        "submitted",
        "started",
        "finished_at",
        "created",
        "finished",
    ]
    # The platform clock's floats, shown by the methods below instead.
    exclude = ["last_step_s", "submitted_s", "started_s", "finished_s"]
    inlines = [TaskInline, MigrationInline]

    submitted = _vv_time("submitted_s", "submitted", vv=lambda vv: vv)
    started = _vv_time("started_s", "started", vv=lambda vv: vv)
    finished_at = _vv_time("finished_s", "ended", vv=lambda vv: vv)

    @admin.display(description="last step's replay", ordering="last_step_s")
    def last_step(self, vv: VirtualVehicle) -> str:
        """How long a replay of its program up to where it waits takes: milliseconds."""
        return number_text(vv.last_step_s * 1000, 1, "ms")


@admin.register(Task)
class TaskAdmin(MadeByThePlatform, ExplainedWhenEmpty):
    empty_list_help = (
        "A task is a point a VV asked to have read (VV.task.execute): the platform makes one "
        "when a VV asks for a reading, and an RV that can serve it flies there."
    )
    list_display = ["vv", "q", "index", "status", "vehicle", "requested", "done"]
    list_filter = ["status", "vehicle"]
    requested = _vv_time("requested_s", "requested")
    done = _vv_time("done_s", "done")


@admin.register(StorageDocument)
class StorageDocumentAdmin(MadeByThePlatform, ExplainedWhenEmpty):
    empty_list_help = (
        "What VVs keep in their private storage (VV.storage.store), one key each; they appear "
        "here as VVs store them."
    )
    list_display = ["vv", "key", "size_bytes"]
    search_fields = ["key", "vv__name"]


@admin.register(LogEntry)
class LogEntryAdmin(MadeByThePlatform, ExplainedWhenEmpty):
    empty_list_help = (
        "The lines VVs log (VV.log), shown to their owners; they appear here as VVs run."
    )
    list_display = ["vv", "seq", "at", "message"]
    at = _vv_time("at_s", "at")
    search_fields = ["message", "vv__name"]


@admin.register(Migration)
class MigrationAdmin(MadeByThePlatform, ExplainedWhenEmpty):
    empty_list_help = (
        "A migration is a VV moving with its whole state from one host (an RV or a ground "
        "station) to another; the platform makes one at every move."
    )
    list_display = ["vv", "from_name", "to_name", "at", "reason"]
    at = _vv_time("at_s", "at")


@admin.register(Message)
class MessageAdmin(ExplainedWhenEmpty):
    """Messages between a customer's VVs and from its own system: sent and taken by the
    platform only, so staff read them and change nothing (a recipient's journal holds what it
    took)."""

    empty_list_help = (
        "Messages a customer's VVs send each other (VV.message.send), or its own system sends "
        "them over the API; they appear here as they are sent."
    )
    list_display = ["id", "customer", "sender_shown", "recipient_name", "bytes", "sent", "received"]
    list_filter = ["customer"]
    search_fields = ["recipient__name", "sender_name"]
    list_select_related = ["customer", "recipient"]
    fields = [
        "customer",
        "sender",
        "sender_name",
        "recipient",
        "value",
        "bytes",
        "sent",
        "received",
    ]
    readonly_fields = fields
    sent = _vv_time("sent_s", "sent", vv=lambda message: message.recipient)
    received = _vv_time("received_s", "received", vv=lambda message: message.recipient)

    def get_queryset(self, request: HttpRequest) -> QuerySet[Message]:
        # The recipient's name and clock, not its program.
        return super().get_queryset(request).defer("recipient__program", "recipient__catalog")

    @admin.display(description="from", ordering="sender_name")
    def sender_shown(self, message: Message) -> str:
        return message.sender_name or "(the customer's system, over the API)"

    @admin.display(description="to", ordering="recipient__name")
    def recipient_name(self, message: Message) -> str:
        return message.recipient.name

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False

    def has_change_permission(self, request: HttpRequest, obj: Any = None) -> bool:
        return False

    def has_delete_permission(self, request: HttpRequest, obj: Any = None) -> bool:
        return False
