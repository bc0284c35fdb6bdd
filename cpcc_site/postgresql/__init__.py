"""Django's PostgreSQL backend with the platform's connection pool (settings.py,
CPCC_DB_POOL_SIZE): ``ENGINE = "cpcc_site.postgresql"``."""
