"""The Account pages' forms: a new API token, a new webhook, the e-mails a user wants, an
invitation and a member's role. The services check what matters (accounts/services.py); these
only read the fields."""

from __future__ import annotations

from typing import Any

from django import forms

from accounts.models import ROLE_CHOICES, NotifyEvent
from accounts.roles import CUSTOMER_ROLES, ROLE_LABELS, VIEWER


class ApiTokenForm(forms.Form):
    """A new API token: its name, and the role it acts with: its user's (as that changes), or
    one narrower than theirs (a read-only token for a dashboard)."""

    name = forms.CharField(
        max_length=100,
        strip=True,
        label="Name",
        help_text="Where you will use it, e.g. “laptop” or “CI”.",
        widget=forms.TextInput(attrs={"placeholder": "laptop", "autocomplete": "off"}),
    )
    role = forms.ChoiceField(required=False, label="May do")

    def __init__(self, *args: Any, user_role: str | None = None, **kwargs: Any) -> None:
        """``user_role``: the role of the user making it (None: staff, whose tokens carry
        none)."""
        super().__init__(*args, **kwargs)
        field: forms.ChoiceField = self.fields["role"]  # type: ignore[assignment]
        if user_role is None:
            field.choices = [("", "What you may")]
            return
        narrower = CUSTOMER_ROLES[: CUSTOMER_ROLES.index(user_role)]
        field.choices = [("", f"What you may (now {user_role})")] + [
            (role, ROLE_LABELS[role]) for role in reversed(narrower)
        ]

    @property
    def offers_roles(self) -> bool:
        """Whether there is a role to choose (a viewer's tokens, like staff's, carry theirs)."""
        return len(self.fields["role"].choices) > 1  # type: ignore[attr-defined]


class WebhookForm(forms.Form):
    """A new webhook: where to POST, and on which events."""

    url = forms.CharField(
        max_length=2000,
        strip=True,
        label="URL",
        widget=forms.URLInput(attrs={"placeholder": "https://example.com/cpcc-hook"}),
    )
    events = forms.MultipleChoiceField(
        choices=NotifyEvent.choices,
        initial=[NotifyEvent.VV_FINISHED, NotifyEvent.VV_FAILED],
        widget=forms.CheckboxSelectMultiple,
        label="Events",
        error_messages={"required": "Choose at least one event."},
    )


class EmailEventsForm(forms.Form):
    """The address a user's e-mails go to, and the events it wants e-mailed."""

    email = forms.CharField(
        max_length=254,
        required=False,
        strip=True,
        label="Address",
        widget=forms.EmailInput(attrs={"placeholder": "you@example.com"}),
    )
    email_events = forms.MultipleChoiceField(
        choices=NotifyEvent.choices,
        required=False,
        widget=forms.CheckboxSelectMultiple,
        label="E-mail me when",
    )


class InviteAcceptForm(forms.Form):
    """The invitee's new account: a user name and a password."""

    username = forms.CharField(
        max_length=150,
        strip=True,
        label="User name",
        widget=forms.TextInput(attrs={"autocomplete": "username", "autofocus": True}),
    )
    password = forms.CharField(
        label="Password",
        strip=False,
        widget=forms.PasswordInput(attrs={"autocomplete": "new-password"}),
    )


class InviteForm(forms.Form):
    """An owner's invitation: the address it goes to, and the role the invitee gets."""

    email = forms.CharField(
        max_length=254,
        strip=True,
        label="E-mail",
        widget=forms.EmailInput(attrs={"placeholder": "colleague@example.com"}),
    )
    role = forms.ChoiceField(choices=ROLE_CHOICES, initial=VIEWER, label="Role")


class MemberRoleForm(forms.Form):
    """A member's new role."""

    role = forms.ChoiceField(choices=[(role, role) for role in CUSTOMER_ROLES], label="Role")
