"""The admin site as an operator meets it: the platform's own sections (Fleet, Missions,
Customers and users) first on the index and in the side bar, the libraries' (Audit log, Axes,
tokens, groups) after them; and a list with nothing in it says what its things are for and
how one is added.

Django makes ``admin.site`` from ``AdminConfig.default_site``: settings.INSTALLED_APPS names
``CpccAdminConfig`` in the place of ``django.contrib.admin``, so every ``@admin.register`` of
the apps and the libraries lands on ``CpccAdminSite``.
"""

from __future__ import annotations

from typing import Any

from django.contrib import admin
from django.contrib.admin.apps import AdminConfig
from django.http import HttpRequest, HttpResponse

# The platform's apps in the order an operator works through them; every other app (the
# libraries') follows in the admin's own order, by name.
PLATFORM_APPS = ("fleet", "missions", "accounts")


class CpccAdminSite(admin.AdminSite):
    def get_app_list(
        self, request: HttpRequest, app_label: str | None = None
    ) -> list[dict[str, Any]]:
        apps = super().get_app_list(request, app_label)
        last = len(PLATFORM_APPS)

        def place(app: dict[str, Any]) -> int:
            label = app["app_label"]
            return PLATFORM_APPS.index(label) if label in PLATFORM_APPS else last

        return sorted(apps, key=place)  # stable: the libraries keep their order


class CpccAdminConfig(AdminConfig):
    default_site = "cpcc_site.admin_site.CpccAdminSite"


class ExplainedWhenEmpty(admin.ModelAdmin):
    """A ModelAdmin whose list, while there is nothing in it at all (not merely nothing
    found), says what its things are for and how one comes to be: ``empty_list_help``, shown
    by templates/admin/change_list.html above an "Add" link when the user may add one."""

    empty_list_help = ""

    def changelist_view(
        self, request: HttpRequest, extra_context: dict[str, Any] | None = None
    ) -> HttpResponse:
        context = {**(extra_context or {}), "empty_list_help": self.empty_list_help}
        return super().changelist_view(request, context)
