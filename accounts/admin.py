from typing import Any

from django import forms
from django.contrib import admin
from django.contrib.admin.widgets import AdminBigIntegerFieldWidget, FilteredSelectMultiple
from django.contrib.auth.admin import UserAdmin as BaseUserAdmin
from django.core.validators import MinValueValidator
from django.db import models
from django.db.models import Count, QuerySet
from django.http import HttpRequest

from accounts.admin_reports import ServiceLevelsReportMixin
from accounts.models import ApiToken, Customer, Invite, ServiceClass, User, Webhook
from accounts.services import api_token_revoke, invite_withdraw, webhook_delete
from cpcc_site.admin_display import SizeField
from cpcc_site.admin_site import ExplainedWhenEmpty
from vvm_worker.platform import platform_vvm
from vvm_worker.runtime import VVM_API_CALLS
from vvm_worker.services import CustomerConfig, customer_create, customer_update
from vvm_worker.services.customers import service_class_save

# The VVM-API calls by what they reach (a call of a new kind in a group of its own, last), each
# named as a program makes it.
_CALL_GROUPS = {
    "task": "Tasks",
    "sensor": "Sensors",
    "storage": "Storage",
    "image": "Images",
    "message": "Messages",
    "log": "Log",
}


def _call_choices() -> list[tuple[str, list[tuple[str, str]]]]:
    groups: dict[str, list[tuple[str, str]]] = {name: [] for name in _CALL_GROUPS.values()}
    for call in VVM_API_CALLS:
        prefix = call.split(".")[0]
        group = _CALL_GROUPS.get(prefix, prefix.capitalize())
        groups.setdefault(group, []).append((call, f"VV.{call}"))
    return [(group, calls) for group, calls in groups.items() if calls]


def _size(name: str, *, unit: str, label: str, help_text: str) -> SizeField:
    """A form field of the customer's size ``name`` (bytes) in ``unit``, with the model's
    default and least value."""
    field = Customer._meta.get_field(name)
    assert isinstance(field, models.Field)
    least = max(v.limit_value for v in field.validators if isinstance(v, MinValueValidator))
    return SizeField(
        unit=unit,
        min_bytes=int(least),
        initial=field.get_default(),
        label=label,
        help_text=help_text,
    )


class CustomerAdminForm(forms.ModelForm):
    """A customer's quotas in words and units: sizes in MB or KB (kept in bytes), the VVM-API
    calls as boxes to tick (kept as the JSON list the API reads and writes)."""

    storage_bytes = _size(
        "storage_bytes",
        unit="MB",
        label="Storage per VV (MB)",
        help_text="What one VV may keep with VV.storage.store, its pictures included; a store "
        "beyond it stops the VV. 1 MB is 1,048,576 bytes.",
    )
    heap_bytes = _size(
        "heap_bytes",
        unit="MB",
        label="JavaScript heap per VV (MB)",
        help_text="Memory one VV's program may hold while it runs (V8 heap, typed arrays "
        "included); a program that needs more is stopped. At least 1 MB.",
    )
    max_message_bytes = _size(
        "max_message_bytes",
        unit="KB",
        label="Size of one message (KB)",
        help_text="Largest value one VV.message.send may carry, as JSON text (UTF-8); a larger "
        "one is refused with an error the program can catch. 1 KB is 1,024 bytes.",
    )
    allowed_api_calls = forms.MultipleChoiceField(
        choices=_call_choices,
        required=False,
        widget=forms.CheckboxSelectMultiple,
        label="VVM-API calls allowed",
        help_text="The calls this customer's VVs may make (VV.log covers stdOut.println and "
        "logInfo too); a VV that makes another one is stopped. None ticked: every call is "
        "allowed.",
    )

    class Meta:
        model = Customer
        fields = ["name"]  # the admin gives it its fieldsets' fields
        labels = {
            "slug": "Short name",
            "privileged": "Privileged customer",
            "max_parallel_vvs": "VVs running at once",
            "max_queued_vvs": "VVs waiting in the queue",
            "max_tasks_per_vv": "Tasks per VV",
            "cpu_ms_per_step": "CPU time per step (ms)",
            "max_messages_per_vv": "Messages sent per VV",
            "allowed_sensors": "Sensors allowed",
        }
        help_texts = {
            "slug": "Letters, digits, hyphens and underscores; names the customer in the API "
            "and the platform's logs. Filled in from the name.",
            "max_tasks_per_vv": "Tasks (readings) one VV may ask for in all "
            "(VV.task.execute, executeAll); asking for more stops the VV.",
            "cpu_ms_per_step": "CPU time a VV's program may use between two calls that wait "
            "(a task, a message), in milliseconds; a program that runs longer is stopped.",
            "max_messages_per_vv": "Messages one VV may send to the customer's other VVs "
            "(VV.message.send); one more is refused with an error the program can catch.",
        }

    def clean_allowed_api_calls(self) -> list[str]:
        ticked = set(self.cleaned_data["allowed_api_calls"])
        return [call for call in VVM_API_CALLS if call in ticked]


