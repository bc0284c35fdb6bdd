"""Customer pages: the list of one's VVs and a VV's tasks, storage and log.

Pages are for a customer's users (their customer's VVs) and for staff (every VV); any other
user is refused. They never name a vehicle or a ground station to a customer, and link camera
pictures to the REST API (``/api/v1/vvs/{id}/images/{file}``), which checks who asks: images are
never served by their path under MEDIA_ROOT.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from functools import wraps
from typing import Any

from django.conf import settings
from django.contrib.auth.decorators import login_required
from django.core.exceptions import PermissionDenied
from django.http import Http404, HttpRequest, HttpResponse, JsonResponse
from django.shortcuts import render
from django.urls import reverse

from missions.readings import image_file, image_references
from missions.selectors import (
    VVNotFound,
    map_snapshot_for_user,
    vv_get_for_user,
    vv_list_for_user,
    vv_log_for_user,
    vv_storage_for_user,
    vv_tasks_for_user,
)

View = Callable[..., HttpResponse]


def customer_or_staff_required(view: View) -> View:
    """Log in first; then only a customer's users and staff get the page (403 otherwise: a
    user of no customer has no VVs to see)."""

    @login_required
    @wraps(view)
    def checked(request: HttpRequest, *args: Any, **kwargs: Any) -> HttpResponse:
        user = request.user
        if not (user.is_staff or getattr(user, "customer_id", None)):
            raise PermissionDenied("Only a customer's users and staff have virtual vehicles.")
        return view(request, *args, **kwargs)

    return checked


@dataclass(frozen=True)
class Shown:
    """A JSON value as the page shows it, with the API URLs of the pictures it references."""

    text: str
    images: list[str]


def shown(vv_id: uuid.UUID, value: Any) -> Shown:
    images = [
        reverse("vv-image", kwargs={"id": str(vv_id), "file": image_file(reference)})
        for reference in image_references(value)
    ]
    return Shown(text=json.dumps(value, ensure_ascii=False), images=list(dict.fromkeys(images)))


@customer_or_staff_required
def home(request: HttpRequest) -> HttpResponse:
    vvs = vv_list_for_user(user=request.user)  # type: ignore[arg-type]
    return render(request, "missions/home.html", {"vvs": vvs})


@customer_or_staff_required
def vv_detail(request: HttpRequest, vv_id: uuid.UUID) -> HttpResponse:
    user = request.user
    try:
        vv = vv_get_for_user(user=user, vv_id=vv_id)  # type: ignore[arg-type]
    except VVNotFound:
        raise Http404("No such virtual vehicle.") from None
    tasks = vv_tasks_for_user(user=user, vv_id=vv.pk)  # type: ignore[arg-type]
    storage = vv_storage_for_user(user=user, vv_id=vv.pk)  # type: ignore[arg-type]
    context = {
        "vv": vv,
        "tasks": [(task, shown(vv.pk, task.readings or [])) for task in tasks],
        "storage": [(doc, shown(vv.pk, doc.value)) for doc in storage],
        "log": vv_log_for_user(user=user, vv_id=vv.pk),  # type: ignore[arg-type]
    }
    return render(request, "missions/vv_detail.html", context)


@customer_or_staff_required
def live_map(request: HttpRequest) -> HttpResponse:
    """The live map: the user's VVs (every VV and vehicle for staff), fed by /ws/map/."""
    context = {"socket_path": "/ws/map/", "tiles": settings.CPCC_MAP_TILES}
    return render(request, "missions/map.html", context)


@customer_or_staff_required
def vv_map_history(request: HttpRequest, vv_id: uuid.UUID) -> JsonResponse:
    """One VV's mission for its map and replay: its tasks, track and migrations (the shape of
    the live map's snapshot)."""
    try:
        snapshot = map_snapshot_for_user(user=request.user, vv_id=vv_id)  # type: ignore[arg-type]
    except VVNotFound:
        raise Http404("No such virtual vehicle.") from None
    return JsonResponse(snapshot)
