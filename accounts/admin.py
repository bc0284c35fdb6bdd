from typing import Any

from django.contrib import admin
from django.contrib.auth.admin import UserAdmin as BaseUserAdmin
from django.http import HttpRequest

from accounts.models import Customer, User
from vvm_worker.platform import platform_vvm
from vvm_worker.services import CustomerConfig, customer_create, customer_update


class CustomerUserInline(admin.TabularInline):
    model = User
    fields = ["username", "email", "is_active"]
    extra = 0
    show_change_link = True


@admin.register(Customer)
class CustomerAdmin(admin.ModelAdmin):
    """Customers with their quotas and users; saved through the services, so more parallel
    VVs start queued ones at once."""

    list_display = ["name", "slug", "privileged", "max_parallel_vvs", "max_tasks_per_vv"]
    list_filter = ["privileged"]
    search_fields = ["name", "slug"]
    prepopulated_fields = {"slug": ["name"]}
    filter_horizontal = ["allowed_sensors"]
    inlines = [CustomerUserInline]
    fieldsets = [
        (None, {"fields": ["name", "slug", "privileged"]}),
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
