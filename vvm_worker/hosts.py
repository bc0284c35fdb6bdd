"""The hosts of the distributed platform: a ground station's worker and an RV's worker.

Each worker process is a Celery worker on its host's own queue (``gs.<id>``, ``rv.<id>``) that
runs one host object. Celery messages only say "look at this VV" or "look at your tasks": the
database holds all state, so a worker that starts (or restarts after a crash) first recovers
everything its host is responsible for, and a message delivered twice finds nothing to do.

An RV's worker does all its VVM work in one thread of its own, the host thread: the VV steps
(with the warm V8 contexts of the VVs aboard), and the vehicle's control loop, which needs
timers (flights take time). Celery tasks hand work to that thread and wait until it is
committed, so a message is acknowledged only after its checkpoint is in the database.
"""

from __future__ import annotations

import concurrent.futures
import heapq
import logging
import queue
import threading
import time
import uuid
from collections.abc import Callable
from typing import Any

from django.conf import settings
from django.db import close_old_connections, connection
from django.db.models import Q, QuerySet

from cpcc_site import database
from fleet.mavlink.driver import MavlinkDriver
from fleet.mavlink.errors import MavlinkError
from fleet.models import Driver, GroundStation, Vehicle, VehicleStatus
from missions.models import ACTIVE_STATUSES, VirtualVehicle, VVStatus
from vvm_worker.clock import Clock
from vvm_worker.executor import build_rig, kinematics
from vvm_worker.live import publish_vehicle
from vvm_worker.planning import DEFAULT_PLANNER
from vvm_worker.platform import platform_vvm
from vvm_worker.services import (
    VVM,
    LeasesUnsure,
    vehicle_heartbeat,
    vehicle_register,
    vehicle_set_status,
    vehicles_check_leases,
    vv_admit_queued,
    vv_advance,
    vvs_reroute_waiting,
)
from vvm_worker.services.base import announcing, db_time_ago
from vvm_worker.services.routing import online_vehicles

logger = logging.getLogger("cpcc.hosts")

# With time acceleration 0 ("instant flights") a simulated vehicle flies this much faster.
INSTANT = 1e6
WAIT_S = 60.0  # how long a Celery task waits for the host thread
SWEEP_S = 5.0  # how often a host looks for work a lost message would have started
WAITING_LOOK_S = 30.0  # how often a ground station routes a VV waiting for an RV again


class RealTimeScheduler:
    """Timers on the platform clock and work from other threads, run in one thread.

    ``call_at`` is for the host thread itself (the vehicle's control loop); ``submit`` for any
    thread, which gets a future for the result.
    """

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = 0
        self._inbox: queue.SimpleQueue[tuple[Callable[[], Any], concurrent.futures.Future[Any]]] = (
            queue.SimpleQueue()
        )
        self._stopping = threading.Event()

    def call_at(self, t_s: float, fn: Callable[[], None]) -> None:
        self._seq += 1
        heapq.heappush(self._timers, (t_s, self._seq, fn))

    def submit(self, fn: Callable[[], Any]) -> concurrent.futures.Future[Any]:
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        self._inbox.put((fn, future))
        return future

    def stop(self) -> None:
        self._stopping.set()
        self.submit(lambda: None)  # wake the thread up

    def run(self) -> None:
        # Work from other threads (a VV arriving, say) goes before the next timer, and one
        # timer runs between two looks at the inbox: with instant flights a vehicle always has
        # a timer due, which must not keep arriving VVs waiting.
        while not self._stopping.is_set():
            wait = 0.5
            if self._timers:
                wait = min(wait, max(0.0, self._timers[0][0] - self.clock.now_s()))
            try:
                fn, future = self._inbox.get(timeout=wait)
            except queue.Empty:
                pass
            else:
                self._run(fn, future)
                while True:
                    try:
                        fn, future = self._inbox.get_nowait()
                    except queue.Empty:
                        break
                    self._run(fn, future)
            if self._timers and self._timers[0][0] <= self.clock.now_s():
                _, _, timer = heapq.heappop(self._timers)
                self._run(timer, None)

    def _run(self, fn: Callable[[], Any], future: concurrent.futures.Future[Any] | None) -> None:
        """Run one piece of work. A database outage is waited out and the work done again, so
        that no timer of the vehicle's control loop is lost to it."""
        close_old_connections()
        try:
            result = database.through_outages(fn, self._stopping)
        except Exception as exc:
            logger.exception("host work failed")
            if future is not None:
                future.set_exception(exc)
        else:
            if future is not None:
                future.set_result(result)


