"""Tenant isolation, route by route.

Every URL pattern of the project (Django's resolver, walked to its leaves: admin, REST API,
pages, auth views, schema and docs) and every WebSocket route of cpcc_site/asgi.py is
classified in ROUTES and WEBSOCKET_ROUTES below; a pattern that is in neither fails
``test_every_url_pattern_is_classified``, so a new URL cannot be forgotten. Each classified
pattern is then tried with real data of two customers (each with a VV flown to its end, with
tasks, storage, log, camera pictures and migrations, a queued one, a user's named API token and a
webhook with a delivery attempt):

- an object of a customer answers 404 to the other customer for every HTTP method, exactly as
  an object that does not exist, changes nothing, and shows none of the owner's data;
- a list shows its caller's data only (its VVs, its API tokens, its customer's webhooks);
- anyone who is not logged in is sent to the login page (pages, admin) or refused (API);
- staff routes refuse customers' users, and let staff in;
- roles (issue 57): each of a customer's members (owner, developer, viewer, and a read-only
  token) may do what the route's ``needs`` says for each method and gets 403 naming the role
  otherwise; each staff group (fleet manager, pilot, support) may do what ``staff`` (or
  STAFF_MODEL_ACCESS for the admin's model views) says, 403 otherwise;
- the live map's socket refuses strangers and other sites, and never sends a customer another
  customer's VVs.
"""

from __future__ import annotations

import datetime as dt
import json
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any
from urllib.parse import urlencode

import pytest
from channels.auth import AuthMiddleware
from channels.routing import URLRouter
from channels.testing import WebsocketCommunicator
from django.apps import apps
from django.conf import settings as django_settings
from django.contrib import admin
from django.contrib.auth.models import Group
from django.db import connection, transaction
from django.db.models import QuerySet
from django.http import HttpResponseBase
from django.test import Client, RequestFactory, override_settings
from django.urls import URLResolver, get_resolver, resolve
from django.utils import timezone
from django.utils.encoding import force_bytes
from django.utils.http import urlsafe_base64_encode
from rest_framework.authtoken.models import Token
from rest_framework.test import APIClient

from accounts.models import (
    ApiToken,
    Customer,
    Invite,
    NotifyEvent,
    ServiceClass,
    User,
    Webhook,
    WebhookDelivery,
)
from accounts.roles import DEVELOPER, FLEET_MANAGER, OWNER, PILOT, SUPPORT, VIEWER, allows
from cpcc_site.asgi import application
from cpcc_site.websocket import SameOriginValidator
from fleet.models import (
    Battery,
    Flight,
    GroundStation,
    MaintenanceInterval,
    MaintenanceRecord,
    PilotDuty,
    SensorType,
    Vehicle,
)
from missions.api.views import UUID_PATTERN
from missions.consumers import MapConsumer
from missions.events import EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH
from missions.models import (
    LogEntry,
    Message,
    Migration,
    StorageDocument,
    Task,
    VirtualVehicle,
    VVStatus,
)
from missions.readings import image_file, image_references
from tests.api_fixtures import MISSION
from tests.conftest import RecordingDispatcher
from tests.factories import CustomerFactory, GroundStationFactory, UserFactory, VehicleFactory

METHODS = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS")
UNSAFE = frozenset({"POST", "PUT", "PATCH", "DELETE"})
READ = ("GET", "HEAD")
ANY = METHODS  # a plain Django view answers whatever the method
# An id that no object has: another customer's object must answer exactly like it.
MISSING_VV = "00000000-0000-4000-8000-000000000000"
MISSING_ID = "987654321"
# The objects of a customer that the URLs name, each as one that does not exist.
MISSING = {
    "vv": MISSING_VV,
    "queued": MISSING_VV,
    "api_token": MISSING_ID,
    "webhook": MISSING_ID,
    "member": MISSING_ID,
    "invite": MISSING_ID,
}
# What a hole would act on: a valid program, a name, a form's confirmation, a webhook (on this
# machine: TestHttp allows such URLs, as the tests' receivers need), an e-mail choice.
HOOK_URL = "http://127.0.0.1:9/taken-over"
API_BODY = {
    "name": "taken over",
    "program": "var x = 1;",
    "value": "taken over",
    "url": HOOK_URL,
    "events": ["vv.finished"],
    "email": "taken-over@example.com",
    "role": "viewer",
}
FORM_BODY = {
    "name": "taken over",
    "program": "var x = 1;",
    "value": '"taken over"',
    "copies": "1",
    "post": "yes",
    "url": HOOK_URL,
    "events": "vv.finished",
    "email": "taken-over@example.com",
    "email_events": "vv.finished",
    "role": "viewer",
}


class Kind(StrEnum):
    PUBLIC = "public"  # anyone, logged in or not; no customer's data
    SIGNED_IN = "signed in"  # any logged-in user; no customer's data
    OWN_LIST = "own list"  # the caller's customer's VVs (staff: all), API tokens or webhooks
    # One VV of a customer, or its data, or a user's API token, or a customer's webhook (or
    # its delivery log): 404 for anyone else.
    OBJECT = "object"
    STAFF = "staff"  # platform staff only: the admin, the fleet, the customers


@dataclass(frozen=True)
class Route:
    """How a URL pattern is tried: what it is, a URL of it (``{name}`` filled from the data of
    the customer who owns the objects), the methods its view acts on."""

    kind: Kind
    url: str
    methods: tuple[str, ...] = READ
    # OBJECT: the same view reached through a query string (``?from=<id>``) and the methods
    # that read it there.
    also: str = ""
    also_methods: tuple[str, ...] = ()
    # STAFF: what staff get for GET when it is not 200 or a redirect (a view that needs
    # more than being staff, or a missing object).
    staff_status: int | None = None
    # STAFF: the model of a view every ModelAdmin has (generated below).
    model: str = ""
    # OWN_LIST: what it lists of the caller's own (Side.listed): its customer's "vvs", its
    # "api tokens", its customer's "webhooks".
    lists: str = "vvs"
    # The methods a token may not use (a token cannot make another): 403 to a token, the
    # declared answer to a session.
    session_only: tuple[str, ...] = ()
    # SIGNED_IN: the view revokes the caller's own token (the one an administrator made):
    # B's request may change that, and nothing else.
    revokes_own_token: bool = False
    # The customer's role each method needs (accounts.roles; "*" for every method): else a
    # viewer reads and a developer changes.
    needs: dict[str, str] = field(default_factory=dict)
    # STAFF: what each staff group may do (the methods; others answer 403). The admin's model
    # views say it in STAFF_MODEL_ACCESS instead.
    staff: dict[str, tuple[str, ...]] | None = None
    # PUBLIC: what GET answers when it is not 200 or a redirect.
    public_status: int | None = None

    def role_needed(self, method: str) -> str:
        if method in self.needs:
            return self.needs[method]
        if "*" in self.needs:
            return self.needs["*"]
        return VIEWER if method in ("GET", "HEAD", "OPTIONS") else DEVELOPER


# --- the classification -----------------------------------------------------------------------

READS = ("GET", "HEAD")
WRITES = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")
PERSONAL = {"*": VIEWER}  # the caller's own account: any member, whatever their role
ONLY_READS = {"*": VIEWER}  # a view that changes nothing, whatever the method
OWNERS_CHANGE = {"POST": OWNER, "PUT": OWNER, "PATCH": OWNER, "DELETE": OWNER}


def staff(
    fleet_manager: tuple[str, ...] = (), pilot: tuple[str, ...] = (), support: tuple[str, ...] = ()
) -> dict[str, tuple[str, ...]]:
    """What each staff group may do on a staff route: the methods (others: 403)."""
    return {FLEET_MANAGER: fleet_manager, PILOT: pilot, SUPPORT: support}


EVERY_GROUP = staff(WRITES, WRITES, WRITES)

