"""Customers (tenants), their users and their quotas; API tokens; webhooks and e-mail
notifications."""

from __future__ import annotations

import uuid

from django.contrib.auth.models import AbstractUser
from django.core.validators import MinValueValidator
from django.db import models
from django.utils import timezone
from django.utils.text import slugify
from knox.models import AbstractAuthToken
from knox.settings import CONSTANTS

from accounts.roles import CUSTOMER_ROLES, OWNER, ROLE_LABELS

DEFAULT_MAX_PARALLEL_VVS = 5
# Room for two editor submissions of the most copies (50) each, and for every VV of the example
# scenarios at once; a scenario or a script that queues more sets its customer's quota higher.
DEFAULT_MAX_QUEUED_VVS = 100
DEFAULT_MAX_TASKS_PER_VV = 10_000
DEFAULT_STORAGE_BYTES = 10 * 1024 * 1024
DEFAULT_CPU_MS_PER_STEP = 2_000
DEFAULT_HEAP_BYTES = 64 * 1024 * 1024
DEFAULT_MAX_MESSAGES_PER_VV = 1_000
DEFAULT_MAX_MESSAGE_BYTES = 64 * 1024


class NotifyEvent(models.TextChoices):
    """What a customer can hear of by webhook or e-mail."""

    VV_FINISHED = "vv.finished", "a VV finished"
    VV_FAILED = "vv.failed", "a VV failed or was killed"
    TASK_DONE = "task.done", "a task was done"


class ServiceClass(models.Model):
    """A service level staff promise customers: a target for the time from a task's request to
    its reading (95th percentile) and a weight the planners give the class's requests. A
    customer without a class has no target and weight 1."""

    name = models.CharField(max_length=60, unique=True)
    p95_s = models.FloatField(
        validators=[MinValueValidator(0.1)],
        help_text="Target: 95 % of the tasks are read within this many seconds of the request.",
    )
    weight = models.FloatField(
        default=1.0,
        validators=[MinValueValidator(0.01)],
        help_text="How much one of its requests weighs in the planners' objective (1: like a "
        "customer without a class).",
    )

    class Meta:
        ordering = ["name"]
        verbose_name_plural = "service classes"
        constraints = [
            models.CheckConstraint(condition=models.Q(p95_s__gt=0), name="service_p95_positive"),
            models.CheckConstraint(
                condition=models.Q(weight__gt=0), name="service_weight_positive"
            ),
        ]

    def __str__(self) -> str:
        return self.name