class RVHost:
    """The worker of one real vehicle: the VVs aboard and the vehicle's control loop."""

    def __init__(self, vehicle: Vehicle, *, speed: float, planner: str = DEFAULT_PLANNER) -> None:
        self.vehicle_id = vehicle.pk
        self.name = vehicle.name
        self.vvm = platform_vvm(local=self)
        self.clock = self.vvm.clock
        self.scheduler = RealTimeScheduler(self.clock)
        # Simulated flights: time acceleration shortens them (distances stay right), and the
        # battery and its charging with them. A MAVLink vehicle flies as fast as it flies:
        # the same acceleration only tells the estimates what a `mavsim --speed` does.
        scale = INSTANT if speed <= 0 else speed
        self._link_down = False
        driver: MavlinkDriver | None = None
        if vehicle.driver == Driver.MAVLINK:
            if speed <= 0:
                raise ValueError("a MAVLink vehicle cannot fly instantly: set CPCC_SIM_SPEED > 0")
            driver = MavlinkDriver(
                vehicle.driver_url,
                spec=kinematics(vehicle, scale=scale),
                depot=vehicle.depot,
                area=vehicle.area,
                min_altitude_m=vehicle.min_altitude_m,
                max_altitude_m=vehicle.max_altitude_m,
                clock=self.clock.now_s,
                link_timeout_s=settings.CPCC_MAVLINK_LINK_TIMEOUT_S,
                on_link_lost=lambda: self.scheduler.submit(self._link_lost),
                name=vehicle.name,
            )
            driver.connect(timeout_s=settings.CPCC_MAVLINK_CONNECT_S)
        self.rig = build_rig(
            vehicle,
            vvm=self.vvm,
            scheduler=self.scheduler,
            planner=planner,
            scale=scale,
            driver=driver,
            plan_time_limit_s=settings.CPCC_PLAN_TIME_LIMIT_S,
            live=announcing(self.vvm),
        )
        self.driver = self.rig.driver
        self.loop = self.rig.loop
        self._thread = threading.Thread(target=self._run, name=f"rv-{vehicle.pk}", daemon=True)

    # --- LocalHost (vvm_worker.dispatch): work this host does itself -------------------------

    def is_vehicle(self, vehicle_id: int) -> bool:
        return vehicle_id == self.vehicle_id

    def advance_later(self, vv_id: uuid.UUID) -> None:
        self.scheduler.submit(lambda: vv_advance(vv_id=vv_id, vvm=self.vvm))

    def wake_later(self) -> None:
        # This host changed its own work (a VV it advanced): no new fence, and no second plan
        # if the loop plans anyway before it gets to this.
        # (On this thread, in the commit of the change: the store forgets what it read now.)
        self.scheduler.submit(self.rig.changed())

    # --- what Celery tasks ask -----------------------------------------------------------------

    def advance(self, vv_id: uuid.UUID) -> None:
        self.scheduler.submit(lambda: vv_advance(vv_id=vv_id, vvm=self.vvm)).result(WAIT_S)

    def wake(self) -> None:
        self.scheduler.submit(self._changed).result(WAIT_S)

    def _changed(self) -> None:
        """The vehicle's work, status or configuration changed: re-plan, and give a MAVLink
        vehicle its new geofence if its area or altitudes changed."""
        if isinstance(self.driver, MavlinkDriver) and self.driver.link_ok:
            vehicle = Vehicle.objects.get(pk=self.vehicle_id)
            wanted = (
                [(lat, lng) for lat, lng in vehicle.area[:-1]],
                vehicle.min_altitude_m,
                vehicle.max_altitude_m,
            )
            if self.driver.fence is None or _fence_differs(self.driver.fence, wanted):
                try:
                    self.driver.upload_fence(
                        vehicle.area, vehicle.min_altitude_m, vehicle.max_altitude_m
                    )
                except MavlinkError:
                    logger.exception("geofence not uploaded", extra={"vehicle": self.name})
        self.rig.store.changed()
        self.loop.wake()

    def _link_lost(self) -> None:
        """The vehicle stopped answering: like an RV taken out of service, its VVs move on
        (a reading it may still report is refused); it comes back when the link does."""
        logger.warning("vehicle link lost", extra={"vehicle": self.name})
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        if vehicle.status == VehicleStatus.ACTIVE:
            self._link_down = True
            vehicle_set_status(vehicle=vehicle, status=VehicleStatus.MAINTENANCE, vvm=self.vvm)

    def _link_check(self) -> None:
        if not self._link_down or not getattr(self.driver, "link_ok", True):
            return
        self._link_down = False
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        if vehicle.status == VehicleStatus.MAINTENANCE:
            logger.warning("vehicle link back: in service again", extra={"vehicle": self.name})
            vehicle_set_status(vehicle=vehicle, status=VehicleStatus.ACTIVE, vvm=self.vvm)

    # --- life ---------------------------------------------------------------------------------

    def start(self) -> None:
        self._thread.start()
        self.scheduler.submit(self._recover).result(WAIT_S)
        logger.info("rv worker started", extra={"vehicle": self.name})

    def stop(self) -> None:
        self.scheduler.stop()
        self._thread.join(timeout=10)

    def _run(self) -> None:
        try:
            self.scheduler.run()
        finally:
            self.vvm.runtime.close()
            if isinstance(self.driver, MavlinkDriver):
                self.driver.close()
            connection.close()

    def _recover(self) -> None:
        """Take up whatever this RV was doing: VVs aboard, its open tasks, and any VV waiting
        for an RV that this one can serve."""
        self._heartbeat()
        aboard = VirtualVehicle.objects.filter(
            host_rv_id=self.vehicle_id, status__in=ACTIVE_STATUSES
        )
        advance_each(aboard, vvm=self.vvm, vehicle=self.name)
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        vehicle_register(vehicle=vehicle, vvm=self.vvm)
        self.rig.store.changed()
        self.loop.wake()
        self.scheduler.call_at(self.clock.now_s() + SWEEP_S, self._sweep)
        self._beacon()

    def _beacon(self) -> None:
        """Tell the live maps where the vehicle is, what it carries and where it goes next."""
        now = self.clock.now_s()
        state = self.loop.live_state(now)
        publish_vehicle(
            state | {"id": self.vehicle_id, "name": self.name, "t": self.clock.epoch_ms(now) / 1000}
        )
        self.scheduler.call_at(now + settings.CPCC_MAP_TICK_S, self._beacon)

    def _heartbeat(self) -> None:
        vehicle_heartbeat(vehicle_id=self.vehicle_id, vvm=self.vvm)
        self._link_check()
        self.scheduler.call_at(self.clock.now_s() + settings.CPCC_RV_LEASE_S / 4, self._heartbeat)

    def _sweep(self) -> None:
        """Messages are hints: now and then, look for VVs aboard that wait for this host."""
        advance_each(stalled(host_rv_id=self.vehicle_id), vvm=self.vvm, vehicle=self.name)
        self.rig.store.changed()  # what a lost message would have said
        self.loop.wake()
        self.scheduler.call_at(self.clock.now_s() + SWEEP_S, self._sweep)