ROUTES: dict[str, Route] = {
    # Django's auth views (the site's login) and the icon.
    "favicon.ico": Route(Kind.PUBLIC, "/favicon.ico"),
    "accounts/login/": Route(Kind.PUBLIC, "/accounts/login/"),
    "accounts/logout/": Route(Kind.PUBLIC, "/accounts/logout/", ("POST",)),
    "accounts/password_change/": Route(
        Kind.SIGNED_IN, "/accounts/password_change/", ("GET", "POST"), needs=PERSONAL
    ),
    "accounts/password_change/done/": Route(Kind.SIGNED_IN, "/accounts/password_change/done/"),
    "accounts/password_reset/": Route(Kind.PUBLIC, "/accounts/password_reset/"),
    "accounts/password_reset/done/": Route(Kind.PUBLIC, "/accounts/password_reset/done/"),
    # A's user id with a token that is not one: the page says the link is invalid.
    "accounts/reset/<uidb64>/<token>/": Route(Kind.PUBLIC, "/accounts/reset/{uidb64}/x-y/"),
    "accounts/reset/done/": Route(Kind.PUBLIC, "/accounts/reset/done/"),
    # The Account pages (accounts/urls.py): the user's own API tokens (a POST makes one), the
    # customer's webhooks and the user's e-mail choice (a POST saves it).
    "accounts/tokens/": Route(
        Kind.OWN_LIST, "/accounts/tokens/", ("GET", "POST"), lists="api tokens", needs=PERSONAL
    ),
    "accounts/tokens/<int:token_id>/revoke/": Route(
        Kind.OBJECT, "/accounts/tokens/{api_token}/revoke/", ("POST",), needs=PERSONAL
    ),
    # The caller's own token made by an administrator (drf_create_token): no id in the URL.
    "accounts/tokens/operator/revoke/": Route(
        Kind.SIGNED_IN,
        "/accounts/tokens/operator/revoke/",
        ("POST",),
        revokes_own_token=True,
        needs=PERSONAL,
    ),
    # The customer's webhooks (developers add them) and the caller's own e-mail choice.
    "accounts/notifications/": Route(
        Kind.OWN_LIST, "/accounts/notifications/", ("GET", "POST"), lists="webhooks", needs=PERSONAL
    ),
    # The customer's members and invitations (every member reads; owners invite, change
    # roles, remove members and withdraw invitations).
    "accounts/members/": Route(
        Kind.OWN_LIST, "/accounts/members/", ("GET", "POST"), lists="members", needs=OWNERS_CHANGE
    ),
    "accounts/members/<int:member_id>/role/": Route(
        Kind.OBJECT, "/accounts/members/{member}/role/", ("POST",), needs=OWNERS_CHANGE
    ),
    "accounts/members/<int:member_id>/remove/": Route(
        Kind.OBJECT, "/accounts/members/{member}/remove/", ("POST",), needs=OWNERS_CHANGE
    ),
    "accounts/invites/<int:invite_id>/withdraw/": Route(
        Kind.OBJECT, "/accounts/invites/{invite}/withdraw/", ("POST",), needs=OWNERS_CHANGE
    ),
    # An invitation's link: a link that is no invitation says so (410).
    "accounts/invite/<str:signed>/": Route(
        Kind.PUBLIC, "/accounts/invite/not-a-link/", ("GET", "POST"), public_status=410
    ),
    # Adds a webhook to the caller's customer; the answer is the caller's Notifications page.
    "accounts/webhooks/new/": Route(Kind.SIGNED_IN, "/accounts/webhooks/new/", ("POST",)),
    "accounts/webhooks/<int:webhook_id>/": Route(
        Kind.OBJECT, "/accounts/webhooks/{webhook}/", ("GET",)
    ),
    "accounts/webhooks/<int:webhook_id>/remove/": Route(
        Kind.OBJECT, "/accounts/webhooks/{webhook}/remove/", ("POST",)
    ),
    # The REST API: VVs (DefaultRouter, with format suffixes) and what hangs off one VV.
    "api/v1/": Route(Kind.SIGNED_IN, "/api/v1/"),
    "api/v1/<drf_format_suffix:format>": Route(Kind.SIGNED_IN, "/api/v1/.json"),
    "api/v1/vvs/$": Route(Kind.OWN_LIST, "/api/v1/vvs/", ("GET", "POST")),
    r"api/v1/vvs\.(?P<format>[a-z0-9]+)/?$": Route(Kind.OWN_LIST, "/api/v1/vvs.json"),
    # A program tried against a simulated copy of the fleet: the caller's own, nothing stored.
    "api/v1/vvs/dry-run/": Route(Kind.SIGNED_IN, "/api/v1/vvs/dry-run/", ("POST",)),
    "api/v1/vvs/(?P<pk>{uuid})/$": Route(Kind.OBJECT, "/api/v1/vvs/{vv}/"),
    r"api/v1/vvs/(?P<pk>{uuid})\.(?P<format>[a-z0-9]+)/?$": Route(
        Kind.OBJECT, "/api/v1/vvs/{vv}.json"
    ),
    "api/v1/vvs/(?P<pk>{uuid})/cancel/$": Route(
        Kind.OBJECT, "/api/v1/vvs/{queued}/cancel/", ("POST",)
    ),
    r"api/v1/vvs/(?P<pk>{uuid})/cancel\.(?P<format>[a-z0-9]+)/?$": Route(
        Kind.OBJECT, "/api/v1/vvs/{queued}/cancel.json", ("POST",)
    ),
    "api/v1/vvs/(?P<id>{uuid})/storage/$": Route(Kind.OBJECT, "/api/v1/vvs/{vv}/storage/"),
    r"api/v1/vvs/(?P<id>{uuid})/storage/(?P<key>[\s\S]+)/$": Route(
        Kind.OBJECT, "/api/v1/vvs/{vv}/storage/{key}/"
    ),
    "api/v1/vvs/(?P<id>{uuid})/images/(?P<file>[^/]+)$": Route(
        Kind.OBJECT, "/api/v1/vvs/{vv}/images/{file}"
    ),
    "api/v1/vvs/(?P<id>{uuid})/tasks/$": Route(Kind.OBJECT, "/api/v1/vvs/{vv}/tasks/"),
    "api/v1/vvs/(?P<id>{uuid})/log/$": Route(Kind.OBJECT, "/api/v1/vvs/{vv}/log/"),
    # The queued VV has not ended: a POST would send it a message.
    "api/v1/vvs/(?P<id>{uuid})/messages/$": Route(
        Kind.OBJECT, "/api/v1/vvs/{queued}/messages/", ("GET", "POST")
    ),
    r"api/v1/vvs/(?P<id>{uuid})/results\.zip$": Route(Kind.OBJECT, "/api/v1/vvs/{vv}/results.zip"),
    r"api/v1/vvs/(?P<id>{uuid})/readings\.csv$": Route(
        Kind.OBJECT, "/api/v1/vvs/{vv}/readings.csv"
    ),
    r"api/v1/vvs/(?P<id>{uuid})/readings\.geojson$": Route(
        Kind.OBJECT, "/api/v1/vvs/{vv}/readings.geojson"
    ),
    r"api/v1/vvs/(?P<id>{uuid})/track\.kml$": Route(Kind.OBJECT, "/api/v1/vvs/{vv}/track.kml"),
    # The SDC entries the caller may use: the same catalog for every customer by default.
    "api/v1/sensors/": Route(Kind.SIGNED_IN, "/api/v1/sensors/"),
    # Where tasks can be served: the same for everyone, no vehicle named.
    "api/v1/service-area/": Route(Kind.SIGNED_IN, "/api/v1/service-area/"),
    "api/v1/service-levels/": Route(
        Kind.STAFF, "/api/v1/service-levels/", staff=staff(READS, (), READS)
    ),
    # The fleet: fleet managers change it; pilots operate the RVs they are assigned (the
    # world's pilot flies Heli One); support reads.
    "api/v1/vehicles/$": Route(
        Kind.STAFF, "/api/v1/vehicles/", ("GET", "POST"), staff=staff(WRITES, READS, READS)
    ),
    "api/v1/vehicles/(?P<pk>[^/.]+)/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/{vehicle}/",
        ("GET", "PATCH", "DELETE"),
        staff=staff(WRITES, READS, READS),
    ),
    "api/v1/vehicles/(?P<pk>[^/.]+)/maintenance/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/{vehicle}/maintenance/",
        ("POST",),
        staff=staff(WRITES, WRITES, READS),
    ),
    "api/v1/vehicles/(?P<pk>[^/.]+)/remove/$": Route(
        Kind.STAFF, "/api/v1/vehicles/{vehicle}/remove/", ("POST",), staff=staff(WRITES)
    ),
    "api/v1/vehicles/(?P<pk>[^/.]+)/return/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/{vehicle}/return/",
        ("POST",),
        staff=staff(WRITES, WRITES, READS),
    ),
    # An operator's commands (issue 26).
    "api/v1/vehicles/(?P<pk>[^/.]+)/return-home/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/{vehicle}/return-home/",
        ("POST",),
        staff=staff(WRITES, WRITES, READS),
    ),
    "api/v1/vehicles/(?P<pk>[^/.]+)/land/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/{vehicle}/land/",
        ("POST",),
        staff=staff(WRITES, WRITES, READS),
    ),
    # A pilot in command (issue 57): one RV or a group on duty, and handed over. A fleet
    # manager may ask (and is told they are not its pilot: 409).
    "api/v1/vehicles/(?P<pk>[^/.]+)/take-duty/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/{vehicle}/take-duty/",
        ("POST",),
        staff=staff(WRITES, WRITES, READS),
    ),
    "api/v1/vehicles/(?P<pk>[^/.]+)/hand-over/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/{vehicle}/hand-over/",
        ("POST",),
        staff=staff(WRITES, WRITES, READS),
    ),
    # A group: the body here names none (400).
    "api/v1/vehicles/take-duty/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/take-duty/",
        ("POST",),
        staff_status=400,
        staff=staff(WRITES, WRITES, READS),
    ),
    "api/v1/vehicles/hand-over/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/hand-over/",
        ("POST",),
        staff_status=400,
        staff=staff(WRITES, WRITES, READS),
    ),
    # The flights and the logbook (issue 58): every staff group reads them.
    "api/v1/flights/": Route(Kind.STAFF, "/api/v1/flights/", staff=EVERY_GROUP),
    "api/v1/flights/export.csv": Route(Kind.STAFF, "/api/v1/flights/export.csv", staff=EVERY_GROUP),
    "api/v1/flights/<str:pk>/": Route(Kind.STAFF, "/api/v1/flights/{flight}/", staff=EVERY_GROUP),
    # The world's flight keeps no log: 404 saying so.
    "api/v1/flights/<str:pk>/log.tlog": Route(
        Kind.STAFF, "/api/v1/flights/{flight}/log.tlog", staff_status=404, staff=EVERY_GROUP
    ),
    "api/v1/vehicles/(?P<pk>[^/.]+)/logbook/$": Route(
        Kind.STAFF, "/api/v1/vehicles/{vehicle}/logbook/", staff=EVERY_GROUP
    ),
    # Batteries and maintenance (issue 58): every staff group reads the batteries; fleet
    # managers record maintenance (the body here says nothing done: 400); a pilot records a
    # battery swap on the RVs they are assigned.
    "api/v1/batteries/": Route(Kind.STAFF, "/api/v1/batteries/", staff=EVERY_GROUP),
    "api/v1/vehicles/(?P<pk>[^/.]+)/maintenance-record/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/{vehicle}/maintenance-record/",
        ("POST",),
        staff_status=400,
        staff=staff(WRITES, READS, READS),
    ),
    "api/v1/vehicles/(?P<pk>[^/.]+)/battery/$": Route(
        Kind.STAFF,
        "/api/v1/vehicles/{vehicle}/battery/",
        ("POST",),
        staff=staff(WRITES, WRITES, READS),
    ),
    "api/v1/ground-stations/$": Route(
        Kind.STAFF, "/api/v1/ground-stations/", ("GET", "POST"), staff=staff(WRITES, READS, READS)
    ),
    "api/v1/ground-stations/(?P<pk>[^/.]+)/$": Route(
        Kind.STAFF,
        "/api/v1/ground-stations/{gs}/",
        ("GET", "PUT", "PATCH", "DELETE"),
        staff=staff(WRITES, READS, READS),
    ),
    # Customers: fleet managers change their quotas and classes (a superuser adds and
    # deletes customers); support reads; pilots see no customer.
    "api/v1/customers/$": Route(
        Kind.STAFF, "/api/v1/customers/", ("GET", "POST"), staff=staff(READS, (), READS)
    ),
    "api/v1/service-classes/$": Route(
        Kind.STAFF, "/api/v1/service-classes/", ("GET", "POST"), staff=staff(WRITES, (), READS)
    ),
    "api/v1/service-classes/(?P<pk>[^/.]+)/$": Route(
        Kind.STAFF, "/api/v1/service-classes/{service_class}/", staff=staff(READS, (), READS)
    ),
    "api/v1/customers/(?P<pk>[^/.]+)/$": Route(
        Kind.STAFF,
        "/api/v1/customers/{customer}/",
        ("GET", "PUT", "PATCH", "DELETE"),
        staff=staff(("GET", "PUT", "PATCH"), (), READS),
    ),
    # A user's named API tokens (made with a session only) and a customer's webhooks.
    "api/v1/tokens/$": Route(
        Kind.OWN_LIST,
        "/api/v1/tokens/",
        ("GET", "POST"),
        lists="api tokens",
        session_only=("POST",),
        needs=PERSONAL,
    ),
    # A token may revoke only itself: another one is revoked with a session.
    "api/v1/tokens/(?P<pk>[^/.]+)/$": Route(
        Kind.OBJECT,
        "/api/v1/tokens/{api_token}/",
        ("GET", "DELETE"),
        needs=PERSONAL,
        session_only=("DELETE",),
    ),
    # The customer's members and invitations: every member reads, owners change.
    "api/v1/members/$": Route(Kind.OWN_LIST, "/api/v1/members/", lists="members"),
    "api/v1/members/(?P<pk>[^/.]+)/$": Route(
        Kind.OBJECT, "/api/v1/members/{member}/", ("GET", "PATCH", "DELETE"), needs=OWNERS_CHANGE
    ),
    "api/v1/invites/$": Route(
        Kind.OWN_LIST, "/api/v1/invites/", ("GET", "POST"), lists="invites", needs=OWNERS_CHANGE
    ),
    "api/v1/invites/(?P<pk>[^/.]+)/$": Route(
        Kind.OBJECT, "/api/v1/invites/{invite}/", ("GET", "DELETE"), needs=OWNERS_CHANGE
    ),
    "api/v1/webhooks/$": Route(
        Kind.OWN_LIST, "/api/v1/webhooks/", ("GET", "POST"), lists="webhooks"
    ),
    "api/v1/webhooks/(?P<pk>[^/.]+)/$": Route(
        Kind.OBJECT, "/api/v1/webhooks/{webhook}/", ("GET", "DELETE")
    ),
    "api/v1/webhooks/(?P<pk>[^/.]+)/deliveries/$": Route(
        Kind.OBJECT, "/api/v1/webhooks/{webhook}/deliveries/"
    ),
    # The API's schema and docs are public (drf-spectacular's default): endpoints, no data.
    "api/schema/": Route(Kind.PUBLIC, "/api/schema/"),
    "api/docs/": Route(Kind.PUBLIC, "/api/docs/"),
    "api/redoc/": Route(Kind.PUBLIC, "/api/redoc/"),
    "api/redoc/redoc.standalone.js": Route(Kind.PUBLIC, "/api/redoc/redoc.standalone.js"),
    # The pages (missions/urls.py).
    "": Route(Kind.OWN_LIST, "/"),
    "vvs/rows/": Route(Kind.OWN_LIST, "/vvs/rows/"),
    "vvs/new/": Route(
        Kind.SIGNED_IN,
        "/vvs/new/",
        ("GET", "POST"),
        # The editor starts from one of the user's VVs with ?from=; a POST ignores it.
        also="/vvs/new/?from={vv}",
        also_methods=("GET", "HEAD", "PUT", "PATCH", "DELETE", "OPTIONS"),
        needs={"*": DEVELOPER},  # the editor is for submitting
    ),
    "vvs/check/": Route(Kind.SIGNED_IN, "/vvs/check/", ("POST",)),
    "vvs/<uuid:vv_id>/": Route(Kind.OBJECT, "/vvs/{vv}/", ANY),
    "vvs/<uuid:vv_id>/edit/": Route(
        Kind.OBJECT, "/vvs/{queued}/edit/", ANY, needs={"*": DEVELOPER}
    ),
    "vvs/<uuid:vv_id>/cancel/": Route(Kind.OBJECT, "/vvs/{queued}/cancel/", ("POST",)),
    "vvs/<uuid:vv_id>/restart/": Route(Kind.OBJECT, "/vvs/{vv}/restart/", ("POST",)),
    "vvs/<uuid:vv_id>/storage.json": Route(
        Kind.OBJECT, "/vvs/{vv}/storage.json", ANY, needs=ONLY_READS
    ),
    "vvs/<uuid:vv_id>/map.json": Route(Kind.OBJECT, "/vvs/{vv}/map.json", ANY, needs=ONLY_READS),
    # The live map's page holds no data: it comes over the socket (tested at the end).
    "map/": Route(Kind.SIGNED_IN, "/map/"),
    # The maps' background: the simulated world, no one's data (fleet/views.py).
    "tiles/<int:z>/<int:x>/<int:y>.png": Route(Kind.PUBLIC, "/tiles/0/0/0.png"),
    # The admin site's own views (every one behind AdminSite.admin_view but the login).
    "admin/": Route(Kind.STAFF, "/admin/", ("GET", "POST"), staff=EVERY_GROUP),
    "admin/login/": Route(Kind.PUBLIC, "/admin/login/"),
    "admin/logout/": Route(Kind.STAFF, "/admin/logout/", ("POST",), staff=EVERY_GROUP),
    "admin/password_change/": Route(
        Kind.STAFF, "/admin/password_change/", ("GET", "POST"), staff=EVERY_GROUP
    ),
    "admin/password_change/done/": Route(
        Kind.STAFF, "/admin/password_change/done/", staff=EVERY_GROUP
    ),
    # The task admin's autocompletion of VVs: their names and customers, to staff only.
    "admin/autocomplete/": Route(
        Kind.STAFF,
        "/admin/autocomplete/?app_label=missions&model_name=task&field_name=vv&term=a",
        staff=staff(READS, (), READS),
    ),
    "admin/jsi18n/": Route(Kind.STAFF, "/admin/jsi18n/", staff=EVERY_GROUP),
    # "View on site" of A's customer: customers have no page of their own on the site.
    "admin/r/<path:content_type_id>/<path:object_id>/": Route(
        Kind.STAFF, "/admin/r/{customer_type}/{customer}/", staff_status=404, staff=EVERY_GROUP
    ),
    # The VVs' section: pilots see none of it.
    "admin/(?P<app_label>{apps})/$": Route(
        Kind.STAFF, "/admin/missions/", ("GET", "POST"), staff=staff(WRITES, (), WRITES)
    ),
    "admin/(?P<url>.*)$": Route(
        Kind.STAFF, "/admin/no/such/page/", staff_status=404, staff=EVERY_GROUP
    ),
    # Custom views of the model admins (ModelAdmin.get_urls overrides).
    "admin/fleet/vehicle/overview/": Route(
        Kind.STAFF, "/admin/fleet/vehicle/overview/", staff=EVERY_GROUP
    ),
    "admin/fleet/vehicle/<int:object_id>/logbook/": Route(
        Kind.STAFF, "/admin/fleet/vehicle/{vehicle}/logbook/", staff=EVERY_GROUP
    ),
    "admin/accounts/serviceclass/levels/": Route(
        Kind.STAFF, "/admin/accounts/serviceclass/levels/", staff=staff(READS, (), READS)
    ),
    # An action of the fleet overview: a POST without one is refused, saying which there are.
    "admin/fleet/vehicle/overview/<int:object_id>/act/": Route(
        Kind.STAFF,
        "/admin/fleet/vehicle/overview/{vehicle}/act/",
        ("POST",),
        staff_status=400,
        staff=staff(WRITES, WRITES, READS),
    ),
    "admin/accounts/user/<id>/password/": Route(
        Kind.STAFF, "/admin/accounts/user/{user}/password/", ("GET", "POST"), staff=staff()
    ),
}

