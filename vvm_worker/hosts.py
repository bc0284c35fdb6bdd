"""The hosts of the distributed platform: a ground station's worker and the RV worker.

Each worker process is a Celery worker on its hosts' own queues (``gs.<id>``, ``rv.<id>``)
that runs one host object. Celery messages only say "look at this VV" or "look at your tasks":
the database holds all state, so a worker that starts (or restarts after a crash) first
recovers everything its hosts are responsible for, and a message delivered twice finds nothing
to do.

An RV worker hosts one vehicle (on the vehicle's own computer) or several (simulated vehicles,
or MAVLink links that reach a server), and may host the ground station they start from too.
It does all its VVM work in one thread of its own, the host thread: the VV steps (with the
warm V8 contexts of the VVs aboard its vehicles, in one runtime), and each vehicle's control
loop, which needs timers (flights take time). Celery tasks hand work to that thread and wait
until it is committed, so a message is acknowledged only after its checkpoint is in the
database.
"""

from __future__ import annotations

import collections
import concurrent.futures
import heapq
import itertools
import logging
import queue
import signal
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from typing import Any

from django.conf import settings
from django.db import close_old_connections, connection, transaction
from django.db.models import Exists, OuterRef, Q, QuerySet

from cpcc_site import database
from fleet.driving import LINK_LOST
from fleet.geo import Position
from fleet.mavlink.driver import Fence, MavlinkDriver
from fleet.mavlink.errors import MavlinkError
from fleet.models import Driver, GroundStation, Vehicle, VehicleStatus
from fleet.selectors import VehicleFence, vehicle_fence
from missions.events import VEHICLE_STALE_S
from missions.models import ACTIVE_STATUSES, Task, TaskStatus, VirtualVehicle, VVStatus
from vvm_worker.clock import Clock
from vvm_worker.executor import RigFleet, build_rig, kinematics, read_aboard, time_scale
from vvm_worker.live import FeedAnnouncer, publish_vehicle
from vvm_worker.planning import DEFAULT_PLANNER, Planner, PlanTask
from vvm_worker.planning.remote import PlanAnswer, PlannerProcess
from vvm_worker.platform import platform_vvm
from vvm_worker.runtime import Runtime
from vvm_worker.runtime.pool import POOL
from vvm_worker.services import (
    VVM,
    LeasesUnsure,
    vehicle_check_maintenance,
    vehicle_heartbeat,
    vehicle_record_health,
    vehicle_register,
    vehicle_set_status,
    vehicles_check_leases,
    vehicles_check_maintenance,
    vehicles_worker_stopped,
    vv_admit_queued,
    vv_advance,
    vvs_reroute_waiting,
)
from vvm_worker.services.flight_logs import flight_logs_prune
from vvm_worker.services.routing import fleet_airspace, online_vehicles
from vvm_worker.services.store import db_time_ago

logger = logging.getLogger("cpcc.hosts")

WAIT_S = 60.0  # how long a Celery task waits for the host thread
SWEEP_S = 5.0  # how often a host looks for work a lost message would have started
# How often an RV worker deletes the flight logs past CPCC_FLIGHT_LOG_DAYS (the platform has no
# scheduler of its own; every worker doing it is harmless), first this long after it starts.
FLIGHT_LOG_PRUNE_S = 24 * 3600.0
FLIGHT_LOG_PRUNE_FIRST_S = 600.0
WAITING_LOOK_S = 30.0  # how often a ground station routes a VV waiting for an RV again
# Warm V8 contexts an RV worker keeps per vehicle it hosts (about 1 MB each, more for a VV
# with a large heap), and at most in all; a VV beyond them resumes by replay.
WARM_CONTEXTS = 64
MAX_CONTEXTS = 512
# A vehicle whose state does not change (landed, idle) tells the live maps again this often,
# well before they forget it.
BEACON_KEYFRAME_S = VEHICLE_STALE_S / 3


class NotYet(Exception):
    """Raised by a piece of work that would have to wait for something not there yet (a
    prepared isolate for a new VV's context), having arranged for ``resume_parked`` to be
    called once it is: the scheduler keeps the work, with its future, and goes on with other
    work meanwhile."""


class HostStopped(Exception):
    """Work the host thread had parked when it stopped: not done."""


