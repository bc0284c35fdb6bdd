from django.contrib import admin

from missions.models import LogEntry, Migration, StorageDocument, Task, VirtualVehicle


class TaskInline(admin.TabularInline):
    model = Task
    fields = ["q", "index", "lat", "lng", "alt", "status", "vehicle", "requested_s", "done_s"]
    readonly_fields = fields
    extra = 0
    can_delete = False
    show_change_link = True


class MigrationInline(admin.TabularInline):
    model = Migration
    fields = ["from_name", "to_name", "at_s", "reason"]
    readonly_fields = fields
    extra = 0
    can_delete = False


@admin.register(VirtualVehicle)
class VirtualVehicleAdmin(admin.ModelAdmin):
    list_display = ["name", "customer", "status", "host_gs", "host_rv", "steps", "submitted_s"]
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
        "last_step_s",
        "storage_bytes",
        "submitted_s",
        "started_s",
        "finished_s",
        "created",
        "finished",
    ]
    inlines = [TaskInline, MigrationInline]


@admin.register(Task)
class TaskAdmin(admin.ModelAdmin):
    list_display = ["vv", "q", "index", "status", "vehicle", "requested_s", "done_s"]
    list_filter = ["status", "vehicle"]


@admin.register(StorageDocument)
class StorageDocumentAdmin(admin.ModelAdmin):
    list_display = ["vv", "key", "size_bytes"]
    search_fields = ["key", "vv__name"]


@admin.register(LogEntry)
class LogEntryAdmin(admin.ModelAdmin):
    list_display = ["vv", "seq", "at_s", "message"]
    search_fields = ["message", "vv__name"]


@admin.register(Migration)
class MigrationAdmin(admin.ModelAdmin):
    list_display = ["vv", "from_name", "to_name", "at_s", "reason"]