# The views every ModelAdmin has (ModelAdmin.get_urls): generated for each registered model,
# each behind AdminSite.admin_view. A model admin's own views are not: they are listed above.
ADMIN_MODEL_VIEWS = {
    "": "",
    "add/": "add/",
    "<path:object_id>/history/": "{obj}/history/",
    "<path:object_id>/delete/": "{obj}/delete/",
    "<path:object_id>/change/": "{obj}/change/",
    "<path:object_id>/": "{obj}/",
}


# What each staff group may do with each model in the admin: "v"iew, "a"dd, "c"hange,
# "d"elete (accounts.staff_groups). A model the admin registers must be here.
_FLEET = {FLEET_MANAGER: "vacd", PILOT: "v", SUPPORT: "v"}
_READ = {FLEET_MANAGER: "v", PILOT: "", SUPPORT: "v"}
_NONE = {FLEET_MANAGER: "", PILOT: "", SUPPORT: ""}
STAFF_MODEL_ACCESS: dict[str, dict[str, str]] = {
    "accounts.apitoken": _NONE,  # keys: a superuser's
    "accounts.customer": {FLEET_MANAGER: "vc", PILOT: "", SUPPORT: "v"},
    "accounts.invite": _READ,
    "accounts.serviceclass": {FLEET_MANAGER: "vacd", PILOT: "", SUPPORT: "v"},
    "accounts.user": _READ,
    "accounts.webhook": _READ,
    "auditlog.logentry": _READ,
    "auth.group": _NONE,
    "authtoken.tokenproxy": _NONE,
    "axes.accessattempt": _NONE,
    "axes.accessfailurelog": _NONE,
    "axes.accesslog": _NONE,
    "fleet.groundstation": _FLEET,
    "fleet.noflyzone": _FLEET,
    "fleet.rallypoint": _FLEET,
    "fleet.sensortype": _FLEET,
    "fleet.vehicle": _FLEET,
    "fleet.pilotduty": {FLEET_MANAGER: "v", PILOT: "v", SUPPORT: "v"},
    "fleet.flight": {FLEET_MANAGER: "v", PILOT: "v", SUPPORT: "v"},
    "fleet.battery": _FLEET,
    "fleet.maintenanceinterval": _FLEET,
    # Added through the service, never changed or deleted.
    "fleet.maintenancerecord": {FLEET_MANAGER: "va", PILOT: "v", SUPPORT: "v"},
    "missions.logentry": _READ,
    "missions.message": _READ,
    "missions.migration": _READ,
    "missions.storagedocument": _READ,
    "missions.task": _READ,
    # Fleet managers may cancel a VV that harms the fleet.
    "missions.virtualvehicle": {FLEET_MANAGER: "vc", PILOT: "", SUPPORT: "v"},
}
# What each of the admin's model views needs (ADMIN_MODEL_VIEWS).
ADMIN_VIEW_NEEDS = {
    "": "v",
    "add/": "a",
    "<path:object_id>/history/": "v",
    "<path:object_id>/delete/": "d",
    "<path:object_id>/change/": "v",
    "<path:object_id>/": "",  # a redirect to .../change/, for any staff
}


