"""Customer pages: the dashboard of one's VVs, the program editor, a VV's page (log, tasks on a
map and its replay, storage, chart, messages, downloads), the live map, and the actions on a VV
(cancel, restart, edit while queued, send it a message).

Pages are for a customer's users (their customer's VVs) and for staff (every VV); any other
user is refused. They never name a vehicle or a ground station to a customer, and link camera
pictures to the REST API (``/api/v1/vvs/{id}/images/{file}``), which checks who asks: images are
never served by their path under MEDIA_ROOT. Each view reads through the scoped selectors of
missions/selectors.py and changes state through one service of vvm_worker/services/.

Changing a VV (submit, check, edit, cancel, restart, send a message) needs a member's developer
role, or staff's STAFF_VV_WRITE permission (``change_refusal``): a viewer reads everything and
is offered no button to change anything. The refusal (403, saying what it needs) comes before
any VV is looked up, so it is the same for a VV that does not exist; another customer's VV
stays 404 to whoever may change their own.
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import wraps
from typing import Any

from django.conf import settings
from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.core.exceptions import PermissionDenied, ValidationError
from django.core.paginator import Page, Paginator
from django.db.models import Count
from django.http import Http404, HttpRequest, HttpResponse, JsonResponse
from django.shortcuts import redirect, render
from django.urls import reverse
from django.utils.http import url_has_allowed_host_and_scheme
from django.utils.text import slugify
from django.views.decorators.http import require_POST

from accounts.roles import DEVELOPER
from cpcc_site import json_depth
from cpcc_site.permissions import change_refusal as permission_change_refusal
from missions.forms import NewProgramForm, ProgramForm
from missions.models import (
    ACTIVE_STATUSES,
    ENDED_STATUSES,
    PROGRAM_MAX_CHARS,
    PROGRAM_TOO_LONG,
    Message,
    Task,
    TaskStatus,
    VirtualVehicle,
    VVStatus,
)
from missions.readings import (
    image_file,
    image_references,
    is_camera_reading,
    map_camera_readings,
    reading_time_ms,
)
from missions.selectors import (
    VVNotFound,
    map_snapshot_for_user,
    vv_get_for_user,
    vv_list_for_user,
    vv_log_for_user,
    vv_messages_pages_for_user,
    vv_storage_for_user,
    vv_tasks_for_user,
    with_task_counts,
)
from missions.waiting import vv_waiting
from vvm_worker.platform import platform_vvm
from vvm_worker.runtime import SyntaxProblem, check_syntax, place_text
from vvm_worker.services import (
    NotACustomer,
    ProgramRejected,
    VVAlreadyEnded,
    VVNotEnded,
    VVNotQueued,
    VVQueueFull,
    vv_cancel_for_user,
    vv_create_copies_for_user,
    vv_restart_for_user,
    vv_update_program_for_user,
)
from vvm_worker.services.messages import MessageError, vv_message_send_for_user

View = Callable[..., HttpResponse]

VVS_PER_PAGE = 50
# A VV may have thousands of tasks, keys and log lines: the page shows this many of each (the
# downloads have everything).
TASKS_SHOWN = 500
STORAGE_SHOWN = 500
LOG_SHOWN = 1_000
# The page shows the last messages in and out (the API lists them all), each value up to this
# many characters of its JSON.
MESSAGES_SHOWN = 50
MESSAGE_CHARS_SHOWN = 2_000
# The dashboard's filter: its name, what it shows.
FILTERS: dict[str, tuple[str, tuple[str, ...]]] = {
    "all": ("All", ()),
    "active": ("Queued and running", (VVStatus.QUEUED, *ACTIVE_STATUSES)),
    "ended": ("Ended", ENDED_STATUSES),
}


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


def change_refusal(user: Any, action: str = "this") -> str | None:
    """Why the user may not change VVs on these pages (None: they may): a customer's member
    needs the developer role, staff the permission STAFF_VV_WRITE."""
    return permission_change_refusal(user, None, DEVELOPER, action)


def _refuse_change(request: HttpRequest, action: str) -> None:
    why = change_refusal(request.user, action)
    if why is not None:
        raise PermissionDenied(why)


def changes_vvs(action: str) -> Callable[[View], View]:
    """The view changes VVs (``action`` names what, in the refusal): a user who may not gets
    403 before anything is looked up (under customer_or_staff_required)."""

    def decorate(view: View) -> View:
        @wraps(view)
        def checked(request: HttpRequest, *args: Any, **kwargs: Any) -> HttpResponse:
            _refuse_change(request, action)
            return view(request, *args, **kwargs)

        return checked

    return decorate


def _vv_or_404(request: HttpRequest, vv_id: uuid.UUID | str) -> VirtualVehicle:
    try:
        return vv_get_for_user(user=request.user, vv_id=vv_id)  # type: ignore[arg-type]
    except VVNotFound:
        raise Http404("No such virtual vehicle.") from None


# --- how a VV is shown --------------------------------------------------------------------


def where(vv: VirtualVehicle, *, staff: bool) -> str:
    """Where the VV is. A customer learns only whether it waits, sits on a ground station or
    is aboard a vehicle, never which; staff see the host's name."""
    if staff and vv.host_name:
        kind = "vehicle" if vv.host_rv_id else "ground station"
        return f"{vv.host_name} ({kind})"
    if vv.host_rv_id:
        return "in flight"
    if vv.host_gs_id:
        return "at a ground station"
    if vv.status == VVStatus.QUEUED:
        return "queued"
    return "—"