class Customer(models.Model):
    """A tenant of the platform: owns VVs, has quotas, never sees another customer's data."""

    # The numeric quotas, as the admin, the API and scenario files name them.
    QUOTA_FIELDS = (
        "max_parallel_vvs",
        "max_queued_vvs",
        "max_tasks_per_vv",
        "storage_bytes",
        "cpu_ms_per_step",
        "heap_bytes",
        "max_messages_per_vv",
        "max_message_bytes",
    )

    name = models.CharField(max_length=120, unique=True)
    slug = models.SlugField(max_length=120, unique=True)
    privileged = models.BooleanField(
        default=False, help_text="May use privileged SDC entries such as the Battery sensor."
    )
    max_parallel_vvs = models.PositiveIntegerField(
        default=DEFAULT_MAX_PARALLEL_VVS,
        validators=[MinValueValidator(1)],
        help_text="VVs running at once; further ones wait in a queue.",
    )
    max_queued_vvs = models.PositiveIntegerField(
        default=DEFAULT_MAX_QUEUED_VVS,
        validators=[MinValueValidator(1)],
        help_text="VVs waiting in the queue at most; a submission beyond is refused.",
    )
    max_tasks_per_vv = models.PositiveIntegerField(
        default=DEFAULT_MAX_TASKS_PER_VV, validators=[MinValueValidator(1)]
    )
    storage_bytes = models.PositiveBigIntegerField(
        default=DEFAULT_STORAGE_BYTES, help_text="Storage quota of each VV, in bytes."
    )
    cpu_ms_per_step = models.PositiveIntegerField(
        default=DEFAULT_CPU_MS_PER_STEP,
        validators=[MinValueValidator(1)],
        help_text="CPU time a VV may use between two blocking calls, in milliseconds.",
    )
    heap_bytes = models.PositiveBigIntegerField(
        default=DEFAULT_HEAP_BYTES,
        validators=[MinValueValidator(1024 * 1024)],
        help_text="V8 heap of one VV, in bytes.",
    )
    max_messages_per_vv = models.PositiveIntegerField(
        default=DEFAULT_MAX_MESSAGES_PER_VV,
        help_text="Messages each VV may send to the customer's other VVs (VV.message.send).",
    )
    max_message_bytes = models.PositiveIntegerField(
        default=DEFAULT_MAX_MESSAGE_BYTES,
        validators=[MinValueValidator(2)],
        help_text="Size of one message's value as JSON, in bytes (UTF-8).",
    )
    allowed_sensors = models.ManyToManyField(
        "fleet.SensorType",
        blank=True,
        related_name="+",
        help_text="SDC entries this customer's VVs may use; none selected means every "
        "unprivileged entry (and privileged ones for privileged customers).",
    )
    allowed_api_calls = models.JSONField(
        default=list,
        blank=True,
        help_text='VVM-API calls this customer\'s VVs may use, e.g. ["task.execute", '
        '"storage.store"]; empty means all.',
    )
    service_class = models.ForeignKey(
        ServiceClass,
        null=True,
        blank=True,
        on_delete=models.PROTECT,
        related_name="customers",
        help_text="The service level promised: a p95 target and a weight; empty: none.",
    )
    created = models.DateTimeField(auto_now_add=True)
    # The events someone of the customer listens for (a webhook, or a user's e-mail): the
    # services that end a VV or answer a task read it with the VV, so an event nobody listens
    # for costs nothing. Kept by the notification services, never edited by hand.
    notify_events = models.JSONField(default=list, blank=True, editable=False)

    class Meta:
        ordering = ["name"]
        constraints = [
            models.CheckConstraint(
                condition=models.Q(max_parallel_vvs__gte=1), name="customer_parallel_vvs_positive"
            ),
            models.CheckConstraint(
                condition=models.Q(max_queued_vvs__gte=1), name="customer_queued_vvs_positive"
            ),
        ]

    def __str__(self) -> str:
        return self.name

    def save(self, *args: object, **kwargs: object) -> None:
        if not self.slug:
            self.slug = slugify(self.name)
        if not (self._state.adding or args or kwargs.get("force_insert")) and (
            kwargs.get("update_fields") is None
        ):
            # notify_events belongs to the notification services (an UPDATE of its own): a
            # customer read before a webhook was made and saved after must not undo it.
            kwargs["update_fields"] = [
                f.name
                for f in self._meta.concrete_fields
                if not f.primary_key and f.name != "notify_events"
            ]
        super().save(*args, **kwargs)  # type: ignore[arg-type]


class ServiceLevelHold(models.Model):
    """A time admission held back a customer's new VVs to keep other classes' targets: its
    class had slack while ``for_classes`` missed theirs. Open (no ``ended_s``) while it
    holds; the service-level report lists each hold of the period."""

    customer = models.ForeignKey(Customer, on_delete=models.CASCADE, related_name="holds")
    service_class = models.CharField(max_length=60, help_text="The customer's class then.")
    for_classes = models.JSONField(
        default=list, help_text="The classes missing their targets it was held for."
    )
    class_p95_s = models.FloatField(
        null=True, blank=True, help_text="Its class's p95 (s) over its recent and open tasks then."
    )
    spare_s = models.FloatField(help_text="How long its VVs could wait at most (its slack, s).")
    started_s = models.FloatField(help_text="Platform clock.")
    ended_s = models.FloatField(null=True, blank=True, help_text="Empty while it holds.")
    vvs_held = models.PositiveIntegerField(default=0, help_text="Most of its VVs held at once.")

    class Meta:
        ordering = ["-started_s"]
        indexes = [models.Index(fields=["customer", "ended_s"])]

    def __str__(self) -> str:
        return f"{self.customer} held from {self.started_s:.0f}"


ROLE_CHOICES = [(role, ROLE_LABELS[role]) for role in reversed(CUSTOMER_ROLES)]


class User(AbstractUser):
    """A person who logs in: a member of a customer with a role (accounts.roles), or platform
    staff (no customer; what they may do is their groups' and permissions')."""

    customer = models.ForeignKey(
        Customer, null=True, blank=True, on_delete=models.CASCADE, related_name="users"
    )
    # A user made without one (by the admin or a scenario that names none) may do everything,
    # as before roles existed; members invited later get the role of their invitation.
    role = models.CharField(
        max_length=10,
        choices=ROLE_CHOICES,
        default=OWNER,
        help_text="What this member may do for the customer (staff: ignored).",
    )
    # Opt-in (none by default): a user made by a scenario has no address, and 50 copies of a
    # VV should not send 50 e-mails unasked.
    email_events = models.JSONField(
        default=list,
        blank=True,
        help_text='Events of the customer\'s VVs e-mailed to this user, e.g. ["vv.failed"].',
    )