def _admin_model_routes() -> dict[str, Route]:
    routes = {}
    for model in admin.site._registry:
        base = f"{model._meta.app_label}/{model._meta.model_name}/"
        for pattern, url in ADMIN_MODEL_VIEWS.items():
            filled = url.replace("{obj}", "{admin:" + model._meta.label_lower + "}")
            routes[f"admin/{base}{pattern}"] = Route(
                Kind.STAFF, f"/admin/{base}{filled}", ("GET", "POST"), model=model._meta.label_lower
            )
    return routes


ROUTES |= _admin_model_routes()

# WebSocket routes (cpcc_site/asgi.py): the consumer each one must reach; tested at the end.
WEBSOCKET_ROUTES = {"ws/map/": MapConsumer}


def _join(prefix: str, route: str) -> str:
    """Patterns joined as Django's resolver does (ResolverMatch.route)."""
    return route if not prefix else prefix + route.removeprefix("^")


def normalized(route: str) -> str:
    """A pattern as ROUTES names it: the VV id pattern and the admin's app list shortened."""
    route = route.replace(UUID_PATTERN, "{uuid}")
    return re.sub(r"\(\?P<app_label>[\w|]+\)", "(?P<app_label>{apps})", route)


def url_patterns(patterns: list[Any] | None = None, prefix: str = "") -> Iterator[str]:
    """Every leaf pattern of the project's URLconf, as its full route."""
    for pattern in get_resolver().url_patterns if patterns is None else patterns:
        route = _join(prefix, str(pattern.pattern))
        if isinstance(pattern, URLResolver):
            yield from url_patterns(pattern.url_patterns, route)
        else:
            yield normalized(route)


def websocket_routes() -> Iterator[tuple[str, Any, list[type]]]:
    """Every WebSocket route of the ASGI application: (route, consumer class, the layers of
    the stack it sits under)."""

    def walk(node: Any, stack: list[type]) -> Iterator[tuple[str, Any, list[type]]]:
        if isinstance(node, URLRouter):
            for route in node.routes:
                if isinstance(route, URLResolver):
                    raise AssertionError("nested WebSocket routers: walk them here")
                callback = route.callback
                yield str(route.pattern), getattr(callback, "consumer_class", callback), stack
            return
        inner = getattr(node, "inner", None) or getattr(node, "application", None)
        if inner is None:
            raise AssertionError(f"no routes under {node!r}")
        yield from walk(inner, [*stack, type(node)])

    yield from walk(application.application_mapping["websocket"], [])


# --- the data -----------------------------------------------------------------------------------

# Customer A's flown VV: the API tests' mission plus a stored value and a log line that appear
# nowhere else (the program builds them, so the program's text does not contain them).
A_FLOWN_PROGRAM = (
    MISSION
    + """
VV.storage.store('alpha note', 'alpha-storage-' + 'secret');
VV.log('alpha-log-' + 'secret');
"""
)
B_FLOWN_PROGRAM = """
var cam = VV.sensor.get('Camera 640x480');
var points = [new VV.types.LatLngAlt(48.1100, 12.8600, 40),
              new VV.types.LatLngAlt(48.1130, 12.8630, 40)];
for (var n = 0; n < points.length; ++n) {
  VV.task.execute({type: 'point', position: points[n], tolerance: 2, sensors: [cam]},
    function (d) { VV.storage.store('b' + n + '.camera', d[0]); });
}
VV.storage.store('bravo note', 'bravo-storage-' + 'secret');
VV.log('bravo-log-' + 'secret');
"""


@dataclass
class Side:
    """One customer and its objects."""

    customer: Customer
    user: User
    token: str
    flown: VirtualVehicle  # ended, with tasks, storage, log, pictures and migrations
    queued: VirtualVehicle  # waiting: it can still be cancelled and edited
    image: str  # the file name of one of its camera pictures
    key: str  # a storage key whose value is a camera reading
    markers: tuple[str, ...] = ()  # strings that are its data and nobody else's
    api_token: ApiToken | None = None  # the user's named API token
    webhook: Webhook | None = None  # the customer's webhook, with one delivery attempt
    # Its members besides ``user`` (its owner): a developer and a viewer.
    members: dict[str, User] = field(default_factory=dict)
    invite: Invite | None = None  # an owner's invitation not accepted yet
    read_only_key: str = ""  # the key of a named token of ``user`` that acts as a viewer

    def values(self) -> dict[str, str]:
        assert self.api_token is not None and self.webhook is not None
        assert self.invite is not None
        return {
            "vv": str(self.flown.pk),
            "queued": str(self.queued.pk),
            "file": self.image,
            "key": self.key,
            "api_token": str(self.api_token.pk),
            "webhook": str(self.webhook.pk),
            "member": str(self.members[VIEWER].pk),
            "invite": str(self.invite.pk),
        }

    def listed(self, what: str) -> str:
        """What a list of the caller's ``what`` (Route.lists) shows of its own."""
        assert self.api_token is not None and self.webhook is not None
        assert self.invite is not None
        return {
            "vvs": self.flown.name,
            "api tokens": self.api_token.name,
            "webhooks": self.webhook.url,
            "members": self.user.username,
            "invites": self.invite.email,
        }[what]


@dataclass
class World:
    a: Side
    b: Side
    staff: User
    media: Path
    # A staff user in each group (accounts.roles.STAFF_GROUPS); the pilot flies Heli One.
    groups: dict[str, User] = field(default_factory=dict)
    ids: dict[str, str] = field(default_factory=dict)  # staff objects, mostly A's
    # The SQL of ``fingerprint``'s queries, by the user left out (None: nobody).
    fingerprint_sql: dict[int | None, dict[str, tuple[str, tuple[Any, ...]]]] = field(
        default_factory=dict
    )

    def url(self, template: str, owner: Side | None = None) -> str:
        """The URL with A's objects (or ``owner``'s) filled in."""
        values = self.ids | (owner or self.a).values()
        return re.sub(r"\{([^{}]+)\}", lambda m: values.get(m[1], MISSING_ID), template)

    def missing_url(self, template: str) -> str:
        """The same URL with a VV (token, webhook) that does not exist (the rest of A's values
        kept)."""
        values = self.ids | self.a.values() | MISSING
        return re.sub(r"\{([^{}]+)\}", lambda m: values[m[1]], template)


def _flight(sim: Any, customer: Customer, prefix: str, program: str) -> Side:
    from vvm_worker.services import vv_submit

    flown = vv_submit(customer=customer, name=f"{prefix}-flown-vv", program=program, vvm=sim.vvm)
    user = UserFactory(username=f"{prefix}-user", customer=customer)
    token, _ = Token.objects.get_or_create(user=user)
    return Side(customer, user, token.key, flown, queued=flown, image="", key="")