@dataclass(frozen=True)
class Actions:
    """What the user may do with a VV now."""

    cancel: bool
    restart: bool
    edit: bool


def actions_for(vv: VirtualVehicle, *, may_change: bool = True) -> Actions:
    """Edit while queued, cancel until it ends, restart once it has ended, unless it failed:
    its program, run again as it is, would fail the same way (its page offers a copy to
    change instead). Nothing for a user who may not change VVs (``change_refusal``)."""
    return Actions(
        cancel=may_change and not vv.is_ended,
        restart=may_change and vv.is_ended and vv.status != VVStatus.FAILED,
        edit=may_change and vv.status == VVStatus.QUEUED,
    )


def error_place(vv: VirtualVehicle) -> str:
    """The place in its program its error names ("line 3, column 9"; "" when none)."""
    return "" if vv.error_line is None else place_text(vv.error_line, vv.error_column)


def error_text(vv: VirtualVehicle) -> str:
    """Why the VV failed, without the place in its program that its error ends with
    (``VVError``'s words; the page shows the place as a link to the line)."""
    place = error_place(vv)
    error = vv.error or ""
    return error.removesuffix(f" ({place})") if place else error


@dataclass(frozen=True)
class Row:
    """A VV as a row of the dashboard."""

    vv: VirtualVehicle
    where: str
    actions: Actions


def _rows(vvs: Iterable[VirtualVehicle], *, staff: bool, may_change: bool) -> list[Row]:
    return [
        Row(vv=vv, where=where(vv, staff=staff), actions=actions_for(vv, may_change=may_change))
        for vv in vvs
    ]


def _image_url(vv_id: uuid.UUID, reference: str) -> str:
    return reverse("vv-image", kwargs={"id": str(vv_id), "file": image_file(reference)})


@dataclass(frozen=True)
class Formatted:
    """A JSON value as the page shows it, by what it is: a scalar reading (value and unit), a
    GPS fix, a camera picture, or any other JSON (pretty-printed, with the pictures of the
    camera readings inside it)."""

    kind: str  # "scalar", "gps", "camera" or "json"
    text: str
    sensor: str = ""
    time: str = ""
    images: list[str] = field(default_factory=list)


def _number(value: Any, digits: int) -> str:
    return f"{value:.{digits}f}" if isinstance(value, int | float) else str(value)


