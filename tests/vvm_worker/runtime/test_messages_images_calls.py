"""VV.message and VV.image in the runtime (issue 27): waiting calls the host answers.

Each call ends the step with a pending request ("call" with its op and arguments, or
"message" with its timeout); the host answers it with a journal entry ("ret", "err" or
"msg") and the next step continues, resumed where the program waits or replayed from the
journal. These tests play the host with made-up answers: no image is read here.
"""

from __future__ import annotations

import json
from typing import Any

import pytest

from tests.vvm_worker.runtime.harness import (
    CATALOG,
    START_MS,
    Run,
    answer_with_readings,
    reading,
)
from vvm_worker.runtime import (
    VVM_API_CALLS,
    ErrorKind,
    Limits,
    Outcome,
    PendingRequest,
    Runtime,
    StepInput,
    StepResult,
    answer_call,
    answer_call_error,
    answer_message,
    run_step,
)
from vvm_worker.runtime.instrument import ReservedNameError, instrument_program

IMAGE = "readings/ab/" + "0" * 32 + ".png"
PICTURE = {
    "sensor": "Camera 640x480",
    "kind": "camera",
    "time": "2025-01-01T00:00:01Z",
    "position": {"lat": 48.1, "lng": 11.5, "alt": 30},
    "image": IMAGE,
    "width": 640,
    "height": 480,
    "format": "png",
}
# The program's picture, as a camera reading gives it.
P = f"var p = {json.dumps(PICTURE)};\n"
MESSAGE = {"from": "base", "id": "b0d5e3f4-0000-4000-8000-000000000001", "value": {"n": 1}}
SENT_AT = "2025-01-01T00:00:05+00:00"


def fake_result(pending: PendingRequest) -> Any:
    """What the host would answer a call with, made up from its arguments."""
    args = pending.args or {}
    if pending.op == "message.send":
        return {"id": 100 + pending.q}
    if pending.op == "image.stats":
        return {"width": 640, "height": 480, "mean": {"r": 1.5, "g": 2, "b": 3}, "std": {}}
    if pending.op == "image.fraction":
        return 0.25
    size = args["region"] if pending.op == "image.crop" else args
    return {
        "kind": "camera",
        "image": "readings/cd/" + str(pending.q) * 32 + ".png",
        "width": size["width"],
        "height": size["height"],
        "format": "png",
        **args["source"],
    }


def answer(pending: PendingRequest, time_ms: int) -> dict[str, Any]:
    """The host's answer: a message for a wait longer than 0 s (none for 0 s), a made-up
    result for a call, readings for a task."""
    if pending.kind == "message":
        assert pending.timeout_s is not None
        message = {**MESSAGE, "sentAt": SENT_AT} if pending.timeout_s > 0 else None
        return answer_message(pending, time_ms=time_ms, message=message)
    if pending.kind == "call":
        return answer_call(pending, time_ms=time_ms, data=fake_result(pending))
    return answer_with_readings(pending, time_ms)


def step_input(source: str, journal: list[dict[str, Any]], **kw: Any) -> StepInput:
    return StepInput(
        vv_id="vv-m",
        vv_name="vv-m",
        source=source,
        seed=3,
        start_ms=START_MS,
        catalog=CATALOG,
        journal=list(journal),
        **kw,
    )


class Host:
    """One warm runtime stepping one VV, answering and applying effects as the VVM does."""

    def __init__(self, source: str, *, limits: Limits | None = None) -> None:
        self.source = source
        self.limits = limits or Limits()
        self.runtime = Runtime()
        self.journal: list[dict[str, Any]] = []
        self.applied = 0
        self.storage: dict[str, Any] = {}
        self.results: list[StepResult] = []

    def step(self, *, answered: bool = True, **kw: Any) -> StepResult:
        inp = step_input(
            self.source, self.journal, effects_applied=self.applied, limits=self.limits, **kw
        )
        result = self.runtime.step(inp)
        for e in result.effects:
            if e.op == "store" and e.key is not None:
                self.storage[e.key] = json.loads(e.value_json or "null")
        self.applied = max(self.applied, result.effects_total)
        self.results.append(result)
        if answered and result.outcome is Outcome.SUSPENDED:
            assert result.pending is not None
            self.journal.append(answer(result.pending, START_MS + 1000 * (len(self.journal) + 1)))
        return result

    def run(self) -> StepResult:
        while True:
            result = self.step()
            if result.outcome is not Outcome.SUSPENDED:
                return result


