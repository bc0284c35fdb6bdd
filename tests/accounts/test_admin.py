"""Customers' API tokens and webhooks in the admin: staff see them and may delete one (a token
revoked at once, a webhook no longer listened for), never add one or see a key or secret."""

from __future__ import annotations

import pytest
from django.urls import reverse
from rest_framework.test import APIClient

from accounts.models import ApiToken, Customer, Webhook
from accounts.services import api_token_create, webhook_create

pytestmark = pytest.mark.django_db


@pytest.mark.parametrize("model", ["apitoken", "webhook"])
def test_the_lists_load_and_offer_no_add(client, staff, user_a, model) -> None:
    token, _ = api_token_create(user=user_a, name="laptop")
    webhook = webhook_create(
        customer=user_a.customer,
        url="http://127.0.0.1:9/h",
        events=["vv.failed"],
        allow_private=True,
    )
    client.force_login(staff)
    changelist = client.get(reverse(f"admin:accounts_{model}_changelist"))
    assert changelist.status_code == 200
    add = reverse(f"admin:accounts_{model}_add")
    assert client.get(add).status_code == 403 and f'href="{add}"' not in changelist.text
    shown = client.get(
        reverse(
            f"admin:accounts_{model}_change", args=[(token if model == "apitoken" else webhook).pk]
        )
    )
    assert shown.status_code == 200
    assert webhook.secret not in shown.text and token.digest not in shown.text


def test_deleting_in_the_admin_revokes_and_unlistens(client, staff, user_a, settings) -> None:
    settings.CPCC_TOKEN_CACHE_S = 10.0
    token, key = api_token_create(user=user_a, name="laptop")
    webhook = webhook_create(
        customer=user_a.customer,
        url="http://127.0.0.1:9/h",
        events=["vv.failed"],
        allow_private=True,
    )
    api = APIClient()
    api.credentials(HTTP_AUTHORIZATION=f"Token {key}")
    assert api.get("/api/v1/vvs/").status_code == 200
    client.force_login(staff)
    for model, obj in (("apitoken", token), ("webhook", webhook)):
        url = reverse(f"admin:accounts_{model}_delete", args=[obj.pk])
        assert client.post(url, {"post": "yes"}).status_code == 302
    assert not ApiToken.objects.exists() and not Webhook.objects.exists()
    assert api.get("/api/v1/vvs/").status_code == 401
    assert Customer.objects.get(pk=user_a.customer_id).notify_events == []