def formatted(vv_id: uuid.UUID, value: Any) -> Formatted:
    if isinstance(value, dict) and isinstance(value.get("sensor"), str):
        sensor, time = value["sensor"], str(value.get("time", ""))
        kind = value.get("kind")
        if kind == "scalar" and isinstance(value.get("value"), int | float):
            unit = value.get("unit") or ""
            text = f"{value['value']:.6g}" + (f" {unit}" if unit else "")
            return Formatted("scalar", text, sensor, time)
        if kind == "gps" and all(isinstance(value.get(k), int | float) for k in ("lat", "lng")):
            text = f"{_number(value['lat'], 6)}, {_number(value['lng'], 6)}"
            if value.get("alt") is not None:
                text += f", {_number(value['alt'], 1)} m"
            return Formatted("gps", text, sensor, time)
        if is_camera_reading(value):
            size = f"{value.get('width', '?')}×{value.get('height', '?')}"
            return Formatted("camera", size, sensor, time, [_image_url(vv_id, value["image"])])
    images = [_image_url(vv_id, reference) for reference in image_references(value)]
    pretty = json.dumps(value, ensure_ascii=False, indent=2)
    return Formatted("json", pretty, images=list(dict.fromkeys(images)))


@dataclass(frozen=True)
class StorageRow:
    """One key of a VV's storage and its value, formatted."""

    key: str
    value: Formatted


@dataclass(frozen=True)
class TaskRow:
    """One of a VV's tasks: the task, its readings formatted, its times after submission."""

    task: Task
    readings: list[Formatted]
    requested: str
    done: str


@dataclass(frozen=True)
class MessageRow:
    """One of a VV's messages as its page shows it: ``direction`` "in" or "out", the names at
    its ends (``sender`` "" when it came over the API), its value as JSON text, its times
    after the VV's submission."""

    direction: str
    sender: str
    recipient: str
    value: str
    bytes: int
    sent: str
    received: str


def message_rows(vv: VirtualVehicle, messages: Iterable[Message]) -> list[MessageRow]:
    rows = []
    for message in messages:
        text = json.dumps(json.loads(message.value), ensure_ascii=False, indent=2)
        if len(text) > MESSAGE_CHARS_SHOWN:
            text = text[:MESSAGE_CHARS_SHOWN] + " …"
        rows.append(
            MessageRow(
                direction="in" if message.recipient_id == vv.pk else "out",
                sender=message.sender_name,
                recipient=message.recipient.name,
                value=text,
                bytes=message.bytes,
                sent=_clock(message.sent_s, vv.submitted_s),
                received=_clock(message.received_s, vv.submitted_s),
            )
        )
    return rows


def chart_series(tasks: Iterable[Task]) -> list[dict[str, Any]]:
    """The scalar readings of the VV's tasks, one series per sensor: ``{sensor, unit,
    points: [[ms, value, "q.index"], ...]}`` where ms is the reading's time (Unix epoch
    milliseconds, UTC), the points in time order: the chart plots them against time (a batch's
    tasks are served in any order). A reading without a readable time is left out."""
    series: dict[str, dict[str, Any]] = {}
    for task in tasks:
        for reading in task.readings or []:
            if not isinstance(reading, dict) or reading.get("kind") != "scalar":
                continue
            value = reading.get("value")
            if not isinstance(value, int | float):
                continue
            taken_ms = reading_time_ms(reading.get("time"))
            if taken_ms is None:
                continue
            sensor = str(reading.get("sensor", "?"))
            entry = series.setdefault(
                sensor, {"sensor": sensor, "unit": reading.get("unit") or "", "points": []}
            )
            label = f"{task.q}.{task.index}" if task.index else str(task.q)
            entry["points"].append([taken_ms, value, label])
    for entry in series.values():
        entry["points"].sort(key=lambda point: point[0])
    return sorted(series.values(), key=lambda s: (s["unit"], s["sensor"]))


def _clock(t_s: float | None, start_s: float) -> str:
    """A time on the platform clock as minutes and seconds after the VV's submission."""
    if t_s is None:
        return ""
    seconds = max(0, round(t_s - start_s))
    hours, rest = divmod(seconds, 3600)
    return (f"{hours}:" if hours else "") + f"{rest // 60:02d}:{rest % 60:02d}"


# --- the dashboard ----------------------------------------------------------------------------