def first_pending(source: str, **kw: Any) -> PendingRequest:
    result = run_step(step_input(source, [], **kw))
    assert result.outcome is Outcome.SUSPENDED, result.error
    assert result.pending is not None
    return result.pending


def failure(source: str, **kw: Any) -> StepResult:
    result = Run(source, **kw).run(answer=answer)
    assert result.outcome is Outcome.FAILED
    assert result.error is not None
    return result


EVERY_CALL = (
    P + "var sent = VV.message.send('base', {n: 1, list: [1, 2]});\n"
    "var s = VV.image.stats(p);\n"
    "var c = VV.image.crop(p, {x: 8, y: 4, width: 16, height: 12});\n"
    "var f = VV.image.fraction(c, {g: [0, 10], r: [200, 255]}, {x: 0, y: 0, width: 2, height: 2});\n"
    "var r = VV.image.resize(c, 4, 3);\n"
    "var m = VV.message.receive(30);\n"
    "var none = VV.message.receive(0);\n"
    "VV.storage.store('out', [sent, s, c, f, r, m, none, Date.now()]);\n"
)


def test_each_call_makes_its_pending_request_with_its_arguments() -> None:
    run = Run(EVERY_CALL)
    assert run.run(answer=answer).outcome is Outcome.FINISHED
    pendings = [r.pending for r in run.results[:-1]]
    assert all(p is not None and p.tasks == () and p.open == () for p in pendings)
    assert [(p.kind, p.q, p.op, p.timeout_s) for p in pendings if p is not None] == [
        ("call", 0, "message.send", None),
        ("call", 1, "image.stats", None),
        ("call", 2, "image.crop", None),
        ("call", 3, "image.fraction", None),
        ("call", 4, "image.resize", None),
        ("message", 5, None, 30.0),
        ("message", 6, None, 0.0),
    ]
    source = {k: PICTURE[k] for k in ("sensor", "time", "position")}
    cropped = "readings/cd/" + "2" * 32 + ".png"
    assert [p.args for p in pendings if p is not None][:5] == [
        {"to": "base", "value": '{"n":1,"list":[1,2]}'},  # the value as JSON text
        {"picture": IMAGE, "region": None},
        {"picture": IMAGE, "region": {"x": 8, "y": 4, "width": 16, "height": 12}, "source": source},
        {
            "picture": cropped,
            "ranges": {"r": [200, 255], "g": [0, 10]},
            "region": {"x": 0, "y": 0, "width": 2, "height": 2},
        },
        {"picture": cropped, "width": 4, "height": 3, "source": source},
    ]
    # Where the program asked, for reports: at the call's name, as for a task.
    lines = EVERY_CALL.splitlines()
    assert [(p.line, p.column) for p in pendings[:2] if p is not None] == [
        (2, lines[1].index("send(") + 1),
        (3, lines[2].index("stats(") + 1),
    ]
    assert run.results[-1].requests == 7


def test_the_program_gets_each_answer_and_the_clock_of_its_answer() -> None:
    run = Run(EVERY_CALL)
    run.run(answer=answer)
    sent, stats, crop, fraction, resize, message, none, now = run.storage["out"]
    assert sent == {"id": 100}
    assert stats["mean"] == {"r": 1.5, "g": 2, "b": 3}
    assert crop == {
        "kind": "camera",
        "image": "readings/cd/" + "2" * 32 + ".png",
        "width": 16,
        "height": 12,
        "format": "png",
        "sensor": "Camera 640x480",
        "time": "2025-01-01T00:00:01Z",
        "position": {"lat": 48.1, "lng": 11.5, "alt": 30},
    }
    assert fraction == 0.25
    assert (resize["width"], resize["height"]) == (4, 3)
    assert message == {**MESSAGE, "sentAt": SENT_AT}
    assert none is None  # the wait timed out
    assert now == START_MS + 7000  # the time of the last answer


