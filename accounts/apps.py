from django.apps import AppConfig


class AccountsConfig(AppConfig):
    name = "accounts"
    verbose_name = "Customers and users"

    def ready(self) -> None:
        from auditlog.registry import auditlog

        from accounts import signals  # noqa: F401 - connects the receivers
        from accounts.models import Customer

        # Customers and their quotas, SDC entries and VVM-API calls: who changed what.
        auditlog.register(Customer, m2m_fields={"allowed_sensors"})