def _dashboard(request: HttpRequest) -> dict[str, Any]:
    user = request.user
    staff = bool(user.is_staff)
    mine = vv_list_for_user(user=user)  # type: ignore[arg-type]
    counts = dict(mine.order_by().values_list("status").annotate(n=Count("id")))
    wanted = request.GET.get("show", "all")
    if wanted not in FILTERS:
        wanted = "all"
    statuses = FILTERS[wanted][1]
    shown_vvs = mine.filter(status__in=statuses) if statuses else mine
    ordered = shown_vvs.order_by("-created", "-submitted_s", "id")
    page: Page[VirtualVehicle] = Paginator(ordered, VVS_PER_PAGE).get_page(request.GET.get("page"))
    may_change = change_refusal(user) is None
    return {
        "rows": _rows(with_task_counts(list(page.object_list)), staff=staff, may_change=may_change),
        "may_change": may_change,
        "page": page,
        "show": wanted,
        "filters": [(key, label) for key, (label, _) in FILTERS.items()],
        "summary": [
            (status.label, status.value, counts.get(status.value, 0))
            for status in VVStatus
            if counts.get(status.value)
        ],
        "total": sum(counts.values()),
        "query": request.GET.urlencode(),
    }


@customer_or_staff_required
def home(request: HttpRequest) -> HttpResponse:
    """The dashboard: the user's VVs (every VV for staff), newest first, kept up to date by
    static/js/dashboard.js from the live map's socket."""
    return render(request, "missions/home.html", _dashboard(request))


@customer_or_staff_required
def vv_rows(request: HttpRequest) -> HttpResponse:
    """The dashboard's rows and summary alone (same query string), for its live updates."""
    return render(request, "missions/_dashboard_rows.html", _dashboard(request))


# --- the program editor -----------------------------------------------------------------------


def _problem_json(problem: SyntaxProblem | None) -> dict[str, Any]:
    if problem is None:
        return {"ok": True}
    return {
        "ok": False,
        "message": problem.message,
        "line": problem.line,
        "column": problem.column,
        "error": str(problem),
    }


@customer_or_staff_required
@require_POST
@changes_vvs("a program check")
def vv_check(request: HttpRequest) -> JsonResponse:
    """``POST /vvs/check/`` (session and CSRF): the API's syntax check of a program without
    submitting it. ``{"program": ...}`` as JSON or form data; answers ``{"ok": true}`` or
    ``{"ok": false, "message", "line", "column", "error"}``. A program longer than a
    submission may be is refused as the submission refuses it (400; a body above
    CPCC_MAX_REQUEST_BYTES gets 413 before it is read)."""
    if request.content_type == "application/json":
        try:
            body = json_depth.loads(request.body or b"{}")
        except json_depth.TooDeep as exc:
            return JsonResponse({"detail": str(exc)}, status=400)
        except ValueError:
            return JsonResponse({"detail": "The body is not JSON."}, status=400)
        program = body.get("program") if isinstance(body, dict) else None
    else:
        program = request.POST.get("program")
    if not isinstance(program, str):
        return JsonResponse({"detail": "Send the program as 'program'."}, status=400)
    if len(program) > PROGRAM_MAX_CHARS:
        return JsonResponse(
            {"detail": f"program: {PROGRAM_TOO_LONG}", "program": [PROGRAM_TOO_LONG]}, status=400
        )
    return JsonResponse(_problem_json(check_syntax(program)))


def _editor(
    request: HttpRequest,
    form: ProgramForm,
    *,
    vv: VirtualVehicle | None = None,
    problem: SyntaxProblem | None = None,
    status: int = 200,
) -> HttpResponse:
    context = {
        "form": form,
        "vv": vv,
        "problem": problem,
        "copies": vv is None,
        # The service-area map's background (static/js/map.js).
        "tiles": settings.CPCC_MAP_TILES,
    }
    return render(request, "missions/editor.html", context, status=status)


