"""Every state change of the platform, one named function each (the VVM's services).

The modules by subject: ``admission`` (a VV's way in), ``vvs`` (a VV's life: advancing,
answers, its end), ``steps`` (running a step and applying it), ``store`` (how a VV's unit of
work reads and writes: the only one with hand-written SQL of the task path), ``routing`` (the
vehicle mapper and the migrator), ``journal``, ``fleet`` (RVs and ground stations),
``customers`` (tenants, quotas and logins), ``user_actions`` (what a user does with their own
VVs) and ``scenarios``. Edges (REST views, pages, admin, Celery tasks, commands) call these
functions and nothing else that writes. Each changes state in one transaction and then tells
the dispatcher which host must act next (DESIGN.md section 3). A VV moves through its life like
this:

- ``vv_submit`` queues it (within the customer's quota of queued VVs); ``vv_admit_queued``
  starts as many as the customer's quota of parallel VVs allows, each on a ground station (the
  loader).
- ``vv_advance`` is what the host holding a VV does with it: run the program to its next
  blocking call (a *step*, by replay of the journal), then route the pending task: keep it on
  this RV, migrate to an RV that can serve it, park on a ground station while only RVs in
  maintenance could, or, on a ground station, reject it so the program gets a
  TaskRejectedError. A VV that ends goes back to a ground station.
- ``task_complete`` records the readings an RV took as the answer in the VV's journal and
  resumes the VV on that RV.

What a user does with their own VVs (the REST API and the web pages; ``user_actions``):
``vv_create_for_user`` and ``vv_create_copies_for_user`` (N copies at once), ``vvs_submit_many_for_user`` (several
programs at once, all or none: ``submissions``), ``vv_update_program_for_user`` (while it is
queued), ``vv_restart_for_user`` (a new VV with the program of an ended one) and
``vv_cancel_for_user``.

A customer's webhooks and e-mails (``notifications``, which the services that end a VV or
answer a task tell through ``vv_notify``) are used from their module; a user's API tokens are
the accounts' own (``accounts.services``).
"""

from vvm_worker.services.admission import VVQueueFull, vv_admit_queued, vv_submit
from vvm_worker.services.base import VVM, ProgramRejected, VVAlreadyEnded
from vvm_worker.services.batteries import battery_observe
from vvm_worker.services.customers import (
    CustomerBusy,
    CustomerConfig,
    customer_create,
    customer_delete,
    customer_limits,
    customer_update,
    user_set_login,
)
from vvm_worker.services.fleet import (
    REACH_FIELDS,
    DutyRefused,
    GroundStationBusy,
    GroundStationConfig,
    LeasesUnsure,
    VehicleConfig,
    VehicleRemoved,
    ground_station_create,
    ground_station_delete,
    ground_station_update,
    no_fly_zone_delete,
    no_fly_zone_save,
    rally_point_delete,
    rally_point_save,
    vehicle_command,
    vehicle_command_take,
    vehicle_create,
    vehicle_hand_over,
    vehicle_heartbeat,
    vehicle_reconfigured,
    vehicle_record_flights,
    vehicle_record_health,
    vehicle_record_state,
    vehicle_record_track,
    vehicle_register,
    vehicle_set_status,
    vehicle_take_duty,
    vehicle_update,
    vehicles_check_leases,
    vehicles_worker_stopped,
    vvs_reroute_waiting,
)
from vvm_worker.services.journal import JournalView
from vvm_worker.services.maintenance import (
    battery_swap,
    maintenance_record,
    vehicle_check_maintenance,
    vehicles_check_maintenance,
)
from vvm_worker.services.routing import fleet_airspace, fleet_caps, vehicle_caps
from vvm_worker.services.submissions import (
    MAX_SUBMISSIONS,
    Submission,
    SubmissionsRefused,
    vvs_submit_many_for_user,
)
from vvm_worker.services.user_actions import (
    MAX_COPIES,
    copy_names,
    vv_cancel_for_user,
    vv_create_copies_for_user,
    vv_create_for_user,
    vv_restart_for_user,
    vv_update_program_for_user,
)
from vvm_worker.services.vvs import (
    MAX_STEPS_PER_ADVANCE,
    NotACustomer,
    VVNotEnded,
    VVNotQueued,
    task_complete,
    vv_advance,
    vv_cancel,
)

__all__ = [
    "MAX_COPIES",
    "MAX_STEPS_PER_ADVANCE",
    "MAX_SUBMISSIONS",
    "REACH_FIELDS",
    "VVM",
    "CustomerBusy",
    "CustomerConfig",
    "DutyRefused",
    "GroundStationBusy",
    "GroundStationConfig",
    "JournalView",
    "LeasesUnsure",
    "NotACustomer",
    "ProgramRejected",
    "Submission",
    "SubmissionsRefused",
    "VVAlreadyEnded",
    "VVNotEnded",
    "VVNotQueued",
    "VVQueueFull",
    "VehicleConfig",
    "VehicleRemoved",
    "battery_observe",
    "battery_swap",
    "copy_names",
    "customer_create",
    "customer_delete",
    "customer_limits",
    "customer_update",
    "fleet_airspace",
    "fleet_caps",
    "ground_station_create",
    "ground_station_delete",
    "ground_station_update",
    "maintenance_record",
    "no_fly_zone_delete",
    "no_fly_zone_save",
    "rally_point_delete",
    "rally_point_save",
    "task_complete",
    "user_set_login",
    "vehicle_caps",
    "vehicle_check_maintenance",
    "vehicle_command",
    "vehicle_command_take",
    "vehicle_create",
    "vehicle_hand_over",
    "vehicle_heartbeat",
    "vehicle_reconfigured",
    "vehicle_record_flights",
    "vehicle_record_health",
    "vehicle_record_state",
    "vehicle_record_track",
    "vehicle_register",
    "vehicle_set_status",
    "vehicle_take_duty",
    "vehicle_update",
    "vehicles_check_leases",
    "vehicles_check_maintenance",
    "vehicles_worker_stopped",
    "vv_admit_queued",
    "vv_advance",
    "vv_cancel",
    "vv_cancel_for_user",
    "vv_create_copies_for_user",
    "vv_create_for_user",
    "vv_restart_for_user",
    "vv_submit",
    "vv_update_program_for_user",
    "vvs_reroute_waiting",
    "vvs_submit_many_for_user",
]
