"""WebSocket routes of the missions app."""

from django.urls import path

from missions.consumers import MapConsumer

websocket_urlpatterns = [
    path("ws/map/", MapConsumer.as_asgi()),
]
