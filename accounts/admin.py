from django.contrib import admin
from django.contrib.auth.admin import UserAdmin as BaseUserAdmin

from accounts.models import Customer, User


class CustomerUserInline(admin.TabularInline):
    model = User
    fields = ["username", "email", "is_active"]
    extra = 0
    show_change_link = True


@admin.register(Customer)
class CustomerAdmin(admin.ModelAdmin):
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
