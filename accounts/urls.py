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
    path("members/", views.members, name="account-members"),
    path("members/<int:member_id>/role/", views.member_role, name="account-member-role"),
    path("members/<int:member_id>/remove/", views.member_remove_view, name="account-member-remove"),
    path(
        "invites/<int:invite_id>/withdraw/",
        views.invite_withdraw_view,
        name="account-invite-withdraw",
    ),
    # An invitation's link (signed, used once): public, it makes the invitee's account.
    path("invite/<str:signed>/", views.invite_accept, name="account-invite"),
    path("webhooks/new/", views.webhook_new, name="account-webhook-new"),
    path("webhooks/<int:webhook_id>/", views.webhook_detail, name="account-webhook"),
    path("webhooks/<int:webhook_id>/remove/", views.webhook_remove, name="account-webhook-remove"),
]
