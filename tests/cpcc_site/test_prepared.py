"""A read compiled once gives what its queryset gives, for any key, with its related rows."""

from __future__ import annotations

import uuid

import pytest
from django.db import DatabaseError, IntegrityError, connection, transaction

from cpcc_site import prepared
from cpcc_site.prepared import (
    Many,
    PreparedRead,
    deferred,
    insert_rows,
    pipelined,
    pipelined_transaction,
    save_fields,
    update_row,
    update_row_with,
)
from fleet.models import Vehicle
from missions.models import LogEntry, StorageDocument, Task, VirtualVehicle
from tests.factories import CustomerFactory, GroundStationFactory, VehicleFactory

pytestmark = pytest.mark.django_db


def _vv(**hosts) -> VirtualVehicle:
    return VirtualVehicle.objects.create(
        customer=CustomerFactory(),
        name="VV",
        program="VV.log('x')",
        seed=7,
        start_ms=0,
        catalog=[{"name": "CO2", "kind": "scalar", "unit": "ppm", "params": {"a": [1, 2]}}],
        pending={"q": 3, "kind": "single", "tasks": []},
        submitted_s=1.5,
        **hosts,
    )


def test_it_reads_each_key_as_the_queryset_does_with_its_related_rows() -> None:
    def build(key):
        return (
            VirtualVehicle.objects.select_for_update(of=("self",))
            .select_related("customer", "host_gs", "host_rv")
            .filter(pk=key)
        )

    read = PreparedRead(build, samples=[("pk", uuid.UUID(int=0))])
    on_rv = _vv(host_rv=VehicleFactory(name="Heli One"))
    on_gs = _vv(host_gs=GroundStationFactory(name="GS One"))
    with transaction.atomic():
        for vv in (on_rv, on_gs, on_rv):
            got = read.first(vv.pk)
            want = build(vv.pk).get()
            assert got is not None and got.pk == vv.pk
            for field in VirtualVehicle._meta.concrete_fields:
                assert getattr(got, field.attname) == getattr(want, field.attname), field.name
            assert got.customer.name == want.customer.name
            assert (got.host_rv and got.host_rv.name) == (want.host_rv and want.host_rv.name)
            assert (got.host_gs and got.host_gs.name) == (want.host_gs and want.host_gs.name)
        assert read.first(uuid.uuid4()) is None


def test_several_keys_each_in_its_place_another_customers_row_is_not_read() -> None:
    def build(key, customer):
        return (
            VirtualVehicle.objects.select_related("customer", "host_gs", "host_rv")
            .filter(pk=key, customer_id=customer)
            .order_by()
        )

    read = PreparedRead(build, samples=[("pk", uuid.UUID(int=0)), ("customer_id", -1)])
    mine, theirs = _vv(), _vv()
    got = read.first(mine.pk, mine.customer_id)
    assert got == build(mine.pk, mine.customer_id).get()
    assert got is not None and got.customer.name == mine.customer.name
    assert read.first(theirs.pk, mine.customer_id) is None
    assert read.first(mine.pk, theirs.customer_id) is None
    assert read.first(theirs.pk, theirs.customer_id) == theirs


def test_a_sample_the_query_holds_twice_is_refused() -> None:
    read = PreparedRead(
        lambda key: VirtualVehicle.objects.filter(pk=key) | VirtualVehicle.objects.filter(pk=key),
        samples=[("pk", uuid.UUID(int=0))],
    )
    with pytest.raises(ValueError, match="must appear once"):
        read.first(uuid.uuid4())


