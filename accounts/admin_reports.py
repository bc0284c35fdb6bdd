"""The service-levels report in the admin (issue 28): how the fleet kept each customer's class
over the last hour, the last day or a period staff choose, from the service classes' list.

A mixin of the service class admin (``accounts/admin.py``): its page is
``admin/accounts/serviceclass/levels/``, behind the admin's login like every admin view, and
shows what ``GET /api/v1/service-levels/`` answers.
"""

from __future__ import annotations

import datetime as dt
from typing import Any

from django import forms
from django.core.exceptions import PermissionDenied
from django.http import HttpRequest
from django.template.response import TemplateResponse
from django.urls import URLPattern, path

from missions.api.service_levels import hold_shown
from vvm_worker.clock import SystemClock
from vvm_worker.level_figures import LevelStats
from vvm_worker.services.service_levels import (
    HoldShown,
    service_level_holds,
    service_levels_by_class,
    service_levels_report,
)

PERIODS = {"hour": 3_600.0, "day": 86_400.0}


class PeriodForm(forms.Form):
    """The period of the report: the last hour, the last day, or from ``since`` to ``until``
    (UTC, until excluded)."""

    period = forms.ChoiceField(
        choices=[("hour", "last hour"), ("day", "last day"), ("custom", "from … until …")],
        initial="day",
    )
    since = forms.DateTimeField(
        required=False, widget=forms.DateTimeInput(attrs={"type": "datetime-local"})
    )
    until = forms.DateTimeField(
        required=False, widget=forms.DateTimeInput(attrs={"type": "datetime-local"})
    )

    def period_s(self, now_s: float) -> tuple[float, float]:
        """(since, until) in epoch seconds; call after ``is_valid``."""
        data = self.cleaned_data
        if data["period"] in PERIODS:
            return now_s - PERIODS[data["period"]], now_s
        return _seconds(data["since"]), _seconds(data["until"])

    def clean(self) -> dict[str, Any]:
        data = super().clean() or {}
        if data.get("period") == "custom":
            since, until = data.get("since"), data.get("until")
            if since is None:
                self.add_error("since", "Give the start of the period.")
            if until is None:
                self.add_error("until", "Give the end of the period.")
            if since is not None and until is not None and since >= until:
                self.add_error("until", "The end must come after the start.")
        return data


def _seconds(moment: dt.datetime) -> float:
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=dt.UTC)
    return moment.timestamp()


class ServiceLevelsReportMixin:
    """Adds the report's page to a ModelAdmin (the service classes')."""

    admin_site: Any
    opts: Any
    has_view_permission: Any

    def get_urls(self) -> list[URLPattern]:
        report = path(
            "levels/",
            self.admin_site.admin_view(self.service_levels_view),
            name="accounts_serviceclass_levels",
        )
        return [report, *super().get_urls()]  # type: ignore[misc]

    def service_levels_view(self, request: HttpRequest) -> TemplateResponse:
        """Requests, median and p95 latency and the share within target per customer and
        class, and per class, over the chosen period."""
        if not self.has_view_permission(request):
            raise PermissionDenied
        form = PeriodForm(request.GET or {"period": "day"})
        customers, classes, holds, since, until = [], [], [], None, None
        if form.is_valid():
            now_s = SystemClock().now_s()
            since_s, until_s = form.period_s(now_s)
            customers = service_levels_report(since_s=since_s, until_s=until_s)
            holds = service_level_holds(since_s=since_s, until_s=until_s, now_s=now_s)
            classes = service_levels_by_class(since_s=since_s, until_s=until_s, holds=holds)
            since = dt.datetime.fromtimestamp(since_s, dt.UTC)
            until = dt.datetime.fromtimestamp(until_s, dt.UTC)
        context = {
            **self.admin_site.each_context(request),
            "title": "Service levels",
            "opts": self.opts,
            "form": form,
            "since": since,
            "until": until,
            "customers": [_shown(s) for s in customers],
            "classes": [_shown(c.got, c.as_dict()) for c in classes],
            "holds": [_hold_shown(h) for h in holds],
        }
        return TemplateResponse(request, "admin/service_levels.html", context)


def _hold_shown(hold: HoldShown) -> dict[str, object]:
    """A hold as the page shows it: the API's figures, its times as UTC datetimes."""
    row = hold_shown(hold)
    row["started_at"] = dt.datetime.fromtimestamp(hold.started_s, dt.UTC)
    row["ended_at"] = (
        None if hold.ended_s is None else dt.datetime.fromtimestamp(hold.ended_s, dt.UTC)
    )
    return row


def _shown(stats: LevelStats, row: dict[str, object] | None = None) -> dict[str, object]:
    """A row of the report as the page shows it: the API's figures (``row``; by default the
    stats') and the share in percent."""
    row = stats.as_dict() if row is None else row
    within = stats.within_target
    row["within_target_percent"] = None if within is None else round(100 * within, 1)
    return row