@customer_or_staff_required
@changes_vvs("a new VV")
def vv_new(request: HttpRequest) -> HttpResponse:
    """The program editor for new VVs: a name, a program (typed or loaded from a .js file),
    a number of copies; ``?from=<id>`` starts from one of the user's VVs."""
    if getattr(request.user, "customer_id", None) is None:
        raise PermissionDenied("Only a customer's users submit VVs (staff have no customer).")
    if request.method != "POST":
        initial: dict[str, Any] = {"copies": 1}
        source = request.GET.get("from")
        if source:
            vv = _vv_or_404(request, source)
            initial |= {"name": vv.name, "program": vv.program}
        return _editor(request, NewProgramForm(initial=initial))
    form = NewProgramForm(request.POST, request.FILES)
    if not form.is_valid():
        return _editor(request, form, status=400)
    data = form.cleaned_data
    try:
        vvs, problem = vv_create_copies_for_user(
            user=request.user,  # type: ignore[arg-type]
            name=data["name"],
            program=data["program"],
            copies=data["copies"],
            vvm=platform_vvm(),
        )
    except NotACustomer:
        raise PermissionDenied("Only a customer's users submit VVs.") from None
    except ValidationError as exc:
        form.add_error(None, exc)
        return _editor(request, form, status=400)
    except VVQueueFull as exc:
        form.add_error(None, str(exc))
        return _editor(request, form, status=429)
    if problem is not None:
        return _editor(request, form, problem=problem, status=400)
    if len(vvs) == 1:  # on to the new VV's page: where it runs, what it reads
        messages.success(request, f"“{vvs[0].name}” is submitted.")
        return redirect("vv-detail", vv_id=vvs[0].pk)
    messages.success(request, f"{len(vvs)} copies of “{data['name']}” are submitted.")
    return redirect("home")


@customer_or_staff_required
@changes_vvs("an edit of a VV's program")
def vv_edit(request: HttpRequest, vv_id: uuid.UUID) -> HttpResponse:
    """The program editor for a VV that is still queued: change its name and program."""
    vv = _vv_or_404(request, vv_id)
    if vv.status != VVStatus.QUEUED:
        messages.warning(request, f"“{vv.name}” has left the queue: its program cannot change.")
        return redirect("vv-detail", vv_id=vv.pk)
    if request.method != "POST":
        return _editor(
            request, ProgramForm(initial={"name": vv.name, "program": vv.program}), vv=vv
        )
    form = ProgramForm(request.POST, request.FILES)
    if not form.is_valid():
        return _editor(request, form, vv=vv, status=400)
    try:
        vv = vv_update_program_for_user(
            user=request.user,  # type: ignore[arg-type]
            vv_id=vv.pk,
            name=form.cleaned_data["name"],
            program=form.cleaned_data["program"],
            vvm=platform_vvm(),
        )
    except ProgramRejected as exc:
        return _editor(request, form, vv=vv, problem=exc.problem, status=400)
    except ValidationError as exc:
        form.add_error(None, exc)
        return _editor(request, form, vv=vv, status=400)
    except VVNotQueued:
        messages.warning(
            request, f"“{vv.name}” started before the change was saved: its program stays."
        )
        return redirect("vv-detail", vv_id=vv.pk)
    except VVNotFound:
        raise Http404("No such virtual vehicle.") from None
    messages.success(request, f"The program of “{vv.name}” is saved.")
    return redirect("vv-detail", vv_id=vv.pk)


# --- actions on a VV --------------------------------------------------------------------------


def _back(request: HttpRequest, default: str) -> HttpResponse:
    """Back where the form was (its ``next``), if that is a page of this site."""
    target = request.POST.get("next", "")
    if target and url_has_allowed_host_and_scheme(
        target, allowed_hosts={request.get_host()}, require_https=request.is_secure()
    ):
        return redirect(target)
    return redirect(default)


@customer_or_staff_required
@require_POST
@changes_vvs("a VV's cancellation")
def vv_cancel(request: HttpRequest, vv_id: uuid.UUID) -> HttpResponse:
    """Cancel a VV that has not ended: its open tasks are dropped, what it stored stays."""
    try:
        vv = vv_cancel_for_user(user=request.user, vv_id=vv_id, vvm=platform_vvm())  # type: ignore[arg-type]
    except VVNotFound:
        raise Http404("No such virtual vehicle.") from None
    except VVAlreadyEnded as exc:
        messages.info(request, f"“{exc.vv.name}” had already ended ({exc.vv.status}).")
        return _back(request, reverse("vv-detail", args=[vv_id]))
    messages.success(request, f"“{vv.name}” is cancelled; what it stored stays.")
    return _back(request, reverse("vv-detail", args=[vv.pk]))