def test_save_fields_writes_those_fields_as_save_does_and_leaves_the_others() -> None:
    vv = _vv(host_rv=VehicleFactory(name="Heli One"))
    other = _vv()
    stale = VirtualVehicle.objects.get(pk=vv.pk)
    stale.name = "changed elsewhere"  # not among the fields: not written
    stale.host_rv = None
    stale.host_gs = GroundStationFactory(name="GS One")
    stale.pending = {"q": 4, "kind": "single", "tasks": [{"lat": 1.5}]}
    stale.steps = 9
    before = vv.updated
    save_fields(stale, ["host_rv", "host_gs", "pending", "steps", "updated"])
    got = VirtualVehicle.objects.get(pk=vv.pk)
    assert (got.host_rv_id, got.host_gs_id) == (None, stale.host_gs.pk)
    assert got.pending == {"q": 4, "kind": "single", "tasks": [{"lat": 1.5}]}
    assert got.steps == 9 and got.name == "VV"
    assert got.updated > before  # auto_now sets itself, as in save
    assert VirtualVehicle.objects.get(pk=other.pk).steps == other.steps
    stale.delete()
    with pytest.raises(DatabaseError, match="no row to update"):
        save_fields(stale, ["steps"])


def _task(vv: VirtualVehicle, q: int) -> Task:
    return Task(vv=vv, q=q, lat=1.0, lng=2.0, alt=3.0, tolerance_m=1.0, sensors=["CO2"],
                requested_s=4.0)  # fmt: skip


def test_insert_rows_inserts_as_bulk_create_does_and_gives_each_object_its_key() -> None:
    vv = _vv()
    tasks = [_task(vv, q) for q in (5, 3, 9)]
    insert_rows(tasks)
    assert all(not task._state.adding for task in tasks)
    stored = {task.pk: task for task in Task.objects.filter(vv=vv)}
    assert {pk: task.q for pk, task in stored.items()} == {task.pk: task.q for task in tasks}
    assert stored[tasks[0].pk].sensors == ["CO2"] and stored[tasks[0].pk].status == "open"
    with pytest.raises(IntegrityError), transaction.atomic():
        insert_rows([_task(vv, 3)])  # a second task of request 3, index 0


def test_insert_rows_ignores_or_updates_the_rows_that_conflict() -> None:
    vv = _vv()
    insert_rows([LogEntry(vv=vv, seq=1, at_s=1.0, message="first")])
    insert_rows(
        [LogEntry(vv=vv, seq=1, at_s=2.0, message="again"), LogEntry(vv=vv, seq=2, at_s=2.0,
         message="second")],
        on_conflict="ignore",
    )  # fmt: skip
    assert list(vv.log.order_by("seq").values_list("message", flat=True)) == ["first", "second"]
    doc = {"vv": vv, "key": "k", "size_bytes": 3, "updated_s": 1.0}
    insert_rows([StorageDocument(**doc, value=[1])])
    update = {"unique_fields": ["vv", "key"], "update_fields": ["value", "updated_s"]}
    insert_rows([StorageDocument(**doc | {"updated_s": 2.0}, value={"a": 2})],
                on_conflict="update", **update)  # fmt: skip
    (stored,) = vv.storage.all()
    assert (stored.value, stored.updated_s) == ({"a": 2}, 2.0)


def test_insert_rows_splits_what_one_statement_cannot_hold(monkeypatch) -> None:
    monkeypatch.setattr(prepared, "_MAX_PARAMS", 30)  # two tasks a statement
    vv = _vv()
    tasks = [_task(vv, q) for q in range(5)]
    insert_rows(tasks)
    assert sorted(Task.objects.filter(vv=vv).values_list("pk", "q")) == sorted(
        (task.pk, task.q) for task in tasks
    )


def test_update_row_sets_and_adds_as_an_orm_update_does() -> None:
    vehicle = VehicleFactory(name="Heli One")
    Vehicle.objects.filter(pk=vehicle.pk).update(tasks_done=3)
    changed = update_row(
        Vehicle, vehicle.pk, values={"lat": 1.5, "planner_state": {"a": [1]}}, add={"tasks_done": 2}
    )
    vehicle.refresh_from_db()
    assert (changed, vehicle.lat, vehicle.planner_state, vehicle.tasks_done) == (
        1,
        1.5,
        {"a": [1]},
        5,
    )
    assert update_row(Vehicle, vehicle.pk + 1000, values={"lat": 2.0}) == 0