class RealTimeScheduler:
    """Timers on the platform clock and work from other threads, run in one thread.

    ``call_at`` is for the host thread itself (the vehicles' control loops, the worker's own
    timers); ``submit`` for any thread, which gets a future for the result. Between two pieces
    of work the thread sleeps until the next timer is due or work comes in (0.5 s at most):
    idle, it wakes for timers only, however many vehicles it serves. Work that raises
    ``NotYet`` is parked, in order, until ``resume_parked``.
    """

    def __init__(self, clock: Clock, *, after_each: Callable[[], None] | None = None) -> None:
        self.clock = clock
        self._after_each = after_each  # after each piece of work (its changes published)
        self._timers: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = 0
        self._inbox: queue.SimpleQueue[tuple[Callable[[], Any], concurrent.futures.Future[Any]]] = (
            queue.SimpleQueue()
        )
        self._stopping = threading.Event()
        self._parked: collections.deque[
            tuple[Callable[[], Any], concurrent.futures.Future[Any] | None]
        ] = collections.deque()

    def call_at(self, t_s: float, fn: Callable[[], None]) -> None:
        self._seq += 1
        heapq.heappush(self._timers, (t_s, self._seq, fn))

    def submit(self, fn: Callable[[], Any]) -> concurrent.futures.Future[Any]:
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        self._inbox.put((fn, future))
        return future

    def resume_parked(self) -> None:
        """From any thread: run the parked work again, in its order (what it waited for may
        be there now)."""
        self.submit(self._resume)

    def _resume(self) -> None:
        parked, self._parked = self._parked, collections.deque()
        while parked:
            fn, future = parked.popleft()
            if not self._run(fn, future):
                self._parked.extend(parked)  # behind the one that still waits, in order
                return

    def stop(self) -> None:
        self._stopping.set()
        self.submit(lambda: None)  # wake the thread up

    def run(self) -> None:
        # Work from other threads (a VV arriving, say) goes before the next timers, and the
        # timers due at a look run before the next look, each vehicle's in turn: with instant
        # flights a vehicle always has a timer due, which must not keep arriving VVs waiting,
        # and a burst of arriving VVs must not keep the VVs aboard the vehicles waiting.
        while not self._stopping.is_set():
            wait = 0.5
            if self._timers:
                wait = min(wait, max(0.0, self._timers[0][0] - self.clock.now_s()))
            try:
                fn, future = self._inbox.get(timeout=wait)
            except queue.Empty:
                pass
            else:
                # What came in before this look; what that work sends here waits for the
                # next one, after the due timers (a chain of VV starts would hold every
                # arrival up).
                waiting = self._inbox.qsize()
                self._run(fn, future)
                for _ in range(waiting):
                    try:
                        fn, future = self._inbox.get_nowait()
                    except queue.Empty:
                        break
                    self._run(fn, future)
            # Every timer due now (those they set wait for the next look).
            now, last = self.clock.now_s(), self._seq
            while self._timers and self._timers[0][0] <= now and self._timers[0][1] <= last:
                _, _, timer = heapq.heappop(self._timers)
                self._run(timer, None)
        # Whoever waits for parked work learns at once that it was not done (the database
        # says where its VV is, and the next start takes it up).
        while self._parked:
            _, future = self._parked.popleft()
            if future is not None:
                future.set_exception(HostStopped("the host stopped before this work was done"))

    def _run(self, fn: Callable[[], Any], future: concurrent.futures.Future[Any] | None) -> bool:
        """Run one piece of work; False when it is parked (``NotYet``). A database outage is
        waited out and the work done again, so that no timer of the vehicle's control loop is
        lost to it."""
        close_old_connections()
        try:
            result = database.through_outages(fn, self._stopping)
        except NotYet:
            self._parked.append((fn, future))
            return False
        except Exception as exc:
            logger.exception("host work failed")
            if future is not None:
                future.set_exception(exc)
        else:
            if future is not None:
                future.set_result(result)
        if self._after_each is not None:
            self._after_each()
        return True


class CannotFly(Exception):
    """A vehicle of an RV worker cannot be flown: its MAVLink autopilot does not answer, or
    it is asked to fly instantly. The message names the vehicle and where it was sought."""

    def __init__(self, vehicle: Vehicle, cause: Exception) -> None:
        where = f" at {vehicle.driver_url}" if vehicle.driver_url else ""
        super().__init__(f"{vehicle.name}: cannot fly its vehicle{where}: {cause}")
        self.vehicle_name = vehicle.name