@customer_or_staff_required
@require_POST
@changes_vvs("a VV's restart")
def vv_restart(request: HttpRequest, vv_id: uuid.UUID) -> HttpResponse:
    """Restart an ended VV: a new VV with the same name and program, queued."""
    try:
        new = vv_restart_for_user(user=request.user, vv_id=vv_id, vvm=platform_vvm())  # type: ignore[arg-type]
    except VVNotFound:
        raise Http404("No such virtual vehicle.") from None
    except VVNotEnded as exc:
        messages.info(request, f"“{exc.vv.name}” has not ended: cancel it first.")
        return _back(request, reverse("vv-detail", args=[vv_id]))
    except ProgramRejected as exc:
        messages.error(
            request, f"The program does not parse ({exc.problem}): fix it in a new VV first."
        )
        return redirect(f"{reverse('vv-new')}?from={vv_id}")
    except ValidationError as exc:
        messages.error(request, f"{' '.join(exc.messages)} Start it anew with another name.")
        return redirect(f"{reverse('vv-new')}?from={vv_id}")
    except VVQueueFull as exc:
        messages.error(request, str(exc))
        return _back(request, reverse("vv-detail", args=[vv_id]))
    messages.success(request, f"“{new.name}” is restarted as a new VV.")
    return _back(request, reverse("vv-detail", args=[new.pk]))


# --- a VV's page ------------------------------------------------------------------------------


@customer_or_staff_required
def vv_detail(request: HttpRequest, vv_id: uuid.UUID) -> HttpResponse:
    """A VV: its status and error, actions, tasks on a map (live while it runs, a replay once
    it has ended), storage formatted by kind, a chart of its scalar readings, its messages,
    its log and the downloads. A POST sends it a message (``value``: JSON text) from the
    customer's own system, as ``POST /api/v1/vvs/{id}/messages/`` does, and comes back to
    the page; a value that cannot be sent shows the page again with why."""
    if request.method != "POST":
        return _vv_page(request, vv_id)
    _refuse_change(request, "a message to a VV")
    text = request.POST.get("value", "")
    try:
        value = _posted_value(text)
        message = vv_message_send_for_user(
            user=request.user,  # type: ignore[arg-type]
            vv_id=vv_id,
            value=value,
            vvm=platform_vvm(),
        )
    except VVNotFound:
        raise Http404("No such virtual vehicle.") from None
    except VVAlreadyEnded as exc:
        messages.info(
            request, f"“{exc.vv.name}” has ended ({exc.vv.status}): it takes no more messages."
        )
        return redirect("vv-detail", vv_id=vv_id)
    except (NotJSON, MessageError) as exc:
        return _vv_page(request, vv_id, send_text=text, send_error=str(exc), status=400)
    messages.success(request, f"The message is sent to “{message.recipient.name}”.")
    return redirect(reverse("vv-detail", args=[vv_id]) + "#messages")


class NotJSON(ValueError):
    """What the page's form sent is not a JSON value (the text says why)."""


def _posted_value(text: str) -> Any:
    """The JSON value of the text the form "Send a message" sent; NotJSON saying what is
    wrong."""
    if not text.strip():
        raise NotJSON(
            'Write the value to send as JSON: a number, "text" in double quotes, true, null, '
            "[a list] or {an object}."
        )
    try:
        return json_depth.loads(text)
    except json_depth.TooDeep as exc:
        raise NotJSON(str(exc)) from None
    except ValueError as exc:
        raise NotJSON(f"The value is not JSON: {exc}.") from None