class CustomerUserInline(admin.TabularInline):
    model = User
    fields = ["username", "email", "is_active"]
    extra = 0
    show_change_link = True


@admin.register(Customer)
class CustomerAdmin(ExplainedWhenEmpty):
    """Customers with their quotas and users; saved through the services, so more parallel
    VVs start queued ones at once."""

    form = CustomerAdminForm
    empty_list_help = (
        "A customer is a tenant of the platform: its users submit VVs (JavaScript programs "
        "flown on the RVs) within the quotas set here, and never see another customer's data. "
        "Add one, then its users: add a user under Users and choose the customer."
    )
    list_display = [
        "name",
        "slug",
        "privileged",
        "service_class",
        "parallel_vvs",
        "tasks_per_vv",
    ]
    list_filter = ["privileged", "service_class"]
    list_select_related = ["service_class"]
    search_fields = ["name", "slug"]
    prepopulated_fields = {"slug": ["name"]}
    filter_horizontal = ["allowed_sensors"]
    # The quotas' boxes as wide as the sizes': 10000 tasks would not fit the admin's narrow one
    # on a phone.
    formfield_overrides = {models.PositiveIntegerField: {"widget": AdminBigIntegerFieldWidget}}
    inlines = [CustomerUserInline]
    fieldsets = [
        (None, {"fields": ["name", "slug", "privileged", "service_class"]}),
        (
            "Quotas",
            {"fields": [*Customer.QUOTA_FIELDS, "allowed_sensors", "allowed_api_calls"]},
        ),
    ]

    @admin.display(description="VVs at once", ordering="max_parallel_vvs")
    def parallel_vvs(self, customer: Customer) -> int:
        return customer.max_parallel_vvs

    @admin.display(description="tasks per VV", ordering="max_tasks_per_vv")
    def tasks_per_vv(self, customer: Customer) -> int:
        return customer.max_tasks_per_vv

    def formfield_for_manytomany(self, db_field: Any, request: HttpRequest, **kwargs: Any) -> Any:
        if db_field.name == "allowed_sensors":  # "Available sensors", "Chosen sensors"
            kwargs["widget"] = FilteredSelectMultiple("sensors", is_stacked=False)
        return super().formfield_for_manytomany(db_field, request, **kwargs)

    def save_model(self, request: HttpRequest, obj: Any, form: Any, change: bool) -> None:
        names = form.changed_data if change else form.cleaned_data
        config: CustomerConfig = {
            f: form.cleaned_data[f]  # type: ignore[misc]
            for f in names
            if f in CustomerConfig.__annotations__
        }
        sensors = [s.name for s in form.cleaned_data.get("allowed_sensors", ())]
        if change:
            changed_sensors = "allowed_sensors" in form.changed_data
            customer_update(
                customer=obj,
                config=config,
                allowed_sensors=sensors if changed_sensors else None,
                vvm=platform_vvm(),
            )
        else:
            obj.pk = customer_create(config=config, allowed_sensors=sensors).pk
        obj.refresh_from_db()

    def save_related(self, request: HttpRequest, form: Any, formsets: Any, change: bool) -> None:
        # The service saved the allowed SDC entries; the users inline is saved here.
        for formset in formsets:
            self.save_formset(request, form, formset, change=change)