class GSHost:
    """The worker of one ground station: loads new VVs, takes back the ones that end or wait,
    and watches the RVs' leases."""

    def __init__(self, station: GroundStation) -> None:
        self.station_id = station.pk
        self.name = station.name
        self.vvm = platform_vvm()
        self._stopping = threading.Event()
        self._watch = threading.Thread(target=self._watch_leases, name="lease-watch", daemon=True)
        # The sweep's memory (its thread's own). No RV's worker can renew its lease while the
        # database is down: after an outage, each gets a full lease's time to do so before
        # its VVs are moved off it.
        self._leases_from = 0.0  # time.monotonic() from which leases are checked
        self._online: set[int] = set()  # the RVs whose lease was valid at the last sweep

    def advance(self, vv_id: uuid.UUID) -> None:
        vv_advance(vv_id=vv_id, vvm=self.vvm)

    def admit(self, customer_id: int) -> None:
        vv_admit_queued(customer_id=customer_id, vvm=self.vvm)

    def wake(self) -> None:  # an RV's message that reached a ground station: nothing to do
        pass

    def start(self) -> None:
        here = VirtualVehicle.objects.filter(host_gs_id=self.station_id, status__in=ACTIVE_STATUSES)
        advance_each(here, vvm=self.vvm, ground_station=self.name)
        _admit_all(self.vvm)
        self._watch.start()
        logger.info("gs worker started", extra={"ground_station": self.name})

    def stop(self) -> None:
        self._stopping.set()
        self._watch.join(timeout=10)

    def _watch_leases(self) -> None:
        vvm = platform_vvm()  # a runtime of this thread's own
        try:
            while not self._stopping.wait(min(SWEEP_S, settings.CPCC_RV_LEASE_S / 4)):
                close_old_connections()
                try:
                    self.sweep_once(vvm)
                except Exception as exc:
                    if not database.is_outage(exc):
                        logger.exception("sweep failed", extra={"ground_station": self.name})
                        continue
                    logger.warning("database unavailable: the sweep waits")
                    if database.wait_until_available(self._stopping):
                        self._leases_from = time.monotonic() + settings.CPCC_RV_LEASE_S
        finally:
            connection.close()

    def sweep_once(self, vvm: VVM) -> None:
        """One look at what needs this station: the RVs' leases, the VVs that can go to an
        RV come back, the VVs here that a lost message left waiting, and queued VVs. A VV (or
        a customer's admission) whose work fails is logged and the others go on; a database
        outage is raised."""
        if time.monotonic() >= self._leases_from:
            try:
                vehicles_check_leases(vvm=vvm)
            except LeasesUnsure:
                self._leases_from = time.monotonic() + settings.CPCC_RV_LEASE_S
        # An RV whose lease came back (its worker stalled, or the database was down) may
        # serve VVs that were sent to wait meanwhile.
        now_online = set(online_vehicles(vvm).values_list("pk", flat=True))
        if now_online - self._online:
            vvs_reroute_waiting(vvm=vvm)
        self._online = now_online
        # Messages are hints: pick up what a lost one would have started, and look again at
        # VVs that have waited here for an RV for a while.
        waiting = stalled(host_gs_id=self.station_id, waiting_s=WAITING_LOOK_S)
        advance_each(waiting, vvm=vvm, ground_station=self.name)
        _admit_all(vvm)