def test_update_row_with_another_write_does_both_in_one_statement_on_postgresql() -> None:
    # (An RV's row and the track points of the VVs aboard, where it stopped to serve a task.)
    from django.test.utils import CaptureQueriesContext

    vehicle = VehicleFactory(name="Heli One")
    vv = _vv()
    log = LogEntry._meta.db_table
    write = (
        f'INSERT INTO "{log}" ("vv_id", "seq", "at_s", "level", "message") '
        "VALUES (%s, %s, %s, %s, %s)",
        [VirtualVehicle._meta.pk.get_db_prep_value(vv.pk, connection), 1, 2.5, "info", "x"],
    )
    with CaptureQueriesContext(connection) as statements, transaction.atomic():
        update_row_with(
            Vehicle,
            vehicle.pk,
            values={"lat": 1.5, "planner_state": {"a": [1]}},
            add={"tasks_done": 2},
            write=write,
        )
    vehicle.refresh_from_db()
    assert (vehicle.lat, vehicle.planner_state, vehicle.tasks_done) == (1.5, {"a": [1]}, 2)
    assert list(LogEntry.objects.filter(vv=vv).values_list("seq", "message")) == [(1, "x")]
    writes = [
        q for q in statements.captured_queries if q["sql"].startswith(("WITH", "INSERT", "UPDATE"))
    ]
    assert len(writes) == (1 if connection.vendor == "postgresql" else 2)


def test_rows_read_what_the_queryset_reads() -> None:
    one, two = VehicleFactory(name="One"), VehicleFactory(name="Two", status="maintenance")
    statuses = PreparedRead(
        lambda ids: Vehicle.objects.filter(pk__in=ids).values_list("pk", "status"),
        samples=[("pk", Many(lambda i: -7_000_000 - i))],
    )
    assert dict(statuses.rows([two.pk, one.pk, two.pk + 1000])) == {
        one.pk: "active",
        two.pk: "maintenance",
    }
    vv = _vv()
    insert_rows([_task(vv, q) for q in (2, 1)])
    read = PreparedRead(
        lambda key: Task.objects.filter(vv=key).order_by("q").values_list("vv_id", "q", "sensors"),
        samples=[("vv", uuid.UUID(int=0))],
    )
    assert read.rows(vv.pk) == [(vv.pk, 1, ["CO2"]), (vv.pk, 2, ["CO2"])]
    assert read.rows(uuid.uuid4()) == []


def test_a_read_by_a_list_of_keys_is_compiled_for_each_length_and_keeps_annotations() -> None:
    from django.db.models import BooleanField, ExpressionWrapper, Q

    from cpcc_site.prepared import Many

    one, two, three = (VehicleFactory(name=n, tasks_done=k) for k, n in enumerate("ABC"))
    read = PreparedRead(
        lambda ids: (
            Vehicle.objects.filter(pk__in=ids)
            .order_by("name")
            .annotate(busy=ExpressionWrapper(Q(tasks_done__gte=1), output_field=BooleanField()))
        ),
        samples=[("pk", Many(lambda i: -1000 - i))],
    )
    assert [(v.name, v.busy) for v in read.all([three.pk, one.pk])] == [("A", False), ("C", True)]
    assert [(v.name, v.busy) for v in read.all([two.pk])] == [("B", True)]
    assert [v.name for v in read.all([two.pk, three.pk, one.pk])] == ["A", "B", "C"]


