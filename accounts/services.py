"""The accounts' services: every state change of a user's own (their API tokens, made and
revoked on the Account page and at ``/api/v1/tokens/``), one keyword-only function each.

A token is django-rest-knox's (accounts.ApiToken): the key is shown once, when it is made; only
its digest and its first characters are kept. Revoking one deletes it, which forgets it at once
in this process's token cache (accounts/signals.py) and within ``CPCC_TOKEN_CACHE_S`` in the
others. The single token per user that ``manage.py drf_create_token`` makes (DRF's) keeps
working beside them, and its owner may revoke it too.
"""

from __future__ import annotations

from django.core.exceptions import ValidationError
from django.db import IntegrityError, transaction

from accounts.models import ApiToken, User
from accounts.selectors import legacy_token_for_user
from cpcc_site.names import plain_name_problem

# More would be forgotten rather than used; revoking one makes room.
MAX_TOKENS_PER_USER = 100
NAME_MAX_CHARS = ApiToken._meta.get_field("name").max_length or 100


def api_token_create(*, user: User, name: str) -> tuple[ApiToken, str]:
    """Make a named token for the user: returns it and its key, which is never shown again.

    Raises ValidationError on ``name`` for a blank name, one over 100 characters, one with a
    control or bidirectional formatting character, or one the user already gave a token (code
    ``unique``); and when the user already has MAX_TOKENS_PER_USER tokens.
    """
    name = name.strip()
    problem = _name_problem(name)
    if problem is not None:
        raise ValidationError({"name": problem})
    with transaction.atomic():
        # The user's row first: two requests at once cannot both take the last place.
        User.objects.select_for_update().filter(pk=user.pk).exists()
        if ApiToken.objects.filter(user=user).count() >= MAX_TOKENS_PER_USER:
            raise ValidationError(
                f"You have {MAX_TOKENS_PER_USER} API tokens, the most one may have: revoke one "
                "you no longer use first."
            )
        if ApiToken.objects.filter(user=user, name=name).exists():
            raise ValidationError({"name": _taken(name)})
        try:
            with transaction.atomic():
                token, key = ApiToken.objects.create(user=user, expiry=None, name=name)
        except IntegrityError:  # made meanwhile by another request of the same user
            raise ValidationError({"name": _taken(name)}) from None
    return token, key


def _name_problem(name: str) -> str | None:
    if not name:
        return 'Give the token a name, e.g. where it is used ("laptop", "CI").'
    if len(name) > NAME_MAX_CHARS:
        return f"A token's name has at most {NAME_MAX_CHARS} characters ({len(name)} given)."
    return plain_name_problem(name)


def _taken(name: str) -> ValidationError:
    return ValidationError(
        f"You already have a token named {name!r}: choose another name, or revoke that one.",
        code="unique",
    )


def api_token_revoke(*, token: ApiToken) -> None:
    """Revoke a token (one the caller selected for its owner): it is refused from now on."""
    token.delete()


def legacy_token_revoke(*, user: User) -> bool:
    """Revoke the token an administrator made for the user with ``drf_create_token``; False
    when the user has none."""
    token = legacy_token_for_user(user=user)
    if token is None:
        return False
    token.delete()
    return True