def _finish(side: Side, prefix: str, vvm: Any) -> None:
    """After the flights: the customer's queued VV (submitted now, or the simulation would
    start it), the user's named API token, the customer's webhook (made now, or the flights
    would notify it) with an attempt of its own, and what only its data holds."""
    from accounts.services import api_token_create, webhook_create
    from vvm_worker.services import vv_submit
    from vvm_worker.services.messages import message_send

    side.queued = vv_submit(
        customer=side.customer,
        name=f"{prefix}-queued-vv",
        program=f"// {prefix}-program-secret\nvar x = 1;",
        vvm=vvm,
        admit=False,
    )
    side.flown.refresh_from_db()
    side.queued.refresh_from_db()
    assert side.flown.status == VVStatus.FINISHED, side.flown.error
    assert side.queued.status == VVStatus.QUEUED
    camera = StorageDocument.objects.filter(vv=side.flown, key__endswith=".camera").order_by("key")
    side.key = camera[0].key
    side.image = image_file(camera[0].value["image"])
    images = {
        image_file(ref) for t in side.flown.tasks.all() for ref in image_references(t.readings)
    }
    assert side.image in images and Migration.objects.filter(vv=side.flown).exists()
    with transaction.atomic():  # from the customer's own system to its queued VV
        message_send(
            customer_id=side.customer.pk,
            sender=None,
            to=side.queued,
            value_json=json.dumps(f"{prefix}-message-secret"),
            vvm=vvm,
        )
    side.api_token, _ = api_token_create(user=side.user, name=f"{prefix}-token-secret")
    # It hears of every event: the other customer's POSTs (a webhook, an e-mail choice) leave
    # that customer's row (the events it listens for) as it is.
    side.webhook = webhook_create(
        customer=side.customer,
        url=f"http://127.0.0.1:9/{prefix}-hook-secret",
        events=NotifyEvent.values,
        allow_private=True,
    )
    WebhookDelivery.objects.create(
        webhook=side.webhook,
        event=NotifyEvent.VV_FINISHED,
        vv_id=side.flown.pk,
        attempt=1,
        status_code=503,
        error=f"{prefix}-delivery-secret",
    )
    for role in (DEVELOPER, VIEWER):
        member = UserFactory(username=f"{prefix}-{role}", customer=side.customer, role=role)
        Token.objects.create(user=member)
        side.members[role] = member
    _, side.read_only_key = api_token_create(
        user=side.user, name=f"{prefix}-dashboard", role=VIEWER
    )
    side.invite = Invite.objects.create(
        customer=side.customer,
        email=f"{prefix}-invitee-secret@example.com",
        role=VIEWER,
        invited_by=side.user,
        expires=timezone.now() + dt.timedelta(days=7),
    )
    side.markers = (
        side.customer.name,
        *(member.username for member in side.members.values()),
        side.invite.email,
        side.user.username,
        side.flown.name,
        side.queued.name,
        str(side.flown.pk),
        str(side.queued.pk),
        f"{prefix}-program-secret",
        f"{prefix}-storage-secret",
        f"{prefix}-log-secret",
        f"{prefix}-message-secret",
        *sorted(images),
        side.token,  # the key of the token an administrator made (the pages show 6 characters)
        side.api_token.name,
        side.api_token.token_key,  # what the pages and the API show of a named token's key
        f"{prefix}-hook-secret",
        side.webhook.secret,  # never shown again, not even to its customer
        f"{prefix}-delivery-secret",
    )


@pytest.fixture(scope="class")
def world(django_db_setup, django_db_blocker, tmp_path_factory) -> Iterator[World]:
    """Two customers, each with a VV flown in-process to its end and a queued one, a vehicle,
    a ground station and staff: built once for the class in a transaction that is rolled back
    at its end (each test runs in a savepoint inside it, as Django's setUpTestData)."""
    from fleet.simulation import SensorField
    from vvm_worker.clock import SimulatedClock
    from vvm_worker.services import VVM
    from vvm_worker.simulation import Simulation

    media = tmp_path_factory.mktemp("isolation-media")
    fast = ["django.contrib.auth.hashers.MD5PasswordHasher"]
    with (
        django_db_blocker.unblock(),
        transaction.atomic(),
        override_settings(MEDIA_ROOT=media, PASSWORD_HASHERS=fast),
    ):
        station = GroundStationFactory(name="GS Base")
        vehicle = VehicleFactory(name="Heli One")
        sim = Simulation(planner="nearest", seed=1)
        sim.add_vehicle_loop(vehicle)
        waiting = VVM(
            clock=SimulatedClock(), dispatcher=RecordingDispatcher(), field=SensorField(1)
        )
        a = _flight(sim, CustomerFactory(name="Alpha Isolation Ltd"), "alpha", A_FLOWN_PROGRAM)
        b = _flight(sim, CustomerFactory(name="Bravo Isolation Ltd"), "bravo", B_FLOWN_PROGRAM)
        sim.drain()
        _finish(a, "alpha", waiting)
        _finish(b, "bravo", waiting)
        staff = UserFactory(username="isolation-staff", is_staff=True, is_superuser=True)
        world = World(a=a, b=b, staff=staff, media=media)
        for name in (FLEET_MANAGER, PILOT, SUPPORT):
            member = UserFactory(username=f"isolation-{name.replace(' ', '-')}", is_staff=True)
            member.groups.add(Group.objects.get(name=name))
            Token.objects.create(user=member)
            world.groups[name] = member
        vehicle.pilots.add(world.groups[PILOT])
        world.ids = _staff_ids(world, vehicle, station)
        yield world
        transaction.set_rollback(True)


def _staff_ids(world: World, vehicle: Vehicle, station: GroundStation) -> dict[str, str]:
    """The objects the staff routes name: A's where they belong to a customer."""
    from auditlog.models import LogEntry as AuditEntry
    from axes.models import AccessAttempt, AccessFailureLog, AccessLog
    from django.contrib.contenttypes.models import ContentType

    a, vv = world.a, world.a.flown
    gold = ServiceClass.objects.create(name="gold", p95_s=30.0, weight=4.0)
    objects: dict[str, Any] = {
        "accounts.serviceclass": gold,
        "accounts.customer": a.customer,
        "accounts.user": a.user,
        "authtoken.tokenproxy": a.user,  # the token admin looks tokens up by their user
        "auditlog.logentry": AuditEntry.objects.get_for_object(a.customer).first(),
        "accounts.invite": a.invite,
        "accounts.apitoken": a.api_token,
        "accounts.webhook": a.webhook,
        "auth.group": Group.objects.get(name=SUPPORT),
        "missions.message": Message.objects.filter(customer=a.customer).first(),
        "axes.accessattempt": AccessAttempt.objects.create(
            username="someone", ip_address="192.0.2.1", failures_since_start=1
        ),
        "axes.accesslog": AccessLog.objects.create(username="someone", ip_address="192.0.2.1"),
        "axes.accessfailurelog": AccessFailureLog.objects.create(
            username="someone", ip_address="192.0.2.1"
        ),
        "fleet.pilotduty": PilotDuty.objects.create(
            vehicle=vehicle, pilot=world.groups[PILOT], pilot_name="pilot", started=timezone.now()
        ),
        "fleet.flight": Flight.objects.create(
            vehicle=vehicle, started=timezone.now(), started_s=0.0, pilot_name="pilot"
        ),
        "fleet.battery": (battery := Battery.objects.create(name="Pack 1", vehicle=vehicle)),
        "fleet.maintenanceinterval": MaintenanceInterval.objects.create(
            name="25-hour inspection", every_hours=25.0
        ),
        "fleet.maintenancerecord": MaintenanceRecord.objects.create(
            vehicle=vehicle, battery=battery, what="propellers", by_name="fm", at=timezone.now()
        ),
        "fleet.sensortype": SensorType.objects.order_by("pk").first(),
        "fleet.groundstation": station,
        "fleet.vehicle": vehicle,
        "missions.virtualvehicle": vv,
        "missions.task": vv.tasks.order_by("pk").first(),
        "missions.storagedocument": vv.storage.order_by("pk").first(),
        "missions.logentry": vv.log.order_by("pk").first(),
        "missions.migration": vv.migrations.order_by("pk").first(),
    }
    ids = {f"admin:{label}": str(obj.pk) for label, obj in objects.items() if obj is not None}
    return ids | {
        "customer": str(a.customer.pk),
        "customer_type": str(ContentType.objects.get_for_model(Customer).pk),
        "user": str(a.user.pk),
        "uidb64": urlsafe_base64_encode(force_bytes(a.user.pk)),
        "vehicle": str(vehicle.pk),
        "flight": str(objects["fleet.flight"].pk),
        "gs": str(station.pk),
        "service_class": str(gold.pk),
    }


# --- asking -------------------------------------------------------------------------------------


def send(client: Client, method: str, url: str) -> tuple[HttpResponseBase, bytes]:
    """The response and its whole body (files too); unsafe methods carry a body that would act:
    JSON to the API, a form to the pages and the admin."""
    if method in UNSAFE and url.startswith("/api/"):
        response = client.generic(method, url, json.dumps(API_BODY), "application/json")
    elif method in UNSAFE:
        response = client.generic(
            method, url, urlencode(FORM_BODY), "application/x-www-form-urlencoded"
        )
    else:
        response = client.generic(method, url)
    # The test client closes the response itself (a file's once it is read): closing it
    # again would end the request a second time and close the test's database connection.
    body = b"".join(response.streaming_content) if response.streaming else response.content
    return response, body


def leaked(body: bytes, markers: tuple[str, ...], url: str) -> list[str]:
    """The markers in a body, but those the caller put in the URL itself."""
    return [m for m in markers if m.encode() in body and m not in url]


def session_client(user: User) -> Client:
    client = Client()
    client.force_login(user)
    return client


def token_client(side: Side) -> APIClient:
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {side.token}")
    return client


def client_for(side: Side, via: str) -> Client:
    return token_client(side) if via == "token" else session_client(side.user)


def fingerprint(world: World, revoked: Side | None = None) -> dict[str, Any]:
    """What the other customer or a customer's user must not be able to change: A's VVs and
    their data, every customer, A's user and tokens, A's webhooks and their delivery logs, the
    fleet and the SDC. ``revoked``: a caller that revokes its own token (the one an
    administrator made), which is left out.

    Taken thousands of times: each query's SQL is made once per world and caller (the ORM
    makes the same statement each time, at several times the cost of running it)."""
    key = revoked.user.pk if revoked is not None else None
    if key not in world.fingerprint_sql:
        world.fingerprint_sql[key] = {
            name: query.query.sql_with_params()
            for name, query in _fingerprint_queries(world, revoked).items()
        }
    with connection.cursor() as cursor:
        taken: dict[str, Any] = {}
        for name, (sql, params) in world.fingerprint_sql[key].items():
            cursor.execute(sql, params)
            columns = [column[0] for column in cursor.description]
            rows = [dict(zip(columns, row, strict=True)) for row in cursor.fetchall()]
            taken[name] = len(rows) if name in COUNTED else rows
    return taken