class HostPlanning:
    """The vehicles' plans of an RV worker (``control.PlanElsewhere``), made in its planner
    process (``planning.remote``) and followed on the host thread.

    The host thread sends each vehicle's planner once and then its requests; a thread of its
    own reads the answers and hands each back to the host thread. Should the process end (it
    was killed, it ran out of memory), the host thread makes the plans asked for and not
    answered itself, and a new process is started, unless the last one ended within
    ``RESTART_AFTER_S`` of its start: then the host thread plans from then on (logged), as
    it does when the process was stopped with SIGTERM (the worker's whole process group was:
    the worker is stopping too).
    """

    RESTART_AFTER_S = 60.0

    def __init__(self, scheduler: RealTimeScheduler) -> None:
        self.scheduler = scheduler
        self.process: PlannerProcess | None = None
        self._started_s = 0.0
        self._closing = False
        self._sent: dict[str, Planner] = {}  # each vehicle's planner the process has
        self._requests = itertools.count(1)
        # Each request not answered yet: its vehicle, planner, arguments and continuation.
        self._waiting: dict[
            int,
            tuple[str, Planner, Position, list[PlanTask], float, Callable[[list[PlanTask]], None]],
        ] = {}

    def start(self) -> None:
        process = PlannerProcess()
        self.process, self._started_s, self._sent = process, time.monotonic(), {}
        threading.Thread(target=self._read, args=(process,), name="cpcc-plans", daemon=True).start()

    def plan(
        self,
        vehicle: str,
        planner: Planner,
        current: Position,
        tasks: list[PlanTask],
        now_s: float,
        then: Callable[[list[PlanTask]], None],
    ) -> None:
        if self.process is None:
            then(planner.plan(current, tasks, now_s))
            return
        request = next(self._requests)
        self._waiting[request] = (vehicle, planner, current, tasks, now_s, then)
        try:
            if self._sent.get(vehicle) is not planner:
                self.process.send_planner(vehicle, planner)
                self._sent[vehicle] = planner
            self.process.ask(request, vehicle, planner.state(), current, tasks, now_s)
        except OSError:
            pass  # the process has ended: its reader hands the request back (`_ended`)

    def close(self) -> None:
        """Stop the planner process (without waiting: it ends when it reads the request)."""
        self._closing = True
        if self.process is not None:
            self.process.stop()

    def _read(self, process: PlannerProcess) -> None:
        for answer in process.answers():
            self.scheduler.submit(lambda answer=answer: self._answered(answer))
        self.scheduler.submit(lambda: self._ended(process))

    def _answered(self, answer: PlanAnswer) -> None:
        waiting = self._waiting.pop(answer.request, None)
        if waiting is None:
            return  # planned here meanwhile (`_ended`)
        vehicle, planner, _, tasks, _, then = waiting
        if answer.task_ids is None:
            raise PlanFailed(f"{vehicle}: the planner failed: {answer.error}")
        planner.restore(answer.state)
        by_id = {task.id: task for task in tasks}
        then([by_id[task_id] for task_id in answer.task_ids])

    def _ended(self, process: PlannerProcess) -> None:
        if self._closing or process is not self.process:
            return
        lived_s = time.monotonic() - self._started_s
        process.join(1.0)
        self.process = None
        if process.exitcode == -signal.SIGTERM:  # stopped with its worker's process group
            logger.info("the planner process was stopped: the vehicles are planned here")
        elif lived_s >= self.RESTART_AFTER_S:
            logger.error("the planner process ended: started again")
            self.start()
        else:
            logger.error(
                "the planner process ended %.0f s after its start: the vehicles are planned "
                "on the host thread from now on",
                lived_s,
            )
        waiting, self._waiting = self._waiting, {}
        for vehicle, planner, current, tasks, now_s, then in waiting.values():
            self.plan(vehicle, planner, current, tasks, now_s, then)


class PlanFailed(Exception):
    """A vehicle's planner raised in the planner process (the message says what)."""


