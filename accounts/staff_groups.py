"""The staff groups' permissions (accounts.roles: fleet manager, pilot, support).

Migration 0008 makes the groups with the permissions of that time; after every ``migrate`` the
groups get what this table says (``sync_staff_groups``), so a model added later is covered
without a migration of its own. A superuser keeps everything; a staff user in no group has the
permissions the admin gave them, as before.
"""

from __future__ import annotations

from typing import Any

from accounts.roles import FLEET_MANAGER, PILOT, SUPPORT

# Models whose rows hold secrets (token keys): nobody reads them but a superuser.
SECRET_MODELS = frozenset({("authtoken", "tokenproxy"), ("authtoken", "token")})
# The apps whose every model support and the fleet managers read.
READ_APPS = ("accounts", "fleet", "missions", "auditlog")

FLEET_MODELS = ("vehicle", "groundstation", "noflyzone", "rallypoint", "sensortype")
# Batteries and maintenance intervals: fleet managers change them; maintenance records are
# added (through the service), never changed.
MAINTENANCE_MODELS = ("battery", "maintenanceinterval")

# Per group: (app label, codename) pairs; "view:<app>" stands for every view_ permission of the
# app's models (the secret ones left out).
STAFF_GROUP_PERMISSIONS: dict[str, tuple[str, ...]] = {
    FLEET_MANAGER: (
        *(f"view:{app}" for app in READ_APPS),
        *(
            f"fleet.{verb}_{model}"
            for model in FLEET_MODELS
            for verb in ("add", "change", "delete")
        ),
        "fleet.operate_vehicle",
        *(
            f"fleet.{verb}_{model}"
            for model in MAINTENANCE_MODELS
            for verb in ("add", "change", "delete")
        ),
        "fleet.add_maintenancerecord",
        "fleet.swap_battery",
        # Customers' quotas and classes (not adding or removing customers: a superuser's).
        "accounts.change_customer",
        "accounts.add_serviceclass",
        "accounts.change_serviceclass",
        "accounts.delete_serviceclass",
        # Cancelling a VV that harms the fleet.
        "missions.change_virtualvehicle",
    ),
    PILOT: (
        *(
            f"fleet.view_{model}"
            for model in (*FLEET_MODELS, "pilotduty", "flight", *MAINTENANCE_MODELS)
        ),
        "fleet.view_maintenancerecord",
        "fleet.operate_vehicle",
        # A battery swap on the RVs they are assigned.
        "fleet.swap_battery",
    ),
    SUPPORT: tuple(f"view:{app}" for app in READ_APPS),
}


def sync_staff_groups(apps: Any, table: dict[str, tuple[str, ...]] | None = None) -> None:
    """Make the staff groups and give each exactly the permissions of ``table`` (this module's
    by default) that exist now; ``apps``: the app registry (a migration's historical one)."""
    Group = apps.get_model("auth", "Group")
    Permission = apps.get_model("auth", "Permission")
    every = {
        (p.content_type.app_label, p.codename): p
        for p in Permission.objects.select_related("content_type")
    }
    for name, entries in (table or STAFF_GROUP_PERMISSIONS).items():
        wanted = []
        for entry in entries:
            if entry.startswith("view:"):
                app = entry.removeprefix("view:")
                wanted += [
                    p
                    for (label, codename), p in every.items()
                    if label == app
                    and codename.startswith("view_")
                    and (label, codename.removeprefix("view_")) not in SECRET_MODELS
                    and codename != "view_apitoken"
                ]
            else:
                app, codename = entry.split(".", 1)
                if (app, codename) in every:
                    wanted.append(every[(app, codename)])
        group, _ = Group.objects.get_or_create(name=name)
        group.permissions.set(wanted)
