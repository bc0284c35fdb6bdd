"""Input and output shapes of the VV endpoints."""

from __future__ import annotations

from rest_framework import serializers

from missions.models import TaskStatus, VirtualVehicle


class VVCreateSerializer(serializers.Serializer):
    name = serializers.CharField(max_length=120)
    program = serializers.CharField(trim_whitespace=False, max_length=1_000_000)


class VVSerializer(serializers.ModelSerializer):
    host = serializers.SerializerMethodField(
        help_text="Where the VV is: a ground station or a vehicle."
    )
    tasks_done = serializers.SerializerMethodField()
    tasks_open = serializers.SerializerMethodField()
    error = serializers.CharField()

    class Meta:
        model = VirtualVehicle
        fields = [
            "id",
            "name",
            "status",
            "host",
            "tasks_done",
            "tasks_open",
            "error",
            "error_line",
            "error_column",
            "created",
            "finished",
        ]

    def get_host(self, vv: VirtualVehicle) -> str | None:
        # Customers never learn which vehicles exist; staff see the host's name.
        request = self.context.get("request")
        if request is not None and request.user.is_staff:
            return vv.host_name
        if vv.host_rv_id is not None:
            return "vehicle"
        if vv.host_gs_id is not None:
            return "ground station"
        return None

    def get_tasks_done(self, vv: VirtualVehicle) -> int:
        return vv.tasks.filter(status=TaskStatus.DONE).count()

    def get_tasks_open(self, vv: VirtualVehicle) -> int:
        return vv.tasks.filter(status=TaskStatus.OPEN).count()