def test_a_warm_context_resumes_through_every_call_and_a_new_one_replays_the_same() -> None:
    host = Host(EVERY_CALL)
    assert host.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in host.results] == [0, 1, 1, 1, 1, 1, 1, 1]
    assert [r.replayed for r in host.results] == [True] + [False] * 7
    cold = Run(EVERY_CALL, seed=3)
    cold.run(answer=answer)
    assert [r.answers_read for r in cold.results] == list(range(8))
    assert host.storage == cold.storage
    assert [r.pending for r in host.results] == [r.pending for r in cold.results]


def test_a_new_context_replays_a_journal_with_calls_to_the_same_pending_request() -> None:
    host = Host(EVERY_CALL)
    for _ in range(5):
        waiting = host.step()
    # The VV moves with its checkpoint (through the database, as JSON) to another host.
    journal = json.loads(json.dumps(host.journal[:-1]))
    moved = run_step(step_input(EVERY_CALL, journal, effects_applied=host.applied))
    assert moved.outcome is Outcome.SUSPENDED and moved.replayed
    assert moved.answers_read == 4
    assert moved.pending == waiting.pending
    assert moved.pending is not None and moved.pending.op == "image.resize"


def test_a_replay_that_asks_another_call_fails_as_non_deterministic() -> None:
    journal = [answer(first_pending(P + "VV.message.send('base', 1);"), START_MS + 1)]
    for other in ("VV.message.send('base', 2);", "VV.image.stats(p);", "VV.message.receive(1);"):
        result = run_step(step_input(P + other + "\nVV.storage.store('x', 1);", journal))
        assert result.outcome is Outcome.FAILED, other
        assert result.error is not None and result.error.kind is ErrorKind.NONDETERMINISM
        assert "non-determinism" in result.error.message


def test_a_call_answered_with_an_error_throws_message_error_or_image_error() -> None:
    source = P + (
        "var out = [];\n"
        "try { VV.message.send('nobody', 1); } catch (e) {\n"
        "  out.push([e.name, e.message, e instanceof MessageError, e instanceof VV.errors.MessageError, e instanceof Error]);\n"
        "}\n"
        "try { VV.image.crop(p, {x: 630, y: 0, width: 70, height: 1}); } catch (e) {\n"
        "  out.push([e.name, e.message, e instanceof ImageError, e instanceof VV.errors.ImageError, e instanceof Error]);\n"
        "}\n"
        "VV.storage.store('out', out);\n"
        "VV.image.stats(p);\n"
    )
    no_vv = 'VV.message.send(to, value): no VV "nobody" of yours to send to'
    beyond = (
        "VV.image.crop(picture, region): region.x + region.width = 700 is beyond the "
        "picture's width 640"
    )

    def refuse(pending: PendingRequest, time_ms: int) -> dict[str, Any]:
        name = "MessageError" if pending.op == "message.send" else "ImageError"
        message = {"message.send": no_vv, "image.crop": beyond}.get(
            pending.op or "", "VV.image.stats(picture): not a picture this VV has received"
        )
        return answer_call_error(pending, time_ms=time_ms, name=name, message=message)

    run = Run(source)
    result = run.run(answer=refuse)
    assert run.storage["out"] == [
        ["MessageError", no_vv, True, True, True],
        ["ImageError", beyond, True, True, True],
    ]
    # Not caught: the VV fails with the error and the line of the call.
    assert result.outcome is Outcome.FAILED and result.error is not None
    assert result.error.message == (
        "ImageError: VV.image.stats(picture): not a picture this VV has received"
    )
    assert result.error.line == 10


def test_only_the_two_call_errors_can_answer_a_call() -> None:
    pending = first_pending(P + "VV.image.stats(p);")
    with pytest.raises(ValueError, match="MessageError, ImageError"):
        answer_call_error(pending, time_ms=START_MS, name="TypeError", message="x")


def test_a_value_the_program_changes_does_not_change_what_a_replay_gets() -> None:
    source = (
        "var m = VV.message.receive(5);\n"
        "VV.storage.store('before', m.value.n);\n"
        "m.value.n = 99;\n"
        "VV.message.send('base', m.value);\n"
    )
    host = Host(source)
    host.step()
    second = host.step(answered=False)
    assert second.pending is not None and second.pending.args == {
        "to": "base",
        "value": '{"n":99}',
    }
    for _ in range(3):
        # The host lost the step's effects: the warm context replays, from the same journal.
        host.applied = 0
        host.storage.clear()
        again = host.step(answered=False)
        assert again.replayed and host.storage == {"before": 1}


