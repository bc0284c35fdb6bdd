"""Customers (tenants), their users and their quotas."""

from __future__ import annotations

from django.contrib.auth.models import AbstractUser
from django.core.validators import MinValueValidator
from django.db import models
from django.utils.text import slugify

DEFAULT_MAX_PARALLEL_VVS = 5
# Room for two editor submissions of the most copies (50) each, and for every VV of the example
# scenarios at once; a scenario or a script that queues more sets its customer's quota higher.
DEFAULT_MAX_QUEUED_VVS = 100
DEFAULT_MAX_TASKS_PER_VV = 10_000
DEFAULT_STORAGE_BYTES = 10 * 1024 * 1024
DEFAULT_CPU_MS_PER_STEP = 2_000
DEFAULT_HEAP_BYTES = 64 * 1024 * 1024


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
    created = models.DateTimeField(auto_now_add=True)

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
        super().save(*args, **kwargs)  # type: ignore[arg-type]


class User(AbstractUser):
    """A person who logs in: a customer's user, or platform staff (no customer)."""

    customer = models.ForeignKey(
        Customer, null=True, blank=True, on_delete=models.CASCADE, related_name="users"
    )
