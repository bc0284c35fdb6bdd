"""A VV's row is written at every task it is given (its host, its pending request, its step
count) and at every map tick its estimate moves: on PostgreSQL its pages keep 30 % free, so
that a new version of the row fits on the page of the old one and most writes leave the
indexes alone (a heap-only tuple update). Measured with bench.platform: 56 % of the VV rows'
updates heap-only instead of 33 %, 0.1-0.2 ms less of PostgreSQL's CPU a task."""

from django.db import migrations

FILLFACTOR = 70


def keep_room(apps, schema_editor):
    if schema_editor.connection.vendor == "postgresql":
        schema_editor.execute(f"ALTER TABLE missions_virtualvehicle SET (fillfactor = {FILLFACTOR})")


def fill_up(apps, schema_editor):
    if schema_editor.connection.vendor == "postgresql":
        schema_editor.execute("ALTER TABLE missions_virtualvehicle RESET (fillfactor)")


class Migration(migrations.Migration):
    dependencies = [("missions", "0010_composite_indexes_only")]
    operations = [migrations.RunPython(keep_room, fill_up)]
