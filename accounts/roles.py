"""Who may do what: the roles of a customer's members and the platform's staff groups.

A pure core (no Django): the edges ask it whether a role allows an action and word the
refusal; the models and the migration name the same roles.

A customer's members are ``owner``, ``developer`` or ``viewer``, each allowing what the one
below allows and more:

- viewer: read everything of the customer (VVs, their data, tasks, logs, webhooks, members);
  change nothing of it. Their own account stays theirs: password, e-mail choice, API tokens
  (each carrying at most their role).
- developer: also submit, edit, restart and cancel the customer's VVs, send them messages,
  try programs (the dry run), make and remove webhooks.
- owner: also invite members, change their roles and remove them.

A token acts with its user's role, or with a narrower one chosen when it was made (a
read-only token for a dashboard); never a wider one.
"""

from __future__ import annotations

OWNER = "owner"
DEVELOPER = "developer"
VIEWER = "viewer"

# From the least to the most allowed.
CUSTOMER_ROLES = (VIEWER, DEVELOPER, OWNER)
ROLE_LABELS = {
    OWNER: "Owner: everything, and the members",
    DEVELOPER: "Developer: submit, edit and cancel VVs, webhooks",
    VIEWER: "Viewer: read only",
}
_RANK = {role: n for n, role in enumerate(CUSTOMER_ROLES)}

# The platform's staff groups (Django groups made by accounts' migration 0014).
FLEET_MANAGER = "fleet manager"
PILOT = "pilot"
SUPPORT = "support"
STAFF_GROUPS = (FLEET_MANAGER, PILOT, SUPPORT)


def is_role(value: object) -> bool:
    return isinstance(value, str) and value in _RANK


def allows(role: str | None, needed: str) -> bool:
    """Whether ``role`` may do what needs ``needed`` (no role: nothing)."""
    return role is not None and _RANK.get(role, -1) >= _RANK[needed]


def narrower(role: str, other: str | None) -> str:
    """The narrower of two roles (``other`` None or blank: ``role``)."""
    if not other:
        return role
    return role if _RANK[role] <= _RANK[other] else other


def refusal(needed: str, role: str | None, action: str = "this") -> str:
    """The sentence a refused member reads: what the action needs and what they act as."""
    acting = f"you act as {role}" if role else "you are not a member of a customer"
    return (
        f"Doing {action} needs the {needed} role or higher; {acting}. Ask an owner of your "
        "customer if you need to."
    )