class RVHost:
    """The worker of one or more real vehicles in one process: the VVs aboard them and their
    control loops, all on one host thread with one VVM (one V8 runtime and its warm contexts).

    Each vehicle has its own control loop (``HostedRV``) and its own Celery queue; the VVM's
    ``local_rvs`` names them all, so a VV that migrates between two of them keeps its warm
    context and goes over without a message. The timers that every vehicle needs (heartbeat,
    sweep, map beacon) are one timer each for the whole process, which serves every vehicle in
    turn: N idle vehicles wake the thread no more often than one. One vehicle is the worker
    of a vehicle's own computer, as before.

    With ``station`` it hosts that ground station too (``rvworker ... --station GS``): the
    station's work runs on the same thread with the same VVM, so a new VV's first step is made
    in this runtime and the VV goes aboard with its warm context, without a message; the
    station's lease watch runs on a thread of its own (``StationWatch``), as in a gsworker.
    """

    def __init__(
        self,
        vehicles: Sequence[Vehicle],
        *,
        speed: float,
        planner: str = DEFAULT_PLANNER,
        station: GroundStation | None = None,
    ) -> None:
        if not vehicles:
            raise ValueError("an RV worker hosts at least one vehicle")
        # A ground station hosted here too (a server that runs simulated RVs and the station
        # they start from): its VVs are stepped on the same host thread, in the same runtime,
        # so a VV that goes from the station to one of these RVs keeps its warm context and
        # goes over without a message, as between two of the RVs.
        self.watch = None if station is None else StationWatch(station)
        self.vvm = platform_vvm(local=self)
        # One runtime for every vehicle here: as many warm contexts per vehicle as a worker
        # of one vehicle keeps, up to what `simulate` keeps for a whole fleet.
        self.vvm.runtime = Runtime(max_contexts=min(WARM_CONTEXTS * len(vehicles), MAX_CONTEXTS))
        self.vvm.local_rvs = {vehicle.pk for vehicle in vehicles}
        self.clock = self.vvm.clock
        self.scheduler = RealTimeScheduler(self.clock, after_each=self.vvm.announcer.flush)
        # The vehicles' plans, made in a process of their own (planning.remote) while this
        # one serves the other vehicles; here, on the host thread, should that process end.
        self.planning = HostPlanning(self.scheduler)
        # The loops here, as the services tell them of work routed to them (no message).
        self.fleet = RigFleet(lambda rig, wake: self.scheduler.submit(wake), alone=False)
        self.vvm.local_fleet = self.fleet
        # What the map tick last read of the VVs aboard: at which count of the changes this
        # process published, and when it reads again anyway (`_aboard_may_have_changed`).
        self._aboard_seen: int | None = None
        self._aboard_due = 0.0
        self.rvs: dict[int, HostedRV] = {}
        for vehicle in vehicles:
            try:
                self.rvs[vehicle.pk] = HostedRV(vehicle, host=self, speed=speed, planner=planner)
                self.fleet.add(self.rvs[vehicle.pk].rig)
            except (MavlinkError, ValueError) as exc:
                self._close_drivers()
                raise CannotFly(vehicle, exc) from exc
            except BaseException:
                self._close_drivers()
                raise
        self.name = ", ".join(rv.name for rv in self.rvs.values())
        self._thread = threading.Thread(target=self._run, name="rv-host", daemon=True)

    # --- LocalHost (vvm_worker.dispatch): work this process does itself -----------------------

    def is_vehicle(self, vehicle_id: int) -> bool:
        return vehicle_id in self.rvs

    def is_station(self, station_id: int) -> bool:
        return self.watch is not None and station_id == self.watch.station_id

    def advance_later(self, vv_id: uuid.UUID) -> None:
        self.scheduler.submit(self._advancing(vv_id))

    def _advancing(self, vv_id: uuid.UUID) -> Callable[[], None]:
        """The work of advancing the VV on the host thread. A VV without a warm context here
        (a new one, or one from another process) needs an isolate: while none is prepared it
        waits parked, and the vehicles' timers and the other VVs go on, rather than the host
        thread waiting for V8 to make one (a burst of new VVs held up every VV aboard)."""

        def advance() -> None:
            if self.vvm.runtime.context(str(vv_id)) is None and POOL.notify_when_ready(
                self.scheduler.resume_parked
            ):
                raise NotYet(f"VV {vv_id}: no isolate prepared yet")
            vv_advance(vv_id=vv_id, vvm=self.vvm)

        return advance

    def wake_later(self, vehicle_id: int) -> None:
        # A vehicle here whose work this process changed (a VV it advanced, one that moved
        # between two of its vehicles): no new fence, and no second plan if the loop plans
        # anyway before it gets to this.
        # (On this thread, in the commit of the change: the store forgets what it read now.)
        self.scheduler.submit(self.rvs[vehicle_id].rig.changed())

    # --- what Celery tasks ask -----------------------------------------------------------------

    def advance(self, vv_id: uuid.UUID) -> None:
        self.scheduler.submit(self._advancing(vv_id)).result(WAIT_S)

    def admit(self, customer_id: int) -> None:
        self.scheduler.submit(
            lambda: vv_admit_queued(customer_id=customer_id, vvm=self.vvm)
        ).result(WAIT_S)

    def wake(self, vehicle_id: int) -> None:
        rv = self.rvs.get(vehicle_id)
        if rv is None:  # a message for a vehicle another process hosts now: not ours to do
            logger.warning("wake-up for a vehicle not hosted here", extra={"vehicle": vehicle_id})
            return
        self.scheduler.submit(rv.changed).result(WAIT_S)

    # --- life ---------------------------------------------------------------------------------

    def start(self) -> None:
        self.planning.start()
        self._thread.start()
        self.scheduler.submit(self._recover).result(WAIT_S * len(self.rvs))
        if self.watch is not None:
            # However many VVs wait on the station (once the RVs are in service).
            watch = self.watch
            self.scheduler.submit(lambda: watch.take_up(self.vvm)).result()
            watch.start()
        logger.info("rv worker started", extra={"vehicle": self.name})

    def stop(self) -> None:
        if self.watch is not None:
            self.watch.stop()
        self.scheduler.stop()
        self._thread.join(timeout=10)
        if self.watch is not None:
            self.watch.join()

    def _run(self) -> None:
        try:
            self.scheduler.run()
            try:  # what the loops said last, for the next start and the API
                self._each(lambda rv: rv.rig.store.write_waiting(), "report")
                # The operator sees at once that nobody drives them (their VVs move on
                # when the lease runs out, unless the worker is back by then).
                vehicles_worker_stopped(vehicle_ids=list(self.rvs))
            except Exception:
                logger.warning("the vehicles' last reports are lost: the database is away")
            self.vvm.announcer.close()
        finally:
            self.planning.close()
            self.vvm.runtime.close()
            self._close_drivers()
            connection.close()

    def _close_drivers(self) -> None:
        for rv in self.rvs.values():
            rv.close()

    def _recover(self) -> None:
        """Take up whatever the vehicles were doing. Every lease is renewed first, so that a
        VV aboard one of them whose next task another serves goes straight there. (Done again
        after a database outage: the timers start only once it is all done.)"""
        self._renew_leases()
        for rv in self.rvs.values():
            rv.recover()
        now = self.clock.now_s()
        self.scheduler.call_at(now + settings.CPCC_RV_LEASE_S / 4, self._heartbeat)
        self.scheduler.call_at(now + SWEEP_S, self._sweep)
        self.scheduler.call_at(now, self._beacon)
        self.scheduler.call_at(now + FLIGHT_LOG_PRUNE_FIRST_S, self._prune_flight_logs)

    def _each(self, work: Callable[[HostedRV], None], what: str) -> None:
        """Do a vehicle's part of a periodic job for each vehicle: one whose part fails for
        another reason than a database outage is logged and the others go on; an outage is
        raised (the scheduler waits it out and does the job again, which is safe to redo)."""
        for rv in self.rvs.values():
            try:
                work(rv)
            except Exception as exc:
                if database.is_outage(exc):
                    raise
                logger.exception("%s failed", what, extra={"vehicle": rv.name})

    def _renew_leases(self) -> None:
        """Every vehicle here is alive: their leases in one commit (the commit is most of
        what a heartbeat costs), then each MAVLink link that came back is in service again."""
        try:
            with transaction.atomic():
                for rv in self.rvs.values():
                    vehicle_heartbeat(vehicle_id=rv.vehicle_id, vvm=self.vvm)
        except Exception as exc:
            if database.is_outage(exc):
                raise
            logger.exception("heartbeat failed", extra={"vehicle": self.name})
        self._each(HostedRV.link_check, "link check")

    def _heartbeat(self) -> None:
        self._renew_leases()
        self.scheduler.call_at(self.clock.now_s() + settings.CPCC_RV_LEASE_S / 4, self._heartbeat)

    def _sweep(self) -> None:
        """Messages are hints: now and then, look for VVs aboard the vehicles here that wait
        for this worker, and tell each vehicle's loop what a lost message would have told it.
        Two queries for all the vehicles, whatever their number."""
        ids = list(self.rvs)
        advance_each(stalled(host_rv_id__in=ids), vvm=self.vvm, vehicle=self.name)
        open_tasks = Task.objects.filter(vehicle_id=OuterRef("pk"), status=TaskStatus.OPEN)
        rows = (
            Vehicle.objects.filter(pk__in=ids)
            .annotate(busy=Exists(open_tasks))
            .values_list("pk", "status", "busy", "command", "command_taken")
        )
        # An operator's command its loop has not taken is work too (its message was lost).
        seen = {
            pk: (status, busy or (bool(command) and taken is None))
            for pk, status, busy, command, taken in rows
        }
        self._each(lambda rv: rv.look_again(*seen.get(rv.vehicle_id, (None, True))), "sweep")
        self.scheduler.call_at(self.clock.now_s() + SWEEP_S, self._sweep)

    def _prune_flight_logs(self) -> None:
        """Daily: the flight logs older than CPCC_FLIGHT_LOG_DAYS go, and the maintenance
        due by the days passed grounds its RVs (what flights make due is looked at when
        each flight ends)."""
        try:
            flight_logs_prune()
            vehicles_check_maintenance(vvm=self.vvm)
        except Exception as exc:
            if database.is_outage(exc):
                raise
            logger.exception("flight log prune failed", extra={"vehicle": self.name})
        self.scheduler.call_at(self.clock.now_s() + FLIGHT_LOG_PRUNE_S, self._prune_flight_logs)

    def _aboard_may_have_changed(self, now: float) -> bool:
        """Whether the map tick reads the VVs aboard the vehicles again: after work of this
        process that changed something (a VV that boards, leaves or ends here announces it),
        else every BEACON_KEYFRAME_S (what another process changed alone, such as a VV
        cancelled on the web while it waits aboard). An idle worker then reads nothing at its
        ticks (on SQLite, a connection opened and closed for each)."""
        announcer = self.vvm.announcer
        published = announcer.published if isinstance(announcer, FeedAnnouncer) else None
        if published is not None and published == self._aboard_seen and now < self._aboard_due:
            return False
        self._aboard_seen, self._aboard_due = published, now + BEACON_KEYFRAME_S
        return True

    def _beacon(self) -> None:
        """The map tick: the reports that wait are written, then the live maps are told
        where each vehicle is and what it carries."""
        now = self.clock.now_s()
        self._each(lambda rv: rv.rig.store.write_waiting(), "report")
        if self.vvm.listened and self._aboard_may_have_changed(now):
            aboard = read_aboard(list(self.rvs))
            self._each(lambda rv: rv.rig.store.seen_aboard(aboard[rv.vehicle_id]), "map")
        self._each(lambda rv: rv.beacon(now), "map beacon")
        self.scheduler.call_at(now + settings.CPCC_MAP_TICK_S, self._beacon)