def test_a_long_list_of_keys_is_read_without_keeping_its_statement(monkeypatch) -> None:
    from cpcc_site.prepared import Many

    monkeypatch.setattr(prepared, "_CACHED_ROWS", 2)
    vehicles = [VehicleFactory(name=f"V{n}") for n in range(3)]
    read = PreparedRead(
        lambda ids: Vehicle.objects.filter(pk__in=ids).order_by("name"),
        samples=[("pk", Many(lambda i: -1000 - i))],
    )
    assert [v.name for v in read.all([v.pk for v in vehicles])] == ["V0", "V1", "V2"]
    assert [v.name for v in read.all([vehicles[1].pk])] == ["V1"]
    assert len(read._compiled) == 1  # the one of one key, not the one of three


def _syncs(monkeypatch) -> list[int]:
    import psycopg

    syncs: list[int] = []
    real = psycopg.Pipeline.sync

    def counted(self):  # type: ignore[no-untyped-def]
        syncs.append(1)
        return real(self)

    monkeypatch.setattr(psycopg.Pipeline, "sync", counted)
    return syncs


def test_a_pipelined_unit_of_work_writes_as_before_and_sets_keys_by_its_end(monkeypatch) -> None:
    """Deferred writes land as the same writes outside a pipeline do; the new rows' keys are
    there when the block ends; a statement that is not deferred still waits for its answer."""
    postgres = connection.vendor == "postgresql"
    syncs = _syncs(monkeypatch) if postgres else []
    vv = _vv(host_rv=VehicleFactory(name="Heli One"))
    tasks = [_task(vv, q) for q in (5, 3)]
    with transaction.atomic(), pipelined():
        with deferred():
            insert_rows(tasks)
            vv.steps = 11
            save_fields(vv, ["steps"])
            changed = update_row(Vehicle, vv.host_rv_id, values={"lat": 7.5})
            if postgres:  # sent, not waited for
                assert [t.pk for t in tasks] == [None, None] and changed is None and not syncs
        # A read waits, and sees what was written before it in the transaction.
        assert Task.objects.filter(vv=vv).count() == 2
        if postgres:
            assert len(syncs) == 1
    assert all(t.pk is not None for t in tasks)
    assert sorted(Task.objects.filter(vv=vv).values_list("pk", "q")) == sorted(
        (t.pk, t.q) for t in tasks
    )
    assert VirtualVehicle.objects.get(pk=vv.pk).steps == 11
    assert Vehicle.objects.get(pk=vv.host_rv_id).lat == 7.5


def test_a_deferred_write_that_fails_rolls_the_unit_of_work_back_with_its_error() -> None:
    vv = _vv()
    insert_rows([_task(vv, 3)])
    gone = VirtualVehicle.objects.get(pk=vv.pk)

    def duplicate() -> None:
        with transaction.atomic(), pipelined(), deferred():
            insert_rows([_task(vv, 4)])
            insert_rows([_task(vv, 3)])  # a second task of request 3, index 0

    with pytest.raises(IntegrityError):
        duplicate()
    assert list(Task.objects.filter(vv=vv).values_list("q", flat=True)) == [3]
    VirtualVehicle.objects.filter(pk=vv.pk).delete()

    def missing_row() -> None:
        with transaction.atomic(), pipelined(), deferred():
            LogEntry.objects.create(vv=_vv(), seq=1, at_s=1.0, message="rolled back")
            save_fields(gone, ["steps"])

    with pytest.raises(DatabaseError, match="no row to update"):
        missing_row()
    assert not LogEntry.objects.filter(message="rolled back").exists()


def test_a_read_sent_ahead_comes_back_with_the_writes_sent_after_it(monkeypatch) -> None:
    """``first_later`` sends a locking read and lets the unit of work send more before it
    reads the row: on PostgreSQL no statement waits on its own (the read fetches every answer
    at once); the row is as it was when the read ran, the writes sent after it land."""
    postgres = connection.vendor == "postgresql"
    syncs = _syncs(monkeypatch) if postgres else []
    read = PreparedRead(
        lambda key: (
            VirtualVehicle.objects.select_for_update(no_key=True)
            .select_related("customer")
            .filter(pk=key)
        ),
        samples=[("pk", uuid.UUID(int=0))],
    )
    vv, other = _vv(), _vv()
    with transaction.atomic(), pipelined():
        later = read.first_later(vv.pk)
        missing = read.first_later(uuid.uuid4())
        with deferred():
            update_row(VirtualVehicle, vv.pk, values={"steps": 5})
            update_row(VirtualVehicle, other.pk, values={"steps": 6})
        got = later()
        assert missing() is None
        assert got is not None and (got.pk, got.steps, got.customer.pk) == (
            vv.pk,
            0,
            vv.customer_id,
        )
        assert not syncs
    assert dict(VirtualVehicle.objects.values_list("pk", "steps")) == {vv.pk: 5, other.pk: 6}


