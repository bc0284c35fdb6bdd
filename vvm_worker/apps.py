from django.apps import AppConfig


class VvmWorkerConfig(AppConfig):
    name = "vvm_worker"
    verbose_name = "Virtual vehicle monitor"
