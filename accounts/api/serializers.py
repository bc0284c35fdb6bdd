"""Input and output shapes of the customer endpoints."""

from __future__ import annotations

from typing import Any

from rest_framework import serializers

from accounts.models import Customer, ServiceClass
from cpcc_site.api import (
    StrictBooleanField,
    StrictCharField,
    StrictFloatField,
    StrictIntegerField,
    StrictSlugField,
)
from vvm_worker.runtime import VVM_API_CALLS
from vvm_worker.services import CustomerConfig


class CustomerInSerializer(serializers.Serializer):
    """A customer and its quotas; quotas left out keep their defaults (or current values)."""

    name = StrictCharField(max_length=120)
    slug = StrictSlugField(
        max_length=120, required=False, help_text="Made from the name when left out."
    )
    privileged = StrictBooleanField(required=False)
    max_parallel_vvs = StrictIntegerField(min_value=1, required=False)
    max_queued_vvs = StrictIntegerField(
        min_value=1, required=False, help_text="VVs waiting in the queue at most."
    )
    max_tasks_per_vv = StrictIntegerField(min_value=1, required=False)
    storage_bytes = StrictIntegerField(min_value=0, required=False)
    cpu_ms_per_step = StrictIntegerField(min_value=1, required=False)
    heap_bytes = StrictIntegerField(min_value=1024 * 1024, required=False)
    max_messages_per_vv = StrictIntegerField(
        min_value=0,
        max_value=2**31 - 1,
        required=False,
        help_text="Messages each VV may send (VV.message.send); 0: none.",
    )
    max_message_bytes = StrictIntegerField(
        min_value=2,
        max_value=2**31 - 1,
        required=False,
        help_text="Size of one message's value as JSON text, in UTF-8 bytes.",
    )
    allowed_sensors = serializers.ListField(
        child=StrictCharField(),
        required=False,
        help_text="SDC entry names its VVs may use; empty: every unprivileged entry "
        "(privileged ones too for a privileged customer).",
    )
    allowed_api_calls = serializers.ListField(
        child=serializers.ChoiceField(choices=VVM_API_CALLS),
        required=False,
        help_text="VVM-API calls its VVs may use; empty: all.",
    )
    service_class = serializers.SlugRelatedField(
        slug_field="name",
        queryset=ServiceClass.objects.all(),
        allow_null=True,
        required=False,
        help_text="The name of its service class (/api/v1/service-classes/); null: none.",
        error_messages={
            "does_not_exist": "no service class named {value!r}: create it first "
            "(POST /api/v1/service-classes/).",
        },
    )

    def config(self) -> CustomerConfig:
        """The validated input as model fields."""
        data: dict[str, Any] = {
            k: v for k, v in self.validated_data.items() if k != "allowed_sensors"
        }
        return CustomerConfig(**data)  # type: ignore[typeddict-item]

    def sensor_names(self) -> list[str] | None:
        """The allowed sensors asked for, or None when the input does not mention them."""
        names = self.validated_data.get("allowed_sensors")
        return None if names is None else list(names)


class ServiceClassInSerializer(serializers.Serializer):
    """A service class: a p95 target for the time from a task's request to its reading, and
    the weight the planners give its requests."""

    name = StrictCharField(max_length=60)
    p95_s = StrictFloatField(
        min_value=0.1, help_text="Target: 95 % of the tasks are read within this many seconds."
    )
    weight = StrictFloatField(
        min_value=0.01,
        required=False,
        default=1.0,
        help_text="How much one of its requests weighs (1: like a customer without a class).",
    )


class ServiceClassOutSerializer(serializers.ModelSerializer):
    """A service class as a customer's ``service_class`` shows it."""

    class Meta:
        model = ServiceClass
        fields = ["name", "p95_s", "weight"]


class ServiceClassListSerializer(serializers.ModelSerializer):
    """A service class with how many customers are in it."""

    customers = StrictIntegerField(
        source="customer_count", read_only=True, default=0, help_text="Customers in it."
    )

    class Meta:
        model = ServiceClass
        fields = ["id", "name", "p95_s", "weight", "customers"]


class CustomerOutSerializer(serializers.ModelSerializer):
    """A customer: its quotas, what its VVs may use, its users, its service class."""

    allowed_sensors = serializers.SlugRelatedField(slug_field="name", many=True, read_only=True)
    allowed_api_calls = serializers.ListField(child=StrictCharField())
    users = serializers.SlugRelatedField(slug_field="username", many=True, read_only=True)
    vvs_active = StrictIntegerField(
        read_only=True, default=0, help_text="Its VVs that have not ended."
    )
    service_class = ServiceClassOutSerializer(
        read_only=True, allow_null=True, help_text="Its service class; null: none."
    )

    class Meta:
        model = Customer
        fields = [
            "id",
            "name",
            "slug",
            "privileged",
            *Customer.QUOTA_FIELDS,
            "allowed_sensors",
            "allowed_api_calls",
            "users",
            "vvs_active",
            "service_class",
            "created",
        ]