@admin.register(ServiceClass)
class ServiceClassAdmin(ServiceLevelsReportMixin, ExplainedWhenEmpty):
    """Service classes: a p95 target and a weight, and how many customers are in each; saved
    through the service. A class keeps its name (a new name is a new class)."""

    empty_list_help = (
        "A service class is a level of service promised to customers: a target time within "
        "which 95 % of their tasks are read, and a weight their requests get in the RVs' "
        "plans. Customers without a class have no target and weight 1. Add a class, then "
        "choose it on each customer's page (Service class)."
    )
    list_display = ["name", "p95_s", "weight", "customer_count"]
    search_fields = ["name"]
    fields = ["name", "p95_s", "weight"]

    def get_queryset(self, request: HttpRequest) -> QuerySet[ServiceClass]:
        return super().get_queryset(request).annotate(customer_count=Count("customers"))

    @admin.display(description="customers", ordering="customer_count")
    def customer_count(self, obj: Any) -> int:
        return int(obj.customer_count)

    def get_readonly_fields(self, request: HttpRequest, obj: Any = None) -> list[str]:
        return ["name"] if obj is not None else []

    def save_model(self, request: HttpRequest, obj: Any, form: Any, change: bool) -> None:
        saved = service_class_save(name=obj.name, p95_s=obj.p95_s, weight=obj.weight)
        obj.pk = saved.pk


@admin.register(User)
class UserAdmin(BaseUserAdmin):
    """Users: a customer's members with their role, staff with their groups (fleet manager,
    pilot, support: accounts.staff_groups)."""

    list_display = ["username", "email", "customer", "role", "is_staff", "is_active"]
    list_filter = ["customer", "role", "is_staff", "groups", "is_active"]
    fieldsets = [
        *BaseUserAdmin.fieldsets,
        ("Customer", {"fields": ["customer", "role"]}),
    ]
    add_fieldsets = [
        *BaseUserAdmin.add_fieldsets,
        ("Customer", {"fields": ["customer", "role"]}),
    ]


@admin.register(Invite)
class InviteAdmin(ExplainedWhenEmpty):
    """Owners' invitations (made on their Members page): staff see them and may withdraw one."""

    empty_list_help = (
        "An owner of a customer invites a colleague by e-mail from Account, Members: the link "
        "works once, until it expires (CPCC_INVITE_DAYS)."
    )
    list_display = ["email", "customer", "role", "invited_by", "created", "expires", "accepted"]
    list_filter = ["customer", "role"]
    search_fields = ["email", "customer__name"]
    fields = list_display

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False

    def has_change_permission(self, request: HttpRequest, obj: Any = None) -> bool:
        return False

    def delete_model(self, request: HttpRequest, obj: Invite) -> None:
        invite_withdraw(invite=obj)

    def delete_queryset(self, request: HttpRequest, queryset: Any) -> None:
        for obj in queryset:
            self.delete_model(request, obj)


class _MadeByTheirOwners(ExplainedWhenEmpty):
    """What customers make themselves (tokens, webhooks): staff see them and may delete one
    (a token revoked, a webhook removed), never add or edit one, nor see a key or secret."""

    def has_add_permission(self, request: HttpRequest) -> bool:
        return False

    def has_change_permission(self, request: HttpRequest, obj: Any = None) -> bool:
        return False

    def delete_queryset(self, request: HttpRequest, queryset: Any) -> None:
        for obj in queryset:  # one by one, through the service
            self.delete_model(request, obj)


@admin.register(ApiToken)
class ApiTokenAdmin(_MadeByTheirOwners):
    empty_list_help = (
        "API tokens let a customer's programs and scripts use the API (cpcc, CI jobs). Users "
        "make their own under Account, API tokens; staff see them here and may revoke one."
    )
    list_display = ["name", "user", "token_key", "created", "last_used"]
    list_filter = ["user__customer"]
    search_fields = ["name", "token_key", "user__username"]
    fields = ["name", "user", "token_key", "created", "last_used"]

    def delete_model(self, request: HttpRequest, obj: ApiToken) -> None:
        api_token_revoke(token=obj)


@admin.register(Webhook)
class WebhookAdmin(_MadeByTheirOwners):
    empty_list_help = (
        "A webhook is an address of a customer's system the platform POSTs to when one of its "
        "VVs finishes or fails, or a task is done. Users add them under Account, "
        "Notifications; staff see them here and may remove one."
    )
    list_display = ["url", "customer", "events", "created"]
    list_filter = ["customer"]
    search_fields = ["url", "customer__name"]
    fields = ["customer", "url", "events", "created"]

    def delete_model(self, request: HttpRequest, obj: Webhook) -> None:
        webhook_delete(webhook=obj)
