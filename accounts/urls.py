"""The Account pages (under /accounts/, beside Django's login and password pages)."""

from django.urls import path

from accounts import views

urlpatterns = [
    path("tokens/", views.tokens, name="account-tokens"),
    path("tokens/<int:token_id>/revoke/", views.token_revoke, name="account-token-revoke"),
    path(
        "tokens/operator/revoke/",
        views.legacy_token_revoke_view,
        name="account-legacy-token-revoke",
    ),
    path("notifications/", views.notifications, name="account-notifications"),
    path("webhooks/new/", views.webhook_new, name="account-webhook-new"),
    path("webhooks/<int:webhook_id>/", views.webhook_detail, name="account-webhook"),
    path("webhooks/<int:webhook_id>/remove/", views.webhook_remove, name="account-webhook-remove"),
]
