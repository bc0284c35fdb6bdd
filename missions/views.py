"""Customer pages: the list of one's VVs and a VV's tasks, storage and log."""

from __future__ import annotations

import uuid

from django.contrib.auth.decorators import login_required
from django.http import Http404, HttpRequest, HttpResponse
from django.shortcuts import render

from missions.selectors import VVNotFound, vv_get_for_user, vv_list_for_user


@login_required
def home(request: HttpRequest) -> HttpResponse:
    vvs = vv_list_for_user(user=request.user)  # type: ignore[arg-type]
    return render(request, "missions/home.html", {"vvs": vvs})


@login_required
def vv_detail(request: HttpRequest, vv_id: uuid.UUID) -> HttpResponse:
    try:
        vv = vv_get_for_user(user=request.user, vv_id=vv_id)  # type: ignore[arg-type]
    except VVNotFound:
        raise Http404("No such virtual vehicle.") from None
    context = {
        "vv": vv,
        "tasks": vv.tasks.select_related("vehicle"),
        "storage": vv.storage.all(),
        "log": vv.log.all(),
    }
    return render(request, "missions/vv_detail.html", context)
