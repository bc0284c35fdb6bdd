"""The store: how the task path reads and writes the database, by intent (a held VV, a task's
answer, a step's effects, a journal entry, an RV's report, tasks put on its list), behind
which sit the SQL mechanics: statements compiled once (``cpcc_site.prepared``), writes sent
without waiting in a pipelined transaction, fenced UPDATEs that give back what the caller
needs, statements written by hand where the ORM would take two.

The services say what happens (``vvs``, ``steps``, ``routing``, ``waiting``, ``fleet``,
``journal``, ``messages``); this package says how it is kept. It is the only module of the
worker that writes SQL by hand or uses ``cpcc_site.prepared`` (the import contract
``rules-through-the-store`` and tests/cpcc_site/test_sql_by_hand.py hold it so).
"""

from vvm_worker.services.store.fleet_rows import (
    VEHICLE_TASK_COLUMNS,
    LandingRow,
    TakeOffRow,
    flights_write,
    ground_stations,
    open_tasks_of_vehicles,
    tasks_assigned,
    track_points_aboard,
    vehicle_report,
    vehicle_statuses,
    vehicle_statuses_later,
    vehicle_tasks,
    vehicles_in_fleet,
    vv_hosts,
)
from vvm_worker.services.store.journal_rows import journal_insert, journal_texts, jsonb_text
from vvm_worker.services.store.units import StepBroke, db_time_ago, rows_add, unit_of_work
from vvm_worker.services.store.vv_rows import (
    effects_write,
    locked_vv,
    locked_vv_later,
    next_task_etas_write,
    open_tasks_of,
    request_tasks_of,
    take_answer,
    vv_fields_save,
    vv_row,
    vv_save_changes,
)

__all__ = [
    "VEHICLE_TASK_COLUMNS",
    "LandingRow",
    "StepBroke",
    "TakeOffRow",
    "db_time_ago",
    "effects_write",
    "flights_write",
    "ground_stations",
    "journal_insert",
    "journal_texts",
    "jsonb_text",
    "locked_vv",
    "locked_vv_later",
    "next_task_etas_write",
    "open_tasks_of",
    "open_tasks_of_vehicles",
    "request_tasks_of",
    "rows_add",
    "take_answer",
    "tasks_assigned",
    "track_points_aboard",
    "unit_of_work",
    "vehicle_report",
    "vehicle_statuses",
    "vehicle_statuses_later",
    "vehicle_tasks",
    "vehicles_in_fleet",
    "vv_fields_save",
    "vv_hosts",
    "vv_row",
    "vv_save_changes",
]