class ApiToken(AbstractAuthToken):
    """A named API token a user made: only a digest of its key is kept (knox's), and the key's
    first characters (``token_key``), which identify it to its owner."""

    # An id for the API and the pages (knox's own key is the digest).
    id = models.BigAutoField(primary_key=True)
    digest = models.CharField(max_length=CONSTANTS.DIGEST_LENGTH, unique=True)
    name = models.CharField(max_length=100)
    # Written at most once a minute per token (accounts/authentication.py), not per request.
    last_used = models.DateTimeField(null=True, blank=True)
    # Narrower than its user's role when chosen so (a read-only token for a dashboard); blank:
    # its user's role, whatever that is now.
    role = models.CharField(max_length=10, choices=ROLE_CHOICES, blank=True)

    class Meta:
        ordering = ["-created", "-id"]
        verbose_name = "API token"
        constraints = [
            models.UniqueConstraint(fields=["user", "name"], name="api_token_name_per_user"),
        ]

    def __str__(self) -> str:
        return f"{self.name} ({self.token_key}…)"

    @property
    def prefix(self) -> str:
        return self.token_key


class Webhook(models.Model):
    """A customer's URL that hears of the events it chose by a signed POST."""

    customer = models.ForeignKey(Customer, on_delete=models.CASCADE, related_name="webhooks")
    url = models.URLField(max_length=2000)
    events = models.JSONField(help_text="NotifyEvent values.")
    # Signs every delivery (HMAC-SHA256): kept as it is, shown to the customer once.
    secret = models.CharField(max_length=100, editable=False)
    created = models.DateTimeField(auto_now_add=True)

    class Meta:
        ordering = ["created", "id"]
        constraints = [
            models.UniqueConstraint(fields=["customer", "url"], name="webhook_url_per_customer"),
        ]

    def __str__(self) -> str:
        return self.url


class WebhookDelivery(models.Model):
    """One attempt to POST one event to a webhook: what it answered, or why it did not."""

    webhook = models.ForeignKey(Webhook, on_delete=models.CASCADE, related_name="deliveries")
    # The same for every attempt of one event's POST (the X-CPCC-Delivery header).
    delivery = models.UUIDField(default=uuid.uuid4)
    event = models.CharField(max_length=20, choices=NotifyEvent.choices)
    vv_id = models.UUIDField()
    task_id = models.BigIntegerField(null=True, blank=True)
    attempt = models.PositiveSmallIntegerField()
    status_code = models.PositiveSmallIntegerField(null=True, blank=True)
    error = models.CharField(max_length=300, blank=True)
    duration_ms = models.PositiveIntegerField(null=True, blank=True)
    at = models.DateTimeField(default=timezone.now)

    class Meta:
        ordering = ["-id"]
        verbose_name = "webhook delivery attempt"
        verbose_name_plural = "webhook delivery attempts"
        indexes = [models.Index(fields=["webhook", "-id"], name="webhook_delivery_newest")]

    def __str__(self) -> str:
        return f"{self.event} {self.vv_id} #{self.attempt}"

    @property
    def ok(self) -> bool:
        return self.status_code is not None and 200 <= self.status_code < 300


class Invite(models.Model):
    """An owner's invitation to join the customer with a role: sent by e-mail as a signed link
    that expires (``CPCC_INVITE_DAYS``) and is used once."""

    customer = models.ForeignKey(Customer, on_delete=models.CASCADE, related_name="invites")
    email = models.EmailField()
    role = models.CharField(max_length=10, choices=ROLE_CHOICES)
    invited_by = models.ForeignKey(
        User, null=True, blank=True, on_delete=models.SET_NULL, related_name="+"
    )
    created = models.DateTimeField(default=timezone.now)
    expires = models.DateTimeField()
    accepted = models.DateTimeField(null=True, blank=True)
    accepted_by = models.ForeignKey(
        User, null=True, blank=True, on_delete=models.SET_NULL, related_name="+"
    )

    class Meta:
        ordering = ["-created", "-id"]
        indexes = [models.Index(fields=["customer", "accepted"])]

    def __str__(self) -> str:
        return f"{self.email} as {self.role}"

    @property
    def open(self) -> bool:
        return self.accepted is None and self.expires > timezone.now()
