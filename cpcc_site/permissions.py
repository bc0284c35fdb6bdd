"""Who may do what, at the edges: a customer's member by role (accounts.roles), staff by the
permissions of their groups (accounts.staff_groups).

- ``MemberRole`` (every API view's default, beside IsAuthenticated): a member whose role (or
  whose token's narrower role) is below what the request needs gets 403 saying which role it
  needs. It is asked before any object is looked up, so a refusal says nothing of whether an
  object exists; another customer's object still answers 404 to whoever may ask. Staff use
  the customer endpoints as staff: reading as their selectors allow, changing a customer's VV
  only with ``missions.change_virtualvehicle``.
- ``StaffPermission``: the staff endpoints; a view names the Django permission each action
  needs (``staff_perms``) or the model whose view/add/change/delete permissions its methods
  need (``staff_model``).
- ``member_refusal`` / ``staff_refusal``: the same decisions for the pages.
"""

from __future__ import annotations

from typing import Any

from django.db.models import Model
from rest_framework.exceptions import PermissionDenied
from rest_framework.permissions import SAFE_METHODS, BasePermission

from accounts.roles import DEVELOPER, VIEWER, allows, narrower, refusal
from cpcc_site.api import IsStaff

# What staff need to change a customer's VV (cancel, edit, message) through the customer
# endpoints and pages.
STAFF_VV_WRITE = "missions.change_virtualvehicle"
STAFF_REFUSAL = (
    "Your staff account may not do this: it needs the permission {perms}. Ask an administrator "
    "if you need to."
)


def acting_role(user: Any, auth: Any = None) -> str | None:
    """The role a member acts with: their own, or their token's when it is narrower. None for
    anyone who is not a customer's member (staff, nobody)."""
    if user is None or not getattr(user, "customer_id", None) or user.is_staff:
        return None
    return narrower(user.role, getattr(auth, "role", "") or "")


def needed_role(view: Any, method: str) -> str:
    """The role a request needs: the view's ``role_needed`` (by method, or one for all),
    else a viewer reads and a developer changes."""
    declared = getattr(view, "role_needed", None)
    if isinstance(declared, str):
        return declared
    if isinstance(declared, dict) and method in declared:
        return declared[method]  # type: ignore[no-any-return]
    return VIEWER if method in SAFE_METHODS else DEVELOPER


def member_refusal(user: Any, auth: Any, needed: str, action: str = "this") -> str | None:
    """Why a customer's member may not do what needs ``needed`` (None: they may, or the caller
    is not a member)."""
    role = acting_role(user, auth)
    if role is None or allows(role, needed):
        return None
    return refusal(needed, role, action)


def staff_refusal(user: Any, perms: tuple[str, ...]) -> str | None:
    """Why a staff user may not do what needs every one of ``perms`` (None: they may)."""
    if not user.is_staff:
        return "Only platform staff may do this."
    if user.has_perms(perms):
        return None
    return STAFF_REFUSAL.format(perms=" and ".join(perms))


def change_refusal(
    user: Any,
    auth: Any,
    needed: str,
    action: str = "this",
    staff_perms: tuple[str, ...] = (STAFF_VV_WRITE,),
) -> str | None:
    """Why the user may not make a change that needs ``needed`` of a customer's member (None:
    they may): staff need ``staff_perms`` (none: any staff user), a member the role. The API
    (``MemberRole``) and the pages ask the same."""
    if user.is_staff:
        return staff_refusal(user, staff_perms) if staff_perms else None
    return member_refusal(user, auth, needed, action)


class MemberRole(BasePermission):
    """The role a customer's request needs (``needed_role``); staff changing a customer's VV
    need STAFF_VV_WRITE unless the view says otherwise (``staff_write_perms``: () lets any
    staff user through, as for their own tokens)."""

    def has_permission(self, request: Any, view: Any) -> bool:
        user = request.user
        if user.is_staff and request.method in SAFE_METHODS:
            return True
        why = change_refusal(
            user,
            request.auth,
            needed_role(view, request.method),
            _action_words(view, request),
            tuple(getattr(view, "staff_write_perms", (STAFF_VV_WRITE,))),
        )
        if why is not None:
            raise PermissionDenied(why)
        return True


def _action_words(view: Any, request: Any) -> str:
    action = getattr(view, "action", None)
    name = getattr(view, "noun", None) or type(view).__name__.removesuffix("View")
    if action:
        return f"{action.replace('_', ' ')} of {name}"
    return f"{request.method} on {name}"


_METHOD_VERBS = {
    "GET": "view",
    "HEAD": "view",
    "OPTIONS": "view",
    "POST": "add",
    "PUT": "change",
    "PATCH": "change",
    "DELETE": "delete",
}


def model_perm(model: type[Model], verb: str) -> str:
    return f"{model._meta.app_label}.{verb}_{model._meta.model_name}"


class StaffPermission(IsStaff):
    """Staff only, each with the permission the action needs: ``view.staff_perms[action]`` (a
    ViewSet's action name, or the method), else the ``staff_model``'s permission for the
    method (view, add, change, delete). A view that names neither is a superuser's."""

    def has_permission(self, request: Any, view: Any) -> bool:
        if not super().has_permission(request, view):
            return False
        perms = staff_perms_needed(view, request.method)
        why = staff_refusal(request.user, perms)
        if why is not None:
            raise PermissionDenied(why)
        return True


def staff_perms_needed(view: Any, method: str) -> tuple[str, ...]:
    declared: dict[str, tuple[str, ...]] = getattr(view, "staff_perms", {})
    action = getattr(view, "action", None)
    if action in declared:
        return declared[action]
    if method in declared:
        return declared[method]
    if method in ("HEAD", "OPTIONS") and "GET" in declared:
        return declared["GET"]
    model = getattr(view, "staff_model", None)
    if model is None:
        return ("cpcc.superuser",)  # nobody holds it: a superuser has every permission
    return (model_perm(model, _METHOD_VERBS.get(method, "change")),)