def advance_each(vvs: QuerySet[VirtualVehicle], *, vvm: VVM, **host: str) -> None:
    """Advance these VVs, oldest first. One whose advance fails for another reason than a
    database outage (a platform bug) is logged, naming it, its customer and ``host``, and the
    others go on; an outage is raised, for the caller to wait out and do all again."""
    rows = list(vvs.order_by("submitted_s", "id").values_list("pk", "customer__slug"))
    for vv_id, customer in rows:
        try:
            vv_advance(vv_id=vv_id, vvm=vvm)
        except Exception as exc:
            if database.is_outage(exc):
                raise
            logger.exception(
                "vv advance failed", extra={"vv": str(vv_id), "customer": customer, **host}
            )


def _admit_all(vvm: VVM) -> None:
    """Start queued VVs of every customer as far as its quota allows. A customer whose
    admission fails (not for a database outage, which is raised) is logged; the others go on."""
    queued = VirtualVehicle.objects.filter(status=VVStatus.QUEUED).order_by("customer_id")
    for customer_id, customer in queued.values_list("customer_id", "customer__slug").distinct():
        try:
            vv_admit_queued(customer_id=customer_id, vvm=vvm)
        except Exception as exc:
            if database.is_outage(exc):
                raise
            logger.exception("admission failed", extra={"customer": customer})


def stalled(*, waiting_s: float | None = None, **host: int) -> QuerySet[VirtualVehicle]:
    """VVs on a host that have not moved for a while although they could: answered but not
    resumed, or arrived but not taken up (their message was lost); with ``waiting_s``, also
    those that have waited that long for an RV (routed again, they wait ``waiting_s`` more)."""
    moving = Q(status=VVStatus.MIGRATING) | Q(status=VVStatus.RUNNING, pending__isnull=True)
    look = Q(updated__lt=db_time_ago(SWEEP_S)) & moving
    if waiting_s is not None:
        look |= Q(
            status=VVStatus.RUNNING, pending__isnull=False, updated__lt=db_time_ago(waiting_s)
        )
    return VirtualVehicle.objects.filter(look, **host)


_host: RVHost | GSHost | None = None


def _fence_differs(
    fence: tuple[list[tuple[float, float]], float, float],
    wanted: tuple[list[tuple[float, float]], float, float],
) -> bool:
    (have, low, high), (want, want_low, want_high) = fence, wanted
    if (low, high) != (want_low, want_high) or len(have) != len(want):
        return True
    return any(
        abs(a - c) > 1e-7 or abs(b - d) > 1e-7 for (a, b), (c, d) in zip(have, want, strict=True)
    )


def set_host(host: RVHost | GSHost | None) -> None:
    global _host
    _host = host


def current_host() -> RVHost | GSHost | None:
    return _host