# Of these only how many there are (a log is long).
COUNTED = {"log", "groups"}


def _fingerprint_queries(world: World, revoked: Side | None) -> dict[str, QuerySet[Any]]:
    a = world.a
    of_a = {"vv__customer": a.customer}
    tokens = Token.objects.order_by("key")
    if revoked is not None:
        tokens = tokens.exclude(user=revoked.user)
    return {
        "vvs": VirtualVehicle.objects.filter(customer=a.customer)
        .order_by("pk")
        .values("pk", "name", "program", "status", "updated"),
        "tasks": Task.objects.filter(**of_a).order_by("pk").values("pk", "status"),
        "storage": StorageDocument.objects.filter(**of_a).order_by("pk").values(),
        "log": LogEntry.objects.filter(**of_a).values("pk"),
        "customers": Customer.objects.order_by("pk").values(),
        "user": User.objects.filter(pk=a.user.pk).values(),
        "members": User.objects.filter(customer=a.customer)
        .order_by("pk")
        .values("pk", "username", "email", "role", "is_active", "customer_id"),
        "invites": Invite.objects.filter(customer=a.customer).order_by("pk").values(),
        "tokens": tokens.values(),
        "api tokens": ApiToken.objects.filter(user=a.user).order_by("pk").values(),
        "webhooks": Webhook.objects.filter(customer=a.customer).order_by("pk").values(),
        "deliveries": WebhookDelivery.objects.filter(webhook__customer=a.customer)
        .order_by("pk")
        .values(),
        "messages": Message.objects.filter(customer=a.customer).order_by("pk").values(),
        "vehicles": Vehicle.objects.order_by("pk").values(),
        "stations": GroundStation.objects.order_by("pk").values(),
        "sensors": SensorType.objects.order_by("pk").values(),
        "groups": Group.objects.values("pk"),
    }


def is_login_redirect(response: HttpResponseBase, login: str) -> bool:
    return response.status_code == 302 and response["Location"].startswith(f"{login}?next=")


def refused_by_the_admin(response: HttpResponseBase) -> bool:
    """AdminSite.admin_view's answer to anyone but staff: its login page (its index for
    logout)."""
    return is_login_redirect(response, "/admin/login/") or (
        response.status_code == 302 and response["Location"] == "/admin/"
    )


def refused_anonymously(response: HttpResponseBase, url: str) -> bool:
    if url.startswith("/admin/"):
        return refused_by_the_admin(response)
    if url.startswith("/api/"):
        return response.status_code in (401, 403)
    return is_login_redirect(response, django_settings.LOGIN_URL)


def _json(body: bytes, response: HttpResponseBase) -> Any:
    if response.get("Content-Type", "").startswith("application/json") and body:
        return json.loads(body)
    return None


def _cases(kinds: set[Kind], *, methods: str = "declared", vias: bool = False) -> list[Any]:
    """pytest parameters: (route key, url template, method[, via]) with a readable id; GET
    and the declared methods (``methods="get"``: GET, or the one the view acts on)."""
    params = []
    for key, route in ROUTES.items():
        if route.kind not in kinds:
            continue
        url, declared = route.url, route.methods
        if methods == "get":
            chosen = ("GET",) if "GET" in declared else declared[:1]
        else:
            chosen = tuple(dict.fromkeys(("GET", *declared)))
        for method in chosen:
            if vias and url.startswith("/api/"):
                for via in ("token", "session"):
                    params.append(pytest.param(key, url, method, via, id=f"{method} {url} {via}"))
            elif vias:
                params.append(pytest.param(key, url, method, "session", id=f"{method} {url}"))
            else:
                params.append(pytest.param(key, url, method, id=f"{method} {url}"))
    return params


def _object_references() -> list[Any]:
    """Every URL that names a VV: the OBJECT routes and the query strings naming one."""
    params = []
    for key, route in ROUTES.items():
        if route.kind is Kind.OBJECT:
            params.append((key, route.url, route.methods))
        if route.also:
            params.append((key, route.also, route.also_methods))
    return params


def _object_cases() -> list[Any]:
    return [
        pytest.param(key, url, method, via, declared, id=f"{method} {url} {via}")
        for key, url, declared in _object_references()
        for method in METHODS
        for via in (("token", "session") if url.startswith("/api/") else ("session",))
    ]


# --- every pattern is classified ----------------------------------------------------------------


def test_every_url_pattern_is_classified() -> None:
    patterns = list(url_patterns())
    unclassified = sorted(set(patterns) - set(ROUTES))
    assert not unclassified, (
        "URL patterns with no entry in ROUTES of tests/cpcc_site/test_isolation.py: say who "
        f"may use each and how to build its URL: {unclassified}"
    )
    stale = sorted(set(ROUTES) - set(patterns))
    assert not stale, f"ROUTES names patterns the project no longer has: {stale}"
    assert len(patterns) == len(set(patterns)), "two patterns with the same route"


def test_every_classified_url_reaches_its_own_pattern() -> None:
    """Each table URL resolves to the pattern it is filed under: the tests below try the view
    the table says they do."""
    values = {"vv": MISSING_VV, "queued": MISSING_VV, "file": "0" * 32 + ".png", "key": "k"}
    wrong = {}
    for key, route in ROUTES.items():
        for template in filter(None, (route.url, route.also)):
            path = re.sub(r"\{([^{}]+)\}", lambda m: values.get(m[1], "1"), template)
            reached = normalized(resolve(path.split("?")[0]).route)
            if reached != key:
                wrong[template] = reached
    assert not wrong, f"URLs that reach another pattern than theirs: {wrong}"


def test_every_websocket_route_is_classified_and_guarded() -> None:
    routes = list(websocket_routes())
    assert {route: consumer for route, consumer, _ in routes} == WEBSOCKET_ROUTES, (
        "WebSocket routes of cpcc_site/asgi.py and WEBSOCKET_ROUTES differ: classify the new one"
    )
    for route, _, stack in routes:
        # Only pages of this site may open a socket; the user comes from their session.
        assert SameOriginValidator in stack, route
        assert AuthMiddleware in stack, route


# --- HTTP, with both customers' data ------------------------------------------------------------