def _vv_page(
    request: HttpRequest,
    vv_id: uuid.UUID,
    *,
    send_text: str = "",
    send_error: str = "",
    status: int = 200,
) -> HttpResponse:
    """The VV's page; ``send_text`` and ``send_error``: a message that could not be sent, shown
    in its form with why."""
    user = request.user
    staff = bool(user.is_staff)
    may_change = change_refusal(user) is None
    try:
        (vv,) = with_task_counts([vv_get_for_user(user=user, vv_id=vv_id)])  # type: ignore[arg-type]
    except VVNotFound:
        raise Http404("No such virtual vehicle.") from None
    tasks = list(vv_tasks_for_user(user=user, vv_id=vv.pk))  # type: ignore[arg-type]
    storage = vv_storage_for_user(user=user, vv_id=vv.pk)  # type: ignore[arg-type]
    storage_count = storage.count()
    log = vv_log_for_user(user=user, vv_id=vv.pk)  # type: ignore[arg-type]
    log_count = log.count()
    log_lines = list(log[max(0, log_count - LOG_SHOWN) :])
    vv_messages = vv_messages_pages_for_user(user=user, vv_id=vv.pk)  # type: ignore[arg-type]
    messages_count = vv_messages.count()
    start_s = vv.submitted_s
    context = {
        "vv": vv,
        "where": where(vv, staff=staff),
        "error_text": error_text(vv),
        "error_place": error_place(vv),
        "refused": any(task.status == TaskStatus.REJECTED for task in tasks),
        # What it waits for (static/js/vv.js keeps it up to date from the API while it runs).
        "waiting": vv_waiting(vv, tasks_open=vv.tasks_open),  # type: ignore[attr-defined]
        "api_url": reverse("vv-detail", kwargs={"pk": str(vv.pk)}),
        "actions": actions_for(vv, may_change=may_change),
        "may_change": may_change,
        "ended": vv.is_ended,
        "tasks": [
            TaskRow(
                task=task,
                readings=[formatted(vv.pk, r) for r in task.readings or []],
                requested=_clock(task.requested_s, start_s),
                done=_clock(task.done_s, start_s),
            )
            for task in tasks[:TASKS_SHOWN]
        ],
        "tasks_count": len(tasks),
        "tasks_shown": min(len(tasks), TASKS_SHOWN),
        "storage": [
            StorageRow(doc.key, formatted(vv.pk, doc.value)) for doc in storage[:STORAGE_SHOWN]
        ],
        "storage_count": storage_count,
        "storage_shown": min(storage_count, STORAGE_SHOWN),
        "chart": chart_series(tasks),
        "log": [(_clock(line.at_s, start_s), line) for line in log_lines],
        "log_count": log_count,
        "vv_messages": message_rows(vv, vv_messages[:MESSAGES_SHOWN]),
        "messages_count": messages_count,
        "messages_api_url": reverse("vv-messages", kwargs={"id": str(vv.pk)}),
        "send_text": send_text,
        "send_error": send_error,
        "started": _clock(vv.started_s, start_s),
        "ended_after": _clock(vv.finished_s, start_s),
        "socket_path": f"/ws/map/?vv={vv.pk}",
        "history_url": reverse("vv-map-history", args=[vv.pk]),
        "tiles": settings.CPCC_MAP_TILES,
        "results_url": reverse("vv-results", kwargs={"id": str(vv.pk)}),
        "program_lines": vv.program.split("\n"),
    }
    return render(request, "missions/vv_detail.html", context, status=status)


@customer_or_staff_required
def vv_storage_json(request: HttpRequest, vv_id: uuid.UUID) -> HttpResponse:
    """The VV's storage as one JSON file to download: ``{key: value}``, every camera reading
    with ``image_url``, where its picture is."""
    vv = _vv_or_404(request, vv_id)

    def with_url(reading: dict[str, Any]) -> dict[str, Any]:
        reading["image_url"] = request.build_absolute_uri(_image_url(vv.pk, reading["image"]))
        return reading

    storage = {
        doc.key: map_camera_readings(doc.value, with_url)
        for doc in vv_storage_for_user(user=request.user, vv_id=vv.pk)  # type: ignore[arg-type]
    }
    response = JsonResponse(storage, json_dumps_params={"ensure_ascii": False, "indent": 2})
    filename = f"{slugify(vv.name) or 'vv'}-{str(vv.pk)[:8]}-storage.json"
    response["Content-Disposition"] = f'attachment; filename="{filename}"'
    return response


# --- the map ----------------------------------------------------------------------------------


# Stands for the chosen VV's id in the URL of its history that the live map's page is given.
_CHOSEN_VV = uuid.UUID(int=0)


@customer_or_staff_required
def live_map(request: HttpRequest) -> HttpResponse:
    """The live map: the user's VVs (every VV and vehicle for staff), fed by /ws/map/, with
    filters (static/js/live_map.js): a time window (staff start with the last 15 minutes) and
    one VV with its whole history (vv_map_history)."""
    context = {
        "socket_path": "/ws/map/",
        "tiles": settings.CPCC_MAP_TILES,
        "history_url": reverse("vv-map-history", args=[_CHOSEN_VV]),
        "history_placeholder": str(_CHOSEN_VV),
    }
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
