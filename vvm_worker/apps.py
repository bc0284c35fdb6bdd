from django.apps import AppConfig
from django.conf import settings


class VvmWorkerConfig(AppConfig):
    name = "vvm_worker"
    verbose_name = "Virtual vehicle monitor"

    def ready(self) -> None:
        from vvm_worker.runtime.pool import POOL

        # The runtime reads no settings (a pure core): it is told them.
        POOL.size = settings.CPCC_ISOLATE_POOL
