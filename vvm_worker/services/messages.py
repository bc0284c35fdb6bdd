"""Messages between the VVs of one customer, and from the customer's own system to a VV.

A VV sends with ``VV.message.send(to, value)``: a call the host answers at once, in the unit of
work of the VV's step (``message_send``), so a message is sent exactly once however often the
VV's program is replayed (the answer is in the sender's journal). The recipient takes messages
with ``VV.message.receive(timeoutS)`` (``vv_message_take``), in the order they were sent, each
once: the answer that hands one over is written to its journal in the same transaction that
marks the message received. A recipient with nothing to take is parked on a ground station
until a message or its timeout wakes it (``vvs.py``).
"""

from __future__ import annotations

import json
import uuid
from typing import Any

from django.db import transaction

from accounts.models import User
from missions.events import message_event
from missions.models import ENDED_STATUSES, Message, VirtualVehicle
from missions.selectors import vv_get_for_user
from vvm_worker.sensing import iso_time
from vvm_worker.services.base import VVM, VVAlreadyEnded, customer_named, logger
from vvm_worker.services.store import rows_add
from vvm_worker.services.values import Unstorable, check_text, json_value


class MessageError(ValueError):
    """A message that cannot be sent: the program sees it as a ``MessageError`` with this
    text, the API as a 400."""


def _no_such(to: str) -> MessageError:
    # The same words whether no VV of that name or id exists at all, it is another
    # customer's, or it has ended: nothing tells a customer what others have.
    return MessageError(f"VV.message.send(to, value): no VV {json.dumps(to)} of yours to send to")


def _recipient(customer_id: int, to: str) -> VirtualVehicle | None:
    """The customer's VV that ``to`` names: its id, else the most recently submitted VV of
    that name that has not ended. None when there is none (or it has ended)."""
    vvs = VirtualVehicle.objects.filter(customer_id=customer_id).exclude(status__in=ENDED_STATUSES)
    try:
        by_id = uuid.UUID(to)
    except ValueError:
        by_id = None
    if by_id is not None:
        found = vvs.filter(pk=by_id).first()
        if found is not None:
            return found
    return vvs.filter(name=to).order_by("-submitted_s", "-created").first()


def _checked_size(value_json: str, max_bytes: int | None) -> int:
    """The message's size in bytes, once its text is checked to be a JSON value a VV can
    store, within ``max_bytes`` (None: not checked here). Raises MessageError."""
    where = "VV.message.send(to, value): the value"
    try:
        check_text(value_json, where=where)
        json_value(value_json, where=where)
    except Unstorable as exc:
        raise MessageError(str(exc)) from None
    size = len(value_json.encode())
    if max_bytes is not None and size > max_bytes:
        raise MessageError(
            f"{where} is {size:,} bytes as JSON, more than the {max_bytes:,} allowed "
            "(quota: bytes per message)"
        )
    return size


def message_send(
    *,
    customer_id: int,
    sender: VirtualVehicle | None,
    to: str | VirtualVehicle,
    value_json: str,
    max_bytes: int | None = None,
    vvm: VVM,
) -> Message:
    """Send the JSON text ``value_json`` to the customer's VV ``to`` (a name or an id, or the
    VV itself) from ``sender`` (None: the customer's own system, over the API). The recipient
    is woken once this commits, wherever it is (if it waits in ``receive`` it takes the
    message; otherwise it finds it at its next ``receive``). ``max_bytes``: the customer's
    quota of a message's size, when the caller has not checked it. Raises MessageError."""
    size = _checked_size(value_json, max_bytes)
    if isinstance(to, VirtualVehicle):
        recipient: VirtualVehicle | None = to
    else:
        recipient = _recipient(customer_id, to)
    if recipient is None or recipient.customer_id != customer_id:
        raise _no_such(str(to))
    message = Message(
        customer_id=customer_id,
        sender=sender,
        sender_name=sender.name if sender is not None else "",
        recipient=recipient,
        value=value_json,
        bytes=size,
        sent_s=vvm.clock.now_s(),
    )
    rows_add([message])  # its key is read by the end of the unit of work
    vvm.dispatcher.vv_arrived(recipient.pk)
    if sender is not None:  # (the map draws a line from one VV to the other)
        vvm.announce_at_commit(lambda: [e for e in [message_event(message)] if e is not None])
    logger.info(
        "message sent",
        extra={
            "vv": str(recipient.pk),
            "from": str(sender.pk) if sender is not None else None,
            "customer": customer_named(recipient),
            "bytes": size,
        },
    )
    return message


def vv_message_send_for_user(
    *, user: User, vv_id: uuid.UUID | str, value: Any, vvm: VVM
) -> Message:
    """The user's own system sends ``value`` (any JSON value) to one of the user's VVs.
    Such messages count like a VV's own: each VV takes at most the customer's messages per VV
    from the API. Raises VVNotFound (no such VV of the user's customer), VVAlreadyEnded, or
    MessageError (a value the platform cannot keep, over the customer's size of a message, or
    over its number)."""
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    if vv.is_ended:
        raise VVAlreadyEnded(vv)
    try:
        text = json.dumps(value, ensure_ascii=False, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise MessageError(f"the value cannot be sent as JSON: {exc}") from None
    allowed = vv.customer.max_messages_per_vv
    with transaction.atomic():
        # One sender at a time per VV (the row lock), so that concurrent requests count right.
        VirtualVehicle.objects.select_for_update().filter(pk=vv.pk).values_list("pk").first()
        sent = Message.objects.filter(recipient_id=vv.pk, sender__isnull=True).count()
        if sent >= allowed:
            raise MessageError(
                f"{vv.name} has been sent {sent:,} messages over the API, as many as it may "
                "take (quota: messages per VV)"
            )
        message = message_send(
            customer_id=vv.customer_id,
            sender=None,
            to=vv,
            value_json=text,
            max_bytes=vv.customer.max_message_bytes,
            vvm=vvm,
        )
    return message


def vv_message_take(*, vv: VirtualVehicle, vvm: VVM) -> dict[str, Any] | None:
    """The oldest message to the VV not taken yet, marked taken (the caller holds the VV's
    row and writes the answer to its journal in this transaction), as the program receives
    it: ``{from, id, value, sentAt}``; None when there is none."""
    message = (
        Message.objects.filter(recipient=vv, received_s__isnull=True)
        .order_by("id")
        .only("id", "sender_id", "sender_name", "value", "sent_s")
        .first()
    )
    if message is None:
        return None
    Message.objects.filter(pk=message.pk).update(received_s=vvm.clock.now_s())
    return {
        "from": message.sender_name or None,
        "id": str(message.sender_id) if message.sender_id is not None else None,
        "value": json.loads(message.value),
        "sentAt": iso_time(vvm.clock.epoch_ms(message.sent_s)),
    }