ARGUMENT_ERRORS = [
    ("VV.message.send(42, 1)", "TypeError: VV.message.send(to, value): to must be the name or the id of a VV"),
    ("VV.message.send('', 1)", "TypeError: VV.message.send(to, value): to must be"),
    ("VV.message.send('base')", "TypeError: VV.message.send(to, value): the value must be JSON (not undefined or a function)"),
    ("VV.message.send('base', 10n)", "TypeError: VV.message.send(to, value): the value cannot be sent as JSON"),
    ("var o = {}; o.o = o; VV.message.send('base', o)", "TypeError: VV.message.send(to, value): the value cannot be sent as JSON"),
    ("VV.message.send('base', {s: 'a\\ud800'})", "RangeError: VV.message.send(to, value): the value holds a string with a lone surrogate"),
    ("var a = []; for (var i = 0; i < 200; i++) a = [a]; VV.message.send('base', a)", "RangeError: VV.message.send(to, value): the value nests arrays and objects more than 100 levels deep"),
    ("VV.message.receive()", "RangeError: VV.message.receive(timeoutS): timeoutS must be a finite number, got undefined"),
    ("VV.message.receive(Infinity)", "RangeError: VV.message.receive(timeoutS): timeoutS must be a finite number"),
    ("VV.message.receive(-1)", "RangeError: VV.message.receive(timeoutS): timeoutS -1 is outside 0..86400"),
    ("VV.message.receive(86401)", "RangeError: VV.message.receive(timeoutS): timeoutS 86401 is outside 0..86400"),
    (f"VV.image.stats('{IMAGE}')", 'TypeError: VV.image.stats(picture): picture must be a picture (a camera reading, or what VV.image.crop or VV.image.resize returned), got "readings/'),
    ("VV.image.stats({image: 5})", "TypeError: VV.image.stats(picture): picture must be a picture"),
    ("VV.image.stats(p, 5)", "TypeError: VV.image.stats(picture, region): region must be an object {x, y, width, height}, got 5"),
    ("VV.image.crop(p)", "TypeError: VV.image.crop(picture, region): region must be an object"),
    ("VV.image.crop(p, {x: 1.5, y: 0, width: 1, height: 1})", "TypeError: VV.image.crop(picture, region): region.x must be an integer, got 1.5"),
    ("VV.image.crop(p, {x: 0, y: '0', width: 1, height: 1})", 'TypeError: VV.image.crop(picture, region): region.y must be an integer, got "0"'),
    ("VV.image.crop(p, {x: -1, y: 0, width: 1, height: 1})", "RangeError: VV.image.crop(picture, region): region.x must be 0 or more, got -1"),
    ("VV.image.crop(p, {x: 0, y: 0, width: 0, height: 1})", "RangeError: VV.image.crop(picture, region): region.width must be 1 or more, got 0"),
    ("VV.image.crop({image: p.image, position: 10n}, {x: 0, y: 0, width: 1, height: 1})", "TypeError: VV.image.crop(picture, region): picture.position: the value cannot be copied as JSON"),
    ("VV.image.fraction(p)", "TypeError: VV.image.fraction(picture, ranges): ranges must be an object such as {r: [min, max], g: [min, max], b: [min, max]}, got undefined"),
    ("VV.image.fraction(p, {})", "TypeError: VV.image.fraction(picture, ranges): ranges must give at least one of r, g, b"),
    ("VV.image.fraction(p, {r: [0, 9], a: [0, 1]})", "TypeError: VV.image.fraction(picture, ranges): ranges.a is not a channel (ranges may give r, g and b)"),
    ("VV.image.fraction(p, {r: 5})", "TypeError: VV.image.fraction(picture, ranges): ranges.r must be [min, max], got 5"),
    ("VV.image.fraction(p, {g: [0, 256]})", "RangeError: VV.image.fraction(picture, ranges): ranges.g[1] 256 is outside 0..255"),
    ("VV.image.fraction(p, {b: [20, 10]})", "RangeError: VV.image.fraction(picture, ranges): ranges.b is [20, 10]: its min is above its max"),
    ("VV.image.fraction(p, {b: [0, 1]}, {x: 0})", "TypeError: VV.image.fraction(picture, ranges, region): region.y must be an integer, got undefined"),
    ("VV.image.resize(p, 0, 10)", "RangeError: VV.image.resize(picture, width, height): width 0 is outside 1..4096"),
    ("VV.image.resize(p, 10, 4097)", "RangeError: VV.image.resize(picture, width, height): height 4097 is outside 1..4096"),
    ("VV.image.resize(p, 10)", "TypeError: VV.image.resize(picture, width, height): height must be an integer, got undefined"),
]  # fmt: skip


