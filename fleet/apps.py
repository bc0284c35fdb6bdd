from django.apps import AppConfig


class FleetConfig(AppConfig):
    name = "fleet"
    verbose_name = "Fleet"

    def ready(self) -> None:
        from auditlog.registry import auditlog

        from fleet import signals  # noqa: F401 - connects the receivers
        from fleet.models import (
            Battery,
            GroundStation,
            MaintenanceInterval,
            MaintenanceRecord,
            SensorType,
            Vehicle,
        )

        # Who changed what, in the admin and over the API (the vehicle's live state, written
        # by its worker with .update(), is not a change anyone made).
        auditlog.register(SensorType)
        auditlog.register(GroundStation)
        auditlog.register(
            Vehicle,
            m2m_fields={"sensors", "pilots"},
            exclude_fields=["lat", "lng", "alt", "phase", "distance_m", "flight_s", "tasks_done",
                            "planner_state", "worker_seen", "updated"],
        )  # fmt: skip
        # Maintenance: who recorded what, the intervals, and a person's battery swaps (what
        # its RV's worker reports of a battery is written with .update(): not audited).
        auditlog.register(MaintenanceRecord)
        auditlog.register(MaintenanceInterval)
        auditlog.register(Battery, include_fields=["name", "serial", "vehicle", "retired"])