@pytest.mark.django_db
class TestHttp:
    @pytest.fixture(autouse=True)
    def _world_media(self, settings, world: World) -> None:
        """The pictures the class's flights took (conftest.py gives each test its own
        MEDIA_ROOT), and webhooks on this machine (HOOK_URL: a POST that would add one does)."""
        settings.MEDIA_ROOT = world.media
        settings.CPCC_WEBHOOK_ALLOW_PRIVATE = True

    @pytest.mark.parametrize(("key", "url", "method", "via", "declared"), _object_cases())
    def test_another_customers_object_is_not_found(
        self, world: World, key: str, url: str, method: str, via: str, declared: tuple[str, ...]
    ) -> None:
        """B gets for A's object what it gets for an object that does not exist (404 for the
        methods the view acts on), sees nothing of A and changes nothing; A gets through."""
        theirs = world.url(url)
        b = client_for(world.b, via)
        before = fingerprint(world)
        response, body = send(b, method, theirs)
        assert fingerprint(world) == before, f"B's {method} changed A's data"
        assert not leaked(body, world.a.markers, theirs), body[:500]
        missing, missing_body = send(b, method, world.missing_url(url))
        assert response.status_code == missing.status_code, (
            "A's object and one that does not exist must look the same to B"
        )
        assert _json(body, response) == _json(missing_body, missing)
        if method in declared:
            assert response.status_code == 404
            # The owner gets through: the 404 above is about who asks.
            own, own_body = send(client_for(world.a, via), method, theirs)
            assert own.status_code not in (404, 405), own_body[:300]
            if own.status_code == 200 and (
                _json(own_body, own) is not None or b"<html" in own_body
            ):
                assert leaked(own_body, world.a.markers, ""), "the owner sees its own data"

    @pytest.mark.parametrize(
        ("key", "url", "method"),
        [
            pytest.param(key, url, "GET" if "GET" in declared else declared[0], id=url)
            for key, url, declared in _object_references()
        ],
    )
    @pytest.mark.parametrize("owner", ["a", "b"])
    def test_a_customers_object_shows_only_its_data(
        self, world: World, key: str, url: str, method: str, owner: str
    ) -> None:
        mine, other = (world.a, world.b) if owner == "a" else (world.b, world.a)
        path = world.url(url, mine)
        via = "token" if path.startswith("/api/") else "session"
        response, body = send(client_for(mine, via), method, path)
        assert response.status_code in (200, 302), body[:300]
        assert not is_login_redirect(response, django_settings.LOGIN_URL)
        assert not leaked(body, other.markers, path), body[:500]

    @pytest.mark.parametrize(
        ("key", "url", "method", "via"),
        _cases({Kind.OWN_LIST, Kind.SIGNED_IN}, vias=True),
    )
    def test_lists_and_pages_hold_only_the_callers_data(
        self, world: World, key: str, url: str, method: str, via: str
    ) -> None:
        route = ROUTES[key]
        declared = route.methods
        for mine, other in ((world.a, world.b), (world.b, world.a)):
            revoked = mine if route.revokes_own_token else None
            before = fingerprint(world, revoked)
            response, body = send(client_for(mine, via), method, url)
            if via == "token" and method in route.session_only:
                assert response.status_code == 403, body[:300]
            elif method in declared:
                assert response.status_code < 400, body[:300]
            else:
                assert response.status_code == 405, body[:300]
            assert not leaked(body, other.markers, url), body[:500]
            if mine is world.b:
                assert fingerprint(world, revoked) == before, f"B's {method} changed A's data"
            if route.kind is Kind.OWN_LIST and method == "GET":
                own = mine.listed(route.lists)
                assert own.encode() in body, f"the caller's own {route.lists} are listed"

    @pytest.mark.parametrize(
        ("key", "url", "method"),
        _cases({Kind.SIGNED_IN, Kind.OWN_LIST, Kind.OBJECT, Kind.STAFF}),
    )
    def test_anonymous_requests_are_sent_to_log_in(
        self, world: World, key: str, url: str, method: str
    ) -> None:
        path = world.url(url)
        before = fingerprint(world)
        response, body = send(Client(), method, path)
        assert refused_anonymously(response, path), (response.status_code, body[:300])
        assert not leaked(body, world.a.markers + world.b.markers, ""), body[:500]
        assert fingerprint(world) == before

    @pytest.mark.parametrize(("key", "url", "method"), _cases({Kind.PUBLIC}))
    def test_public_routes_serve_anyone_and_no_customers_data(
        self, world: World, key: str, url: str, method: str
    ) -> None:
        path = world.url(url)
        response, body = send(Client(), method, path)
        route = ROUTES[key]
        if route.public_status is not None and method in ("GET", *route.methods):
            assert response.status_code == route.public_status, body[:300]
        else:
            assert response.status_code < 400 or method not in route.methods, body[:300]
        assert not is_login_redirect(response, django_settings.LOGIN_URL)
        assert not leaked(body, world.a.markers + world.b.markers, ""), body[:500]

    @pytest.mark.parametrize(("key", "url", "method"), _cases({Kind.STAFF}))
    def test_customers_users_are_refused_staff_routes(
        self, world: World, key: str, url: str, method: str
    ) -> None:
        path = world.url(url)
        before = fingerprint(world)
        client = token_client(world.b) if path.startswith("/api/") else session_client(world.b.user)
        response, body = send(client, method, path)
        if path.startswith("/api/"):
            assert response.status_code == 403, body[:300]
        else:
            assert refused_by_the_admin(response), (response.status_code, body[:300])
        assert not leaked(body, world.a.markers, ""), body[:500]
        assert fingerprint(world) == before

    @pytest.mark.parametrize(("key", "url", "method"), _cases({Kind.STAFF}, methods="get"))
    def test_staff_get_in(self, world: World, key: str, url: str, method: str) -> None:
        path = world.url(url)
        response, body = send(session_client(world.staff), method, path)
        route = ROUTES[key]
        expected = route.staff_status
        if route.model and key.endswith(("/add/", "/delete/")):
            # A read-only model admin (the audit log, login attempts) lets no one add or delete.
            model_admin = admin.site._registry[apps.get_model(route.model)]
            request = RequestFactory().get(path)
            request.user = world.staff
            if key.endswith("/add/"):
                allowed = model_admin.has_add_permission(request)
            else:
                allowed = model_admin.has_delete_permission(request)
            expected = None if allowed else 403
        if expected is not None:
            assert response.status_code == expected, body[:300]
        else:
            assert response.status_code in (200, 302), body[:300]
            assert not is_login_redirect(response, "/admin/login/")

    def test_pictures_are_not_served_by_their_path(self, world: World) -> None:
        reference = next(
            ref for t in world.a.flown.tasks.all() for ref in image_references(t.readings)
        )
        assert (world.media / reference).is_file()
        for client in (Client(), session_client(world.b.user), session_client(world.a.user)):
            assert client.get(f"/media/{reference}").status_code == 404

    def test_the_owners_actions_change_what_the_refusals_keep(self, world: World) -> None:
        """The fingerprint sees what a hole would change: the owner's message, cancel, restart
        and edit (the same requests B is refused above) change it."""
        a = session_client(world.a.user)
        # A message to its VV that has not ended, over the API and from its page.
        for client, template in (
            (token_client(world.a), "/api/v1/vvs/{queued}/messages/"),
            (a, "/vvs/{queued}/"),
        ):
            before = fingerprint(world)
            response, _ = send(client, "POST", world.url(template))
            assert response.status_code in (201, 302), template
            assert fingerprint(world)["messages"] != before["messages"], template
        for template in ("/vvs/{queued}/cancel/", "/vvs/{vv}/restart/"):
            before = fingerprint(world)
            response, _ = send(a, "POST", world.url(template))
            assert response.status_code == 302
            assert fingerprint(world) != before, template
        before = fingerprint(world)
        response, _ = send(token_client(world.a), "POST", "/api/v1/vvs/")
        assert response.status_code == 201 and fingerprint(world) != before
        # Its named token, its webhook with its delivery log, its e-mail choice, the token an
        # administrator made for it.
        for template, parts in (
            ("/accounts/tokens/{api_token}/revoke/", ("api tokens",)),
            ("/accounts/webhooks/{webhook}/remove/", ("webhooks", "deliveries")),
            ("/accounts/notifications/", ("user",)),
            ("/accounts/tokens/operator/revoke/", ("tokens",)),
        ):
            before = fingerprint(world)
            response, _ = send(a, "POST", world.url(template))
            assert response.status_code == 302, template
            after = fingerprint(world)
            assert all(after[part] != before[part] for part in parts), template


# --- roles: a customer's members and the staff groups ---------------------------------------------

READ_ONLY_TOKEN = "read-only token"
MEMBER_ACTORS = (OWNER, DEVELOPER, VIEWER, READ_ONLY_TOKEN)


def member_client(world: World, actor: str, via: str) -> Client:
    """A's owner, developer or viewer (by token or session), or A's owner's read-only token."""
    a = world.a
    if actor == READ_ONLY_TOKEN:
        client = APIClient()
        client.credentials(HTTP_AUTHORIZATION=f"Token {a.read_only_key}")
        return client
    user = a.user if actor == OWNER else a.members[actor]
    if via == "session":
        return session_client(user)
    key = a.token if actor == OWNER else Token.objects.get(user=user).key
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {key}")
    return client


def staff_client(world: World, group: str, path: str) -> Client:
    user = world.groups[group]
    if not path.startswith("/api/"):
        return session_client(user)
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {Token.objects.get(user=user).key}")
    return client


def send_undone(client: Client, method: str, url: str) -> tuple[HttpResponseBase, bytes]:
    """``send``, with whatever the request changes rolled back: the next one finds the world
    as it was."""
    with transaction.atomic():
        answer = send(client, method, url)
        transaction.set_rollback(True)
    return answer


def _role_methods(route: Route) -> tuple[str, ...]:
    # A view that answers any method is tried with a read and a change; HEAD is asked as GET
    # (Django and DRF answer it with GET's view and permissions).
    if route.methods == ANY:
        return ("GET", "POST")
    return tuple(m for m in route.methods if m != "HEAD")


def _customer_routes() -> list[Any]:
    return [
        pytest.param(key, id=route.url)
        for key, route in ROUTES.items()
        if route.kind in (Kind.OWN_LIST, Kind.OBJECT, Kind.SIGNED_IN)
    ]


def _staff_routes() -> list[Any]:
    return [
        pytest.param(key, id=route.url) for key, route in ROUTES.items() if route.kind is Kind.STAFF
    ]


def _staff_allows(key: str, route: Route, group: str, method: str) -> bool:
    """What the table says a staff group may do on a staff route."""
    if route.model:
        access = STAFF_MODEL_ACCESS[route.model][group]
        pattern = key.removeprefix(f"admin/{route.model.replace('.', '/')}/")
        needed = ADMIN_VIEW_NEEDS[pattern]
        return all(letter in access for letter in needed)
    assert route.staff is not None
    return method in route.staff[group]


def test_every_staff_route_says_what_each_staff_group_may_do() -> None:
    missing = [
        key
        for key, route in ROUTES.items()
        if route.kind is Kind.STAFF and not route.model and route.staff is None
    ]
    assert not missing, f"STAFF routes with no staff= in ROUTES: {missing}"
    registered = {model._meta.label_lower for model in admin.site._registry}
    assert registered == set(STAFF_MODEL_ACCESS), (
        "models the admin registers and STAFF_MODEL_ACCESS differ: say what each staff group "
        f"may do with {sorted(registered ^ set(STAFF_MODEL_ACCESS))}"
    )