def _commits(monkeypatch) -> list[str]:
    """What the server's transaction was when Django asked psycopg to commit: ``idle`` means
    it was committed already (with the unit's last writes), so the commit sent nothing."""
    import psycopg
    from psycopg import pq

    seen: list[str] = []
    real = psycopg.Connection.commit

    def spied(self):  # type: ignore[no-untyped-def]
        status = self.pgconn.transaction_status
        seen.append("idle" if status == pq.TransactionStatus.IDLE else "open")
        return real(self)

    monkeypatch.setattr(psycopg.Connection, "commit", spied)
    return seen


def _locked(vv: VirtualVehicle) -> VirtualVehicle:
    return VirtualVehicle.objects.select_for_update(no_key=True).get(pk=vv.pk)


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
def test_a_unit_of_work_of_its_own_commits_with_its_last_writes(monkeypatch) -> None:
    """``pipelined_transaction`` whose deferred writes wait for no check (the row it updates
    is one it holds): the writes and the COMMIT go to PostgreSQL together; what waits for
    the commit (``on_commit``) runs once it is done, and a write that fails leaves nothing
    behind, as a transaction of its own does on any database."""
    postgres = connection.vendor == "postgresql"
    commits = _commits(monkeypatch) if postgres else []
    vv = _vv()
    commits.clear()  # (making the VV committed by itself)
    done: list[int] = []
    with pipelined_transaction():
        held = _locked(vv)
        transaction.on_commit(lambda: done.append(VirtualVehicle.objects.get(pk=vv.pk).steps))
        with deferred():
            held.steps = 4
            save_fields(held, ["steps"], held=True)
            tasks = [_task(vv, 3)]
            insert_rows(tasks)
        assert not done
    assert done == [4] and tasks[0].pk is not None
    assert Task.objects.get(pk=tasks[0].pk).vv_id == vv.pk
    if postgres:
        assert commits == ["idle"]  # nothing was left for a round trip of its own

    def duplicate() -> None:
        with pipelined_transaction():
            held = _locked(vv)
            with deferred():
                held.steps = 5
                save_fields(held, ["steps"], held=True)
                insert_rows([_task(vv, 3)])  # a second task of request 3, index 0

    with pytest.raises(IntegrityError):
        duplicate()
    assert VirtualVehicle.objects.get(pk=vv.pk).steps == 4
    assert Task.objects.filter(vv=vv).count() == 1


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
def test_a_unit_of_work_of_its_own_sends_its_begin_with_its_first_statements(monkeypatch) -> None:
    """On PostgreSQL a unit that is a transaction of its own waits for the server twice: for
    its locking read (which BEGIN goes with: it gets no round trip of its own), and for its
    last writes with the COMMIT. It is a transaction all the same (on any database): what it
    holds is held until it ends, and what it wrote before a failure is rolled back."""
    postgres = connection.vendor == "postgresql"
    waits = _pipeline_waits(monkeypatch) if postgres else []
    vv, other = _vv(), _vv()
    with pipelined_transaction():
        held = _locked(vv)
        if postgres:
            assert waits == ["sync"]  # the read (and the BEGIN sent with it)
            _assert_held_elsewhere(vv)
        with deferred():
            held.steps = 7
            save_fields(held, ["steps"], held=True)
    if postgres:
        assert waits == ["sync"]  # the writes and the COMMIT went when the pipeline closed
        assert connection.connection.autocommit  # as Django leaves it between transactions
    assert VirtualVehicle.objects.get(pk=vv.pk).steps == 7

    def failing() -> None:
        with pipelined_transaction():
            held = _locked(other)
            with deferred():
                held.steps = 8
                save_fields(held, ["steps"], held=True)
            raise RuntimeError("the unit fails")

    with pytest.raises(RuntimeError):
        failing()
    assert VirtualVehicle.objects.get(pk=other.pk).steps == 0