@pytest.mark.parametrize(("call", "message"), ARGUMENT_ERRORS)
def test_bad_arguments_throw_naming_the_argument_before_any_request(
    call: str, message: str
) -> None:
    result = failure(P + call + ";")
    assert result.error is not None and result.error.message.startswith(message)
    assert result.requests == 0 and result.error.line == 2


def test_a_message_too_big_or_one_too_many_throws_message_error() -> None:
    source = (
        "var out = [];\n"
        "function attempt(to, value) {\n"
        "  try { out.push(VV.message.send(to, value).id); }\n"
        "  catch (e) { if (!(e instanceof MessageError)) throw e; out.push(e.message); }\n"
        "}\n"
        "attempt('base', 'é'.repeat(5));\n"  # 12 bytes of JSON in UTF-8: over the quota
        "attempt('base', 'abcdefgh');\n"  # 10 bytes: just fits
        "attempt('x'.repeat(200), 1);\n"  # no VV has such a name
        "attempt('nobody', 1);\n"  # refused by the host: not a message sent
        "attempt('base', 2);\n"
        "attempt('base', 3);\n"
        "VV.storage.store('out', out);\n"
    )

    def host(pending: PendingRequest, time_ms: int) -> dict[str, Any]:
        assert pending.args is not None
        if pending.args["to"] == "nobody":
            message = 'VV.message.send(to, value): no VV "nobody" of yours to send to'
            return answer_call_error(pending, time_ms=time_ms, name="MessageError", message=message)
        return answer(pending, time_ms)

    run = Run(source, limits=Limits(message_bytes=10, max_messages=2))
    assert run.run(answer=host).outcome is Outcome.FINISHED
    assert run.storage["out"] == [
        "VV.message.send(to, value): the value is 12 bytes of JSON, more than the 10 allowed "
        "(quota: message bytes)",
        100,
        f'VV.message.send(to, value): no VV "{"x" * 200}" of yours to send to',
        'VV.message.send(to, value): no VV "nobody" of yours to send to',
        102,
        "VV.message.send(to, value): this VV has sent 2 messages, as many as it may "
        "(quota: messages per VV)",
    ]
    assert [r.pending.args["to"] for r in run.results if r.pending and r.pending.args] == [
        "base",
        "nobody",
        "base",
    ]


def test_a_customer_limited_to_some_calls_has_the_vv_killed_at_another() -> None:
    source = P + "VV.message.send('base', 1);\nVV.image.stats(p);\n"
    run = Run(source, limits=Limits(allowed_calls=frozenset({"message.send"})))
    result = run.run(answer=answer)
    assert result.outcome is Outcome.KILLED
    assert result.error is not None and result.error.quota == "api_calls"
    assert "image.stats is not allowed" in result.error.message
    assert result.error.line == 3
    assert len(run.journal) == 1  # the send went through
    assert set(VVM_API_CALLS) >= {
        "message.send",
        "message.receive",
        "image.stats",
        "image.fraction",
        "image.crop",
        "image.resize",
    }


def test_cpu_already_spent_shortens_the_step_and_does_not_make_a_warm_context_replay() -> None:
    source = "VV.message.send('base', 1);\nVV.message.send('base', 2);\nwhile (true) {}\n"
    host = Host(source, limits=Limits(cpu_s=4))
    host.step()
    second = host.step(cpu_spent_s=1.0)
    assert (second.replayed, second.answers_read) == (False, 1)
    killed = host.step(cpu_spent_s=3.8)
    assert killed.outcome is Outcome.KILLED
    assert killed.error is not None and killed.error.quota == "cpu"
    assert "more than 4 s of CPU time" in killed.error.message
    assert killed.duration_s < 1.5  # 0.2 s left of the 4 s quota


