"""The missions' admin shows times on the platform clock as UTC dates and positions rounded
to what they mean, never a float's every digit."""

from __future__ import annotations

from django.urls import reverse

from missions.models import LogEntry, Migration, Task
from tests.admin_numbers import RAW_FLOAT, cells


def test_a_vvs_times_positions_and_steps_are_dates_and_rounded_numbers(
    client, staff, mission
) -> None:
    # The in-process platform's clock starts at 2025-01-01 00:00 UTC, with the VV.
    task = mission.tasks.filter(status="done").order_by("q").first()
    Task.objects.filter(pk=task.pk).update(
        lat=48.11114444444, requested_s=3723.456789, done_s=3725.0123456
    )
    type(mission).objects.filter(pk=mission.pk).update(
        submitted_s=0.0123456789, finished_s=3726.98765432, last_step_s=0.0183456789
    )
    Migration.objects.filter(vv=mission).update(at_s=61.2345678)
    LogEntry.objects.filter(vv=mission).update(at_s=62.3456789)

    client.force_login(staff)
    page = client.get(reverse("admin:missions_virtualvehicle_change", args=[mission.pk]))
    shown = cells(page.text)
    for text in (
        "48.111144",
        "50.0 m",
        "2025-01-01 01:02:03.4 UTC",  # the task's request
        "2025-01-01 01:02:05.0 UTC",  # done
        "2025-01-01 00:00:00.0 UTC",  # the VV's submission
        "2025-01-01 01:02:06.9 UTC",  # its end
        "18.3 ms",  # its last step's replay
        "2025-01-01 00:01:01.2 UTC",  # a migration
    ):
        assert text in shown, text
    assert not RAW_FLOAT.search(shown), RAW_FLOAT.search(shown)
    # The floats themselves are not offered for editing instead.
    assert 'name="submitted_s"' not in page.text and 'name="last_step_s"' not in page.text

    lists = {
        "virtualvehicle": "2025-01-01 00:00:00.0 UTC",
        "task": "2025-01-01 01:02:03.4 UTC",
        "logentry": "2025-01-01 00:01:02.3 UTC",
        "migration": "2025-01-01 00:01:01.2 UTC",
    }
    for model, text in lists.items():
        listed = cells(client.get(reverse(f"admin:missions_{model}_changelist")).text)
        assert text in listed, (model, text)
        assert not RAW_FLOAT.search(listed), (model, RAW_FLOAT.search(listed))
