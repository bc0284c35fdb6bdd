"""Keeping the API's token cache (accounts/authentication.py) honest: a token deleted or
rotated, a user changed or deleted, a customer changed or deleted is forgotten at once in this
process, and again once the change commits (a request that read the old state meanwhile may
have put it back)."""

from __future__ import annotations

from typing import Any

from django.db import transaction
from django.db.models.signals import post_delete, post_save
from django.dispatch import receiver
from rest_framework.authtoken.models import Token, TokenProxy

from accounts.authentication import TOKENS, token_digest
from accounts.models import ApiToken, Customer, User


def _forget(**which: Any) -> None:
    TOKENS.forget(**which)
    transaction.on_commit(lambda: TOKENS.forget(**which), robust=True)


@receiver(post_save, sender=Token)
@receiver(post_delete, sender=Token)
@receiver(post_save, sender=TokenProxy)
@receiver(post_delete, sender=TokenProxy)
def token_changed(sender: Any, instance: Token, **kwargs: Any) -> None:
    # A user has one token: forgetting the user's entries also drops a rotated token's.
    _forget(digest=token_digest(instance.key or ""), user_id=instance.user_id)


@receiver(post_save, sender=ApiToken)
@receiver(post_delete, sender=ApiToken)
def api_token_changed(sender: Any, instance: ApiToken, **kwargs: Any) -> None:
    # A named token is cached under its digest (the key itself is not known here).
    _forget(digest=instance.digest)


@receiver(post_save, sender=User)
@receiver(post_delete, sender=User)
def user_changed(sender: Any, instance: User, **kwargs: Any) -> None:
    _forget(user_id=instance.pk)


@receiver(post_save, sender=Customer)
@receiver(post_delete, sender=Customer)
def customer_changed(sender: Any, instance: Customer, **kwargs: Any) -> None:
    _forget(customer_id=instance.pk)