@pytest.mark.django_db
class TestRoles:
    @pytest.fixture(autouse=True)
    def _world_media(self, settings, world: World) -> None:
        settings.MEDIA_ROOT = world.media
        settings.CPCC_WEBHOOK_ALLOW_PRIVATE = True

    @pytest.mark.parametrize("key", _customer_routes())
    def test_each_member_may_do_what_their_role_allows(self, world: World, key: str) -> None:
        """A's owner, developer, viewer and read-only token on A's own objects: allowed where
        the role suffices (never a 403, never a 404 for its own object), else 403 naming the
        role, with nothing changed."""
        route = ROUTES[key]
        path = world.url(route.url)
        # The API asks the role the same way whatever the authentication (the tests above try
        # both): a token here, as scripts use it.
        vias = ("token",) if path.startswith("/api/") else ("session",)
        for method in _role_methods(route):
            needed = route.role_needed(method)
            for actor in MEMBER_ACTORS:
                for via in vias:
                    if actor == READ_ONLY_TOKEN and via == "session":
                        continue
                    role = VIEWER if actor == READ_ONLY_TOKEN else actor
                    # Its own object (an API token is its user's: the owner's here).
                    mine = (
                        route.kind is not Kind.OBJECT
                        or route.needs is not PERSONAL
                        or actor in (OWNER, READ_ONLY_TOKEN)
                    )
                    token_refused = via == "token" and method in route.session_only and mine
                    before = fingerprint(world) if not allows(role, needed) else None
                    response, body = send_undone(member_client(world, actor, via), method, path)
                    case = f"{method} {path} as {actor} by {via}"
                    if token_refused:
                        assert response.status_code == 403, case
                    elif allows(role, needed):
                        assert response.status_code != 403, (case, body[:300])
                        assert not is_login_redirect(response, django_settings.LOGIN_URL), case
                        if route.kind is Kind.OBJECT and mine:
                            assert response.status_code != 404, (case, body[:300])
                    else:
                        assert response.status_code == 403, (case, body[:300])
                        assert f"needs the {needed} role".encode() in body, (case, body[:300])
                        assert fingerprint(world) == before, case

    @pytest.mark.parametrize("key", _customer_routes())
    def test_staff_groups_on_the_customers_routes(self, world: World, key: str) -> None:
        """Fleet managers and support read customers' VVs, pilots see none (404); only fleet
        managers may change one: pilots and support are refused whatever needs a developer
        (403, or 404 for what belongs to a customer and so is no staff user's: a webhook, a
        member), and nothing changes."""
        route = ROUTES[key]
        path = world.url(route.url)
        vv_route = path.startswith(("/api/v1/vvs/", "/vvs/"))
        for method in _role_methods(route):
            refused = route.role_needed(method) == DEVELOPER
            for group in (FLEET_MANAGER, PILOT, SUPPORT):
                client = staff_client(world, group, path)
                refused_here = refused and group != FLEET_MANAGER
                before = fingerprint(world) if refused_here else None
                response, body = send_undone(client, method, path)
                case = f"{method} {path} as {group}"
                if refused_here:
                    hidden = route.kind is Kind.OBJECT and not vv_route
                    assert response.status_code in ((403, 404) if hidden else (403,)), (
                        case,
                        body[:300],
                    )
                    assert fingerprint(world) == before, case
                elif method == "GET" and vv_route and route.kind is Kind.OBJECT:
                    expected = (404,) if group == PILOT else (200, 302)
                    assert response.status_code in expected, (case, body[:300])

    @pytest.mark.parametrize("key", _staff_routes())
    def test_each_staff_group_may_do_what_the_table_says(self, world: World, key: str) -> None:
        route = ROUTES[key]
        path = world.url(route.url)
        methods = ("GET",) if route.model else _role_methods(route)
        for method in methods:
            for group in (FLEET_MANAGER, PILOT, SUPPORT):
                allowed = _staff_allows(key, route, group, method)
                if route.model and key.endswith(("/add/", "/delete/")) and allowed:
                    model_admin = admin.site._registry[apps.get_model(route.model)]
                    request = RequestFactory().get(path)
                    request.user = world.staff
                    allowed = (
                        model_admin.has_add_permission(request)
                        if key.endswith("/add/")
                        else model_admin.has_delete_permission(request)
                    )
                before = None if allowed else fingerprint(world)
                client = staff_client(world, group, path)
                response, body = send_undone(client, method, path)
                case = f"{method} {path} as {group}"
                assert not is_login_redirect(response, "/admin/login/"), case
                if allowed:
                    assert response.status_code != 403, (case, body[:300])
                elif path.startswith("/api/"):
                    assert response.status_code == 403, (case, body[:300])
                else:  # the admin hides a section from those who may see nothing of it
                    assert response.status_code in (403, 404), (case, body[:300])
                if not allowed:
                    assert fingerprint(world) == before, case

    def test_a_pilot_operates_only_the_rvs_they_are_assigned(self, world: World) -> None:
        other = VehicleFactory(name="Heli Elsewhere")
        pilot = staff_client(world, PILOT, "/api/")
        for act in ("maintenance", "return-home", "land", "return", "take-duty"):
            response, body = send_undone(pilot, "POST", f"/api/v1/vehicles/{other.pk}/{act}/")
            assert response.status_code in (403, 409), (act, body[:300])
            assert b"not one of Heli Elsewhere's pilots" in body, (act, body[:300])
        response, body = send_undone(
            pilot, "POST", f"/api/v1/vehicles/{world.ids['vehicle']}/land/"
        )
        assert response.status_code == 200, body[:300]


# --- the live map's socket ----------------------------------------------------------------------

PROGRAM = """
var co2 = VV.sensor.get('CO2');
VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                 tolerance: 2, sensors: [co2]});
"""


@pytest.fixture
async def _close_socket_connections():
    """The sockets read the database in a worker thread: close its connection after each test,
    or PostgreSQL refuses to drop the test database at the end of the run."""
    yield
    from channels.db import database_sync_to_async
    from django.db import connections

    await database_sync_to_async(connections.close_all)()


@pytest.fixture
def feed(broker):
    """The test run's Redis carries the feed; empty before and after each test."""
    broker.delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)
    yield broker
    broker.delete(EVENTS_STREAM, POSITIONS_STREAM, VEHICLES_HASH)


def _socket(client: Client, path: str = "/ws/map/", origin: bytes = b"http://testserver") -> Any:
    headers = [(b"host", b"testserver"), (b"origin", origin)]
    cookie = client.cookies.get("sessionid")
    if cookie is not None:
        headers.append((b"cookie", f"sessionid={cookie.value}".encode()))
    return WebsocketCommunicator(application, path, headers=headers)


def _state(vehicle: Vehicle, vvs: list[VirtualVehicle], t: float) -> dict[str, Any]:
    return {
        "id": vehicle.pk,
        "name": vehicle.name,
        "lat": 48.1105,
        "lng": 12.8605,
        "alt": 40.0,
        "phase": "cruise",
        "status": "active",
        "battery": None,
        "vvs": [{"id": str(vv.pk), "name": vv.name, "customer": vv.customer_id} for vv in vvs],
        "route": [[48.1111, 12.8619]],
        "t": t,
    }


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
@pytest.mark.usefixtures("_close_socket_connections", "feed")
class TestMapSocket:
    async def test_an_anonymous_socket_is_refused(self, client, mission) -> None:
        for path in ("/ws/map/", f"/ws/map/?vv={mission.pk}"):
            connected, code = await _socket(client, path).connect()
            assert not connected and code == 4403, path

    async def test_a_socket_from_another_site_is_refused(self, client, user_b) -> None:
        from asgiref.sync import sync_to_async

        await sync_to_async(client.force_login)(user_b)
        for origin in (
            b"http://evil.example",
            b"https://testserver.evil.example",
            b"null",
            b"http://testserver:9999",  # another program on the same host
            b"https://testserver",  # the other scheme
        ):
            connected, _ = await _socket(client, origin=origin).connect()
            assert not connected, origin
        socket = _socket(client)  # the same user from the site's own page is let in
        assert (await socket.connect())[0]
        await socket.disconnect()

    async def test_another_customers_vv_cannot_be_followed(self, client, user_b, mission) -> None:
        from asgiref.sync import sync_to_async

        await sync_to_async(client.force_login)(user_b)
        connected, code = await _socket(client, f"/ws/map/?vv={mission.pk}").connect()
        assert not connected and code == 4404

    async def test_a_customer_receives_nothing_of_another_customers_vvs(
        self, client, mission, customer_a, customer_b, user_b, vvm_factory, feed
    ) -> None:
        """B's map while A's flown VV is in the database, A's queued VV is cancelled and a
        vehicle carries A's VV (alone, then with B's): B sees its own VV and a nameless
        carrier with only its VV aboard, nothing of A."""
        import time

        from asgiref.sync import sync_to_async

        from vvm_worker.live import FeedAnnouncer, publish_vehicle
        from vvm_worker.services import vv_cancel, vv_submit

        vvm = vvm_factory()
        vvm.announcer = FeedAnnouncer()
        theirs = await sync_to_async(vv_submit)(
            customer=customer_a, name="alpha-live-vv", program=PROGRAM, vvm=vvm
        )
        mine = await sync_to_async(vv_submit)(
            customer=customer_b, name="bravo-live-vv", program=PROGRAM, vvm=vvm
        )
        alone = await sync_to_async(VehicleFactory)(name="Heli Two")
        shared = await sync_to_async(Vehicle.objects.get)(name="Heli One")
        a_markers = [str(mission.pk), mission.name, str(theirs.pk), theirs.name, "Heli", "GS Base"]

        await sync_to_async(client.force_login)(user_b)
        socket = _socket(client)
        assert (await socket.connect())[0]
        snapshot = await socket.receive_json_from(timeout=5)
        assert snapshot["type"] == "snapshot"
        assert [vv["vv"] for vv in snapshot["vvs"]] == [str(mine.pk)]
        assert not [m for m in a_markers if m in json.dumps(snapshot)]

        now = time.time()
        publish_vehicle(_state(alone, [mission, theirs], now))
        publish_vehicle(_state(shared, [theirs, mine], now))
        await sync_to_async(vv_cancel)(vv_id=theirs.pk, vvm=vvm)
        await sync_to_async(vv_cancel)(vv_id=mine.pk, vvm=vvm)  # the last thing announced
        frames = []
        while not any(
            e.get("vv") == str(mine.pk) and e.get("status") == "cancelled"
            for f in frames
            for e in f.get("events", ())
        ):
            frames.append(await socket.receive_json_from(timeout=5))
        await socket.send_json_to({"type": "resync"})
        while frames[-1]["type"] != "snapshot":
            frames.append(await socket.receive_json_from(timeout=5))
        await socket.disconnect()

        announced = b"".join(fields[b"e"] for _, fields in feed.xrange(EVENTS_STREAM))
        assert str(theirs.pk).encode() in announced, "A's cancellation went through the feed"
        seen = json.dumps(frames)
        assert not [m for m in a_markers if m in seen], seen[:1000]
        assert {e["vv"] for f in frames for e in f.get("events", ())} == {str(mine.pk)}
        carriers = [v for f in frames for v in f.get("vehicles", ())]
        assert carriers, "the vehicle carrying B's VV is shown to B"
        for carrier in carriers:
            assert carrier["id"] not in (alone.pk, shared.pk) and "route" not in carrier
            assert carrier["vvs"] == [
                {"id": str(mine.pk), "name": "bravo-live-vv", "customer": customer_b.pk}
            ]
        assert [vv["vv"] for vv in frames[-1]["vvs"]] == [str(mine.pk)]
