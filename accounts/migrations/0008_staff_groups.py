"""The staff groups (accounts.roles): fleet manager, pilot, support, with their permissions."""

from django.contrib.auth.management import create_permissions
from django.db import migrations

GROUPS = {
    "fleet manager": (
        "view:accounts",
        "view:fleet",
        "view:missions",
        "view:auditlog",
        *(
            f"fleet.{verb}_{model}"
            for model in ("vehicle", "groundstation", "noflyzone", "rallypoint", "sensortype")
            for verb in ("add", "change", "delete")
        ),
        "fleet.operate_vehicle",
        "accounts.change_customer",
        "accounts.add_serviceclass",
        "accounts.change_serviceclass",
        "accounts.delete_serviceclass",
        "missions.change_virtualvehicle",
    ),
    "pilot": (
        *(
            f"fleet.view_{model}"
            for model in (
                "vehicle",
                "groundstation",
                "noflyzone",
                "rallypoint",
                "sensortype",
                "pilotduty",
                "flight",
            )
        ),
        "fleet.operate_vehicle",
    ),
    "support": ("view:accounts", "view:fleet", "view:missions", "view:auditlog"),
}


def make_groups(apps, schema_editor):
    # The permissions are made after the last migration (post_migrate); these groups need
    # them now.
    for app_config in apps.get_app_configs():
        app_config.models_module = True
        create_permissions(app_config, apps=apps, verbosity=0)
        app_config.models_module = None
    from accounts.staff_groups import sync_staff_groups

    sync_staff_groups(apps, GROUPS)


def remove_groups(apps, schema_editor):
    apps.get_model("auth", "Group").objects.filter(name__in=GROUPS).delete()


class Migration(migrations.Migration):
    dependencies = [
        ("accounts", "0007_roles_and_invites"),
        ("fleet", "0010_pilots"),
        ("missions", "0014_task_requested_index"),
        ("auditlog", "__latest__"),
        ("auth", "__latest__"),
        ("contenttypes", "__latest__"),
    ]

    operations = [migrations.RunPython(make_groups, remove_groups)]
