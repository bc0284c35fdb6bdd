"""The virtual vehicle monitor (VVM): loader, vehicle mapper, migrator and VV steps.

Every function here changes state in one transaction and then tells the dispatcher which host
must act next (DESIGN.md section 3). A VV moves through its life like this:

- ``vv_submit`` queues it; ``vv_admit_queued`` starts as many as the customer's quota of
  parallel VVs allows, each on a ground station (the loader).
- ``vv_advance`` is what the host holding a VV does with it: run the program to its next
  blocking call (a *step*, by replay of the journal), then route the pending task: keep it on
  this RV, migrate to an RV that can serve it, park on a ground station while only RVs in
  maintenance could, or, on a ground station, reject it so the program gets a
  TaskRejectedError. A VV that ends goes back to a ground station.
- ``task_complete`` records the readings an RV took as the answer in the VV's journal and
  resumes the VV on that RV.
"""

from vvm_worker.services.base import VVM, ProgramRejected
from vvm_worker.services.fleet import (
    vehicle_heartbeat,
    vehicle_reconfigured,
    vehicle_register,
    vehicle_set_status,
    vehicles_check_leases,
    vvs_reroute_waiting,
)
from vvm_worker.services.journal import JournalView
from vvm_worker.services.routing import fleet_caps, vehicle_caps
from vvm_worker.services.vvs import (
    MAX_STEPS_PER_ADVANCE,
    task_complete,
    vv_admit_queued,
    vv_advance,
    vv_cancel,
    vv_submit,
)

__all__ = [
    "MAX_STEPS_PER_ADVANCE",
    "VVM",
    "JournalView",
    "ProgramRejected",
    "fleet_caps",
    "task_complete",
    "vehicle_caps",
    "vehicle_heartbeat",
    "vehicle_reconfigured",
    "vehicle_register",
    "vehicle_set_status",
    "vehicles_check_leases",
    "vv_admit_queued",
    "vv_advance",
    "vv_cancel",
    "vv_submit",
    "vvs_reroute_waiting",
]
