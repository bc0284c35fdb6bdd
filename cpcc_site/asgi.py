"""ASGI entry point: HTTP through Django, WebSockets through Channels (the live map)."""

import os

from channels.auth import AuthMiddlewareStack
from channels.routing import ProtocolTypeRouter, URLRouter
from django.core.asgi import get_asgi_application

os.environ.setdefault("DJANGO_SETTINGS_MODULE", "cpcc_site.settings")
# Under ASGI each request runs in a thread of its own: a persistent database connection would
# stay open per thread until the server refuses more clients (Django's advice: none).
os.environ.setdefault("CPCC_DB_CONN_MAX_AGE", "0")
# With PostgreSQL, those connections come from a pool of the process (settings.py says how it
# recovers after an outage).
os.environ.setdefault("CPCC_DB_POOL_SIZE", "8")
django_asgi_app = get_asgi_application()

from cpcc_site.serving import drain_before_shutdown  # noqa: E402
from cpcc_site.websocket import SameOriginValidator  # noqa: E402
from missions.routing import websocket_urlpatterns  # noqa: E402 - needs the apps loaded

drain_before_shutdown()

application = ProtocolTypeRouter(
    {
        "http": django_asgi_app,
        # Session login, as the pages; only pages of this site (its scheme, host and port) may
        # open the socket.
        "websocket": SameOriginValidator(AuthMiddlewareStack(URLRouter(websocket_urlpatterns))),
    }
)
