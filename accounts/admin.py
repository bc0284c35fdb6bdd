from typing import Any

from django.contrib import admin
from django.contrib.auth.admin import UserAdmin as BaseUserAdmin
from django.db.models import Count, QuerySet
from django.http import HttpRequest

from accounts.admin_reports import ServiceLevelsReportMixin
from accounts.models import ApiToken, Customer, ServiceClass, User, Webhook
from accounts.services import api_token_revoke, webhook_delete
from vvm_worker.platform import platform_vvm
from vvm_worker.services import CustomerConfig, customer_create, customer_update
from vvm_worker.services.customers import service_class_save


class CustomerUserInline(admin.TabularInline):
    model = User
    fields = ["username", "email", "is_active"]
    extra = 0
    show_change_link = True


@admin.register(Customer)
class CustomerAdmin(admin.ModelAdmin):
    """Customers with their quotas and users; saved through the services, so more parallel
    VVs start queued ones at once."""

    list_display = [
        "name",
        "slug",
        "privileged",
        "service_class",
        "max_parallel_vvs",
        "max_tasks_per_vv",
    ]
    list_filter = ["privileged", "service_class"]
    list_select_related = ["service_class"]
    search_fields = ["name", "slug"]
    prepopulated_fields = {"slug": ["name"]}
    filter_horizontal = ["allowed_sensors"]
    inlines = [CustomerUserInline]
    fieldsets = [
        (None, {"fields": ["name", "slug", "privileged", "service_class"]}),
        (
            "Quotas",
            {"fields": [*Customer.QUOTA_FIELDS, "allowed_sensors", "allowed_api_calls"]},
        ),
    ]

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
class ServiceClassAdmin(ServiceLevelsReportMixin, admin.ModelAdmin):
    """Service classes: a p95 target and a weight, and how many customers are in each; saved
    through the service. A class keeps its name (a new name is a new class)."""

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
    list_display = ["username", "email", "customer", "is_staff", "is_active"]
    list_filter = ["customer", "is_staff", "is_active"]
    fieldsets = [
        *BaseUserAdmin.fieldsets,
        ("Customer", {"fields": ["customer"]}),
    ]
    add_fieldsets = [
        *BaseUserAdmin.add_fieldsets,
        ("Customer", {"fields": ["customer"]}),
    ]


class _MadeByTheirOwners(admin.ModelAdmin):
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
    list_display = ["name", "user", "token_key", "created", "last_used"]
    list_filter = ["user__customer"]
    search_fields = ["name", "token_key", "user__username"]
    fields = ["name", "user", "token_key", "created", "last_used"]

    def delete_model(self, request: HttpRequest, obj: ApiToken) -> None:
        api_token_revoke(token=obj)


@admin.register(Webhook)
class WebhookAdmin(_MadeByTheirOwners):
    list_display = ["url", "customer", "events", "created"]
    list_filter = ["customer"]
    search_fields = ["url", "customer__name"]
    fields = ["customer", "url", "events", "created"]

    def delete_model(self, request: HttpRequest, obj: Webhook) -> None:
        webhook_delete(webhook=obj)