class HostedRV:
    """One real vehicle of an RV worker: its control loop (``build_rig``), its driver, and
    the vehicle's part of the worker's recovery, sweep, map beacon and link checks. Runs on
    the worker's host thread, with the worker's VVM."""

    def __init__(
        self, vehicle: Vehicle, *, host: RVHost, speed: float, planner: str = DEFAULT_PLANNER
    ) -> None:
        self.vehicle_id = vehicle.pk
        self.name = vehicle.name
        self.kind = vehicle.kind
        self.host = host
        vvm, scheduler = host.vvm, host.scheduler
        scale = time_scale(vehicle, speed)
        self._link_down = False
        driver: MavlinkDriver | None = None
        if vehicle.driver == Driver.MAVLINK:
            fence = vehicle_fence(vehicle=vehicle)
            driver = MavlinkDriver(
                vehicle.driver_url,
                spec=kinematics(vehicle, scale=scale),
                depot=vehicle.depot,
                area=fence.area,
                min_altitude_m=fence.min_altitude_m,
                max_altitude_m=fence.max_altitude_m,
                exclusions=fence.exclusions,
                rally=fence.rally,
                clock=vvm.clock.now_s,
                link_timeout_s=settings.CPCC_MAVLINK_LINK_TIMEOUT_S,
                on_link_lost=self._link_lost_later,
                name=vehicle.name,
                gcs_failsafe_s=settings.CPCC_GCS_FAILSAFE_S,
                kind=vehicle.kind,
            )
            driver.connect(timeout_s=settings.CPCC_MAVLINK_CONNECT_S)
        self.rig = build_rig(
            vehicle,
            vvm=vvm,
            scheduler=scheduler,
            planner=planner,
            scale=scale,
            driver=driver,
            plan_time_limit_s=settings.CPCC_PLAN_TIME_LIMIT_S,
            live=vvm.listened,
            ticks=True,
            wake_defers_to_arrival=True,
            plan_elsewhere=host.planning.plan,
        )
        self.driver = self.rig.driver
        self.loop = self.rig.loop
        self._sources = vehicle.sensor_sources  # as the rig's sensing reads them
        self._scale = scale
        self._battery_s = vehicle.battery_s  # as the loop and the driver plan with it
        self._health: dict[str, Any] | None = None  # as last recorded
        # What the map was told last (without its time) and when: an RV whose state does not
        # change (landed, idle) is told again only every BEACON_KEYFRAME_S.
        self._told: tuple[dict[str, Any], float] | None = None

    def _log(self) -> dict[str, Any]:
        return {"vehicle": self.name}

    def changed(self) -> None:
        """The vehicle's work, status or configuration changed: re-plan, read its sensors
        from the sources configured now, fly around the no-fly zones as they are now, and give
        a MAVLink vehicle its new geofence if its area, altitudes, the no-fly zones or the
        rally points changed."""
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        if vehicle.sensor_sources != self._sources:  # not at every wake-up: only a change
            try:
                self.rig.sensing.configure(vehicle.parsed_sources())
                self._sources = vehicle.sensor_sources
            except ValueError:  # a plug-in gone since it was configured: the old ones stay
                logger.exception("sensor sources not changed", extra=self._log())
        if isinstance(self.driver, MavlinkDriver) and self.driver.link_ok:
            fence = vehicle_fence(vehicle=vehicle)
            if self.driver.fence is None or _fence_differs(self.driver.fence, fence, vehicle):
                try:
                    self.driver.upload_fence(
                        fence.area,
                        fence.min_altitude_m,
                        fence.max_altitude_m,
                        exclusions=fence.exclusions,
                        rally=fence.rally,
                    )
                except MavlinkError:
                    logger.exception("geofence not uploaded", extra=self._log())
        if vehicle.battery_s != self._battery_s:  # a new battery, configured: no restart
            spec = kinematics(vehicle, scale=self._scale)
            self.driver.spec = spec
            self.loop.set_battery(spec.battery_s)
            self._battery_s = vehicle.battery_s
        self.rig.fly_in(fleet_airspace())
        self.rig.store.changed()
        self.loop.wake()

    def _link_lost_later(self) -> None:  # on the driver's thread
        self.host.scheduler.submit(self._link_lost)

    def _link_lost(self) -> None:
        """The vehicle stopped answering: it goes offline and its VVs move on (a reading it
        may still report is refused); it comes back into service when the link does. An RV
        not in service (maintenance, charging) keeps its status: the link is its health."""
        logger.warning("vehicle %s: link lost", self.name, extra=self._log())
        self._link_down = True
        vehicle_set_status(
            vehicle=Vehicle(pk=self.vehicle_id),
            status=VehicleStatus.OFFLINE,
            vvm=self.host.vvm,
            reason=LINK_LOST,
            expected=VehicleStatus.ACTIVE,
        )

    def link_check(self) -> None:
        """The MAVLink link lost before is back: an RV offline for it is in service again;
        one a person put into maintenance meanwhile stays there."""
        if not self._link_down or not getattr(self.driver, "link_ok", True):
            return
        self._link_down = False
        logger.warning("vehicle %s: link back", self.name, extra=self._log())
        vehicle_set_status(
            vehicle=Vehicle(pk=self.vehicle_id),
            status=VehicleStatus.ACTIVE,
            vvm=self.host.vvm,
            reason="link back",
            expected=VehicleStatus.OFFLINE,
        )

    def recover(self) -> None:
        """Take up whatever this RV was doing: VVs aboard, its open tasks, and any VV waiting
        for an RV that this one can serve (its lease is renewed already)."""
        vvm = self.host.vvm
        aboard = VirtualVehicle.objects.filter(
            host_rv_id=self.vehicle_id, status__in=ACTIVE_STATUSES
        )
        advance_each(aboard, vvm=vvm, vehicle=self.name)
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        vehicle_register(vehicle=vehicle, vvm=vvm)
        self.rig.store.changed()
        self.loop.wake()

    def look_again(self, status: str | None, busy: bool) -> None:
        """The sweep's look at the vehicle (``status``: the vehicle's in the database;
        ``busy``: it has open tasks there): what a lost message would have said. A vehicle
        with work reads it again and re-plans; an idle one only if its loop still holds tasks
        or another status (nothing else a message says changes an idle vehicle's plan)."""
        store = self.rig.store
        if busy or store.open_tasks() or store.status() != status:
            store.changed()
            self.loop.wake()

    def beacon(self, now: float) -> None:
        """Tell the live maps where the vehicle is, what it carries and where it goes next:
        when that changed, else now and then (a map forgets a state VEHICLE_STALE_S old)."""
        health = self._note_health(now)
        state = self.loop.live_state(now) | self._for_operators(now, health)
        if self._told is not None and self._told[0] == state and now < self._told[1]:
            return
        self._told = (state, now + BEACON_KEYFRAME_S)
        clock = self.host.clock
        publish_vehicle(
            state
            | {
                "id": self.vehicle_id,
                "name": self.name,
                "kind": self.kind,
                "t": clock.epoch_ms(now) / 1000,
            }
        )

    def _for_operators(self, now: float, health: dict[str, Any]) -> dict[str, Any]:
        """What only staff see of the vehicle live (missions.events.vehicle_for keeps it
        from customers): why its status is what it is, its ground speed (a simulated
        vehicle's at its own speed, not the worker's time acceleration), its link and health,
        and its battery's charge, or why there is none."""
        battery = self.loop.battery_fraction(now)
        why = ""
        if isinstance(self.driver, MavlinkDriver):
            if battery is None:  # no endurance configured: the autopilot's charge still counts
                battery = self.driver.battery_fraction()
            if battery is None:
                why = "the autopilot has not reported its battery"
        elif battery is None:
            why = "simulated without a battery (no battery_s set)"
        return {
            "driver": "mavlink" if isinstance(self.driver, MavlinkDriver) else "sim",
            "status_reason": self.rig.store.status_reason,
            "speed_mps": round(self.driver.speed_at(now) / self._scale, 1),
            "link": health.get("link"),
            "health": health,
            "battery": battery,
            "battery_why": why,
        }

    def _note_health(self, now: float) -> dict[str, Any]:
        """Record the vehicle's health when it changed (the battery in steps of 5 %);
        returns it."""
        if isinstance(self.driver, MavlinkDriver):
            health = self.driver.health()
        else:
            battery = self.loop.battery_fraction(now)
            health = {
                "link": "simulated",
                "battery_pct": None if battery is None else round(battery * 100),
            }
        step = health.get("battery_pct")
        seen = health | {"battery_pct": None if step is None else 5 * round(step / 5)}
        if seen != self._health:
            if vehicle_record_health(vehicle_id=self.vehicle_id, health=health):
                # Another battery, or one retired: grounded, or no longer (at once, before
                # the RV takes off with it).
                vehicle_check_maintenance(vehicle_id=self.vehicle_id, vvm=self.host.vvm)
            self._health = seen
        return health

    def close(self) -> None:
        self.rig.sensing.close()
        if isinstance(self.driver, MavlinkDriver):
            self.driver.close()