def _pipeline_waits(monkeypatch) -> list[str]:
    """Each time a psycopg pipeline syncs with the server and waits for its answers."""
    from psycopg._pipeline_base import BasePipeline

    waits: list[str] = []
    real = BasePipeline._sync_gen

    def counted(self):  # type: ignore[no-untyped-def]
        waits.append("sync")
        return real(self)

    monkeypatch.setattr(BasePipeline, "_sync_gen", counted)
    return waits


def _assert_held_elsewhere(vv: VirtualVehicle) -> None:
    """Another connection cannot lock the VV's row: a transaction holds it."""
    import psycopg

    settings = connection.settings_dict
    with (
        psycopg.connect(
            host=settings["HOST"],
            port=settings["PORT"],
            dbname=settings["NAME"],
            user=settings["USER"],
            password=settings["PASSWORD"],
            autocommit=True,
        ) as onlooker,
        pytest.raises(psycopg.errors.LockNotAvailable),
    ):
        onlooker.execute(
            "SELECT 1 FROM missions_virtualvehicle WHERE id = %s FOR UPDATE NOWAIT", [vv.pk]
        )


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
def test_a_unit_whose_write_waits_for_its_check_commits_only_once_the_check_passed(
    monkeypatch,
) -> None:
    """A deferred write of a row the unit does not hold is checked when its answer is in:
    the COMMIT waits for that check, and a row that was gone rolls back every write of the
    unit, those sent before it included."""
    postgres = connection.vendor == "postgresql"
    commits = _commits(monkeypatch) if postgres else []
    vv, gone = _vv(), _vv()
    stale = VirtualVehicle.objects.get(pk=gone.pk)
    commits.clear()
    with pipelined_transaction(), deferred():
        vv.steps = 2
        save_fields(vv, ["steps"])
    assert VirtualVehicle.objects.get(pk=vv.pk).steps == 2
    if postgres:
        assert commits == ["open"]  # committed after the check, in a round trip of its own
    VirtualVehicle.objects.filter(pk=gone.pk).delete()

    def missing_row() -> None:
        with pipelined_transaction(), deferred():
            insert_rows([LogEntry(vv=vv, seq=1, at_s=1.0, message="rolled back")])
            vv.steps = 3
            save_fields(vv, ["steps"], held=True)
            save_fields(stale, ["steps"])

    with pytest.raises(DatabaseError, match="no row to update"):
        missing_row()
    assert not LogEntry.objects.filter(message="rolled back").exists()
    assert VirtualVehicle.objects.get(pk=vv.pk).steps == 2


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
def test_a_unit_of_work_inside_another_transaction_commits_nothing_of_its_own() -> None:
    """Inside an outer transaction the unit is a savepoint: its writes stand or fall with the
    outer transaction, which alone commits."""
    vv = _vv()

    def outer() -> None:
        with transaction.atomic():
            with pipelined_transaction():
                held = _locked(vv)
                with deferred():
                    held.steps = 9
                    save_fields(held, ["steps"], held=True)
            assert VirtualVehicle.objects.get(pk=vv.pk).steps == 9  # in the outer transaction
            raise RuntimeError("the outer transaction fails")

    with pytest.raises(RuntimeError):
        outer()
    assert VirtualVehicle.objects.get(pk=vv.pk).steps == 0
