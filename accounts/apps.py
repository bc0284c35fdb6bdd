from django.apps import AppConfig
from django.db.models.signals import post_migrate


class AccountsConfig(AppConfig):
    name = "accounts"
    verbose_name = "Customers and users"

    def ready(self) -> None:
        from auditlog.registry import auditlog

        from accounts import signals  # noqa: F401 - connects the receivers
        from accounts.models import Customer

        # Customers and their quotas, SDC entries and VVM-API calls: who changed what.
        auditlog.register(Customer, m2m_fields={"allowed_sensors"})
        post_migrate.connect(_sync_staff_groups, sender=self, dispatch_uid="cpcc-staff-groups")


def _sync_staff_groups(using: str = "default", **kwargs: object) -> None:
    """After ``migrate``: the staff groups get the permissions accounts.staff_groups names,
    those of every app's models (made now if the apps after this one have not yet)."""
    from django.apps import apps
    from django.contrib.auth.management import create_permissions

    from accounts.staff_groups import sync_staff_groups

    for app_config in apps.get_app_configs():
        create_permissions(app_config, verbosity=0, using=using)
    sync_staff_groups(apps)