class GSHost:
    """The worker of one ground station: loads new VVs, takes back the ones that end or wait,
    and watches the RVs' leases.

    The VVs that its own work leaves on the station (those it admits, one that steps again
    here) it advances itself, right after that work, in the same thread and without a message
    (``advance_later``): a message is a hint the station would only send to itself. Should
    the worker die first, they are on the station in the database, where its sweep and its
    next start find them."""

    def __init__(self, station: GroundStation) -> None:
        self.station_id = station.pk
        self.name = station.name
        self.vvm = platform_vvm(local=self)
        self._later: collections.deque[uuid.UUID] = collections.deque()
        # The station's work runs on a host thread of its own, as an RV worker's does: Celery's
        # thread hands it over and waits. The host thread keeps its database connection (and
        # the statements prepared on it) from one message to the next, where Celery closes
        # its own thread's connection after every task.
        self.scheduler = RealTimeScheduler(self.vvm.clock)
        self._thread = threading.Thread(target=self._run, name="gs-host", daemon=True)
        self.watch = StationWatch(station)

    # --- LocalHost (vvm_worker.dispatch): the VVs this station takes -------------------------

    def is_vehicle(self, vehicle_id: int) -> bool:
        return False

    def is_station(self, station_id: int) -> bool:
        return bool(station_id == self.station_id)

    def advance_later(self, vv_id: uuid.UUID) -> None:
        self._later.append(vv_id)

    def wake_later(self, vehicle_id: int) -> None:  # no vehicle is hosted here
        raise AssertionError(f"a ground station's worker hosts no vehicle ({vehicle_id})")

    # --- what Celery tasks ask (one at a time, in Celery's thread, done on the host thread) ---

    def advance(self, vv_id: uuid.UUID) -> None:
        self._on_host(lambda: vv_advance(vv_id=vv_id, vvm=self.vvm))

    def admit(self, customer_id: int) -> None:
        self._on_host(lambda: vv_admit_queued(customer_id=customer_id, vvm=self.vvm))

    def _on_host(self, work: Callable[[], Any], timeout_s: float | None = WAIT_S) -> None:
        self.scheduler.submit(lambda: self._work(work)).result(timeout_s)

    def wake(self, vehicle_id: int) -> None:  # an RV's message that reached a GS: nothing to do
        pass

    def _work(self, work: Callable[[], Any]) -> None:
        """Do a piece of work, then advance the VVs it left here; the maps are told what each
        of them changed as soon as it is committed."""
        try:
            work()
        finally:
            self.vvm.announcer.flush()
        self._advance_waiting()

    def _advance_waiting(self) -> None:
        """Advance the VVs that work of this worker left on the station, oldest first (those
        they leave here in turn too). One whose advance fails for another reason than a
        database outage is logged and the others go on; an outage is raised with the VV still
        waiting (the caller waits it out and does all again)."""
        while self._later:
            vv_id = self._later[0]
            try:
                vv_advance(vv_id=vv_id, vvm=self.vvm)
            except Exception as exc:
                if database.is_outage(exc):
                    raise
                logger.exception(
                    "vv advance failed", extra={"vv": str(vv_id), "ground_station": self.name}
                )
            finally:
                self.vvm.announcer.flush()
            self._later.popleft()

    def start(self) -> None:
        self._thread.start()
        # However many VVs wait on the station.
        self._on_host(lambda: self.watch.take_up(self.vvm), timeout_s=None)
        self.watch.start()
        logger.info("gs worker started", extra={"ground_station": self.name})

    def stop(self) -> None:
        self.watch.stop()
        self.scheduler.stop()
        if self._thread.is_alive():
            self._thread.join(timeout=10)
        self.watch.join()
        self.vvm.announcer.close()

    def _run(self) -> None:
        try:
            self.scheduler.run()
        finally:
            connection.close()

    def sweep_once(self, vvm: VVM) -> None:
        """``StationWatch.sweep_once`` (what a sweep of this station's worker does)."""
        self.watch.sweep_once(vvm)