def test_the_allowance_is_the_quota_less_what_was_spent_and_never_nothing() -> None:
    assert step_input("", [], limits=Limits(cpu_s=2), cpu_spent_s=0.5).cpu_allowance_s == 1.5
    assert step_input("", [], limits=Limits(cpu_s=2), cpu_spent_s=9).cpu_allowance_s == 0.001


def test_calls_in_callbacks_work_by_replay() -> None:
    source = P + (
        "[0, 1].forEach(function (i) {\n"
        "  var c = VV.image.crop(p, {x: i, y: 0, width: 2, height: 2});\n"
        "  VV.storage.store('c' + i, [c.width, VV.image.stats(c).width]);\n"
        "});\n"
        "var send = VV.message.send;\n"  # a call made through a value: not a yield
        "VV.storage.store('sent', send('base', 1));\n"
    )
    assert not instrument_program(source).generator
    host = Host(source)
    assert host.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in host.results] == [0, 1, 2, 3, 4, 5]
    assert host.storage == {"c0": [2, 640], "c1": [2, 640], "sent": {"id": 104}}


def test_a_picture_from_a_camera_task_goes_to_the_image_calls() -> None:
    source = (
        "var r = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(1, 2, 3),"
        " tolerance: 1, sensors: [VV.sensor.get('Camera 640x480')]});\n"
        "VV.storage.store('f', VV.image.fraction(r[0], {r: [0, 255]}));\n"
    )

    def host(pending: PendingRequest, time_ms: int) -> dict[str, Any]:
        if pending.kind == "task":
            picture = {**reading("Camera 640x480", 0, pending.tasks[0]), **PICTURE}
            return {"q": pending.q, "k": "done", "t": time_ms, "r": pending.fingerprint,
                    "data": [picture]}  # fmt: skip
        return answer(pending, time_ms)

    run = Run(source)
    assert run.run(answer=host).outcome is Outcome.FINISHED
    call = run.results[1].pending
    assert call is not None and call.args is not None and call.args["picture"] == IMAGE
    assert run.storage["f"] == 0.25


@pytest.mark.parametrize(
    ("call", "hook"),
    [
        ("VV.message.send('a', 1)", "__cpcc_send"),
        ("VV.message.receive(5)", "__cpcc_receive"),
        ("VV.image.stats(p)", "__cpcc_stats"),
        ("VV.image.fraction(p, {r: [0, 1]})", "__cpcc_fraction"),
        ("VV.image.crop(p, r)", "__cpcc_crop"),
        ("VV.image.resize(p, 1, 1)", "__cpcc_resize"),
    ],
)
def test_each_call_in_the_programs_body_waits_by_yielding(call: str, hook: str) -> None:
    program = instrument_program(f"var n = 0\n{call}\nfunction f() {{ return {call}; }}\nf()\n")
    assert program.generator
    line = program.code.splitlines()[1]
    assert line.startswith(";(yield*") and f" {hook}(" in line
    # The hook's name starts where the call's own name did: V8 places the call there.
    assert line.index(hook) == 1 + call.index("(") - len(hook.removeprefix("__cpcc_"))
    assert "return (yield* " in program.code and f" {hook}(" in program.code.splitlines()[2]
    # Across lines the call stays as written (and works by replay).
    written = call.replace(".", "\n.", 1)
    assert hook not in instrument_program(written).code
    with pytest.raises(ReservedNameError):
        instrument_program(f"var {hook} = 1;")


def test_pending_requests_of_calls_round_trip_and_old_rows_still_load() -> None:
    pending = first_pending(P + "VV.image.crop(p, {x: 0, y: 0, width: 1, height: 1});")
    assert PendingRequest.from_json(json.loads(json.dumps(pending.to_json()))) == pending
    waiting = first_pending("VV.message.receive(2.5);")
    assert PendingRequest.from_json(waiting.to_json()) == waiting
    assert waiting.to_json()["timeout_s"] == 2.5
    old = {
        "kind": "task",
        "q": 0,
        "r": "{}",
        "tasks": [
            {"position": {"lat": 1.0, "lng": 2.0, "alt": 3.0}, "tolerance": 1, "sensors": ["GPS"]}
        ],
        "open": [0],
    }
    task = PendingRequest.from_json(old)
    assert (task.op, task.args, task.timeout_s) == (None, None, None)
    assert task.to_json() == old
    hash(task)
    hash(pending)