class StationWatch:
    """A ground station's watch over the fleet, on a thread of its own with a VVM (and V8
    runtime) of its own, whichever process hosts the station: the RVs' leases, VVs that a lost
    message left waiting on the station, queued VVs (``sweep_once``, every ``SWEEP_S``)."""

    def __init__(self, station: GroundStation) -> None:
        self.station_id = station.pk
        self.name = station.name
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lease-watch", daemon=True)
        # The sweep's memory (its thread's own). No RV's worker can renew its lease while the
        # database is down: after an outage, each gets a full lease's time to do so before
        # its VVs are moved off it.
        self._leases_from = 0.0  # time.monotonic() from which leases are checked
        self._online: set[int] = set()  # the RVs whose lease was valid at the last sweep

    def take_up(self, vvm: VVM) -> None:
        """What a worker that starts (or starts again) hosting the station takes up, with its
        host's ``vvm`` and on its host thread: the VVs on the station, then the queued VVs of
        every customer."""
        here = VirtualVehicle.objects.filter(host_gs_id=self.station_id, status__in=ACTIVE_STATUSES)
        advance_each(here, vvm=vvm, ground_station=self.name)
        _admit_all(vvm)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stopping.set()

    def join(self) -> None:
        if self._thread.is_alive():
            self._thread.join(timeout=10)

    def _run(self) -> None:
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
        waiting = stalled(
            host_gs_id=self.station_id, waiting_s=WAITING_LOOK_S, now_s=vvm.clock.now_s()
        )
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


def stalled(
    *, waiting_s: float | None = None, now_s: float | None = None, **host: Any
) -> QuerySet[VirtualVehicle]:
    """VVs on a host that have not moved for a while although they could: answered but not
    resumed, or arrived but not taken up (their message was lost); with ``waiting_s``, also
    those that have waited that long for an RV (routed again, they wait ``waiting_s`` more)
    and, with ``now_s`` (platform clock), those whose wait for a message timed out by then
    (their timer was lost). A VV that waits for a message costs nothing before."""
    moving = Q(status=VVStatus.MIGRATING) | Q(status=VVStatus.RUNNING, pending__isnull=True)
    look = Q(updated__lt=db_time_ago(SWEEP_S)) & moving
    receiving = Q(pending__kind="message")
    if waiting_s is not None:
        look |= (
            Q(status=VVStatus.RUNNING, pending__isnull=False, updated__lt=db_time_ago(waiting_s))
            & ~receiving
        )
    if now_s is not None:
        look |= Q(status=VVStatus.RUNNING, pending__until_s__lt=now_s) & receiving
    return VirtualVehicle.objects.filter(look, **host)


_host: RVHost | GSHost | None = None


def _fence_differs(have: Fence, wanted: VehicleFence, vehicle: Vehicle) -> bool:
    """Whether the autopilot's fence is not (within the protocol's 1e-7 degrees) the one
    wanted now."""

    def vertices(ring: list[list[float]]) -> list[tuple[float, float]]:
        points = [(float(lat), float(lng)) for lat, lng in ring]
        return points[:-1] if len(points) > 1 and points[0] == points[-1] else points

    want = [
        vertices(wanted.area),
        [wanted.min_altitude_m, wanted.max_altitude_m],
        *(vertices(ring) for ring in wanted.exclusions),
        [(p.lat, p.lng, p.alt - vehicle.depot_alt) for p in wanted.rally],
    ]
    got = [
        have.area,
        [have.min_altitude_m, have.max_altitude_m],
        *have.exclusions,
        list(have.rally),
    ]
    flat_want, flat_got = _flat(want), _flat(got)
    return len(flat_want) != len(flat_got) or any(
        abs(a - b) > 1e-7 for a, b in zip(flat_want, flat_got, strict=True)
    )


def _flat(value: Any) -> list[float]:
    if isinstance(value, int | float):
        return [float(value)]
    return [x for item in value for x in _flat(item)]


def set_host(host: RVHost | GSHost | None) -> None:
    global _host
    _host = host


def current_host() -> RVHost | GSHost | None:
    return _host
