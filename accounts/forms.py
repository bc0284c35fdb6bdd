"""The Account pages' forms: a new API token, a new webhook, the e-mails a user wants. The
services check what matters (accounts/services.py); these only read the fields."""

from __future__ import annotations

from django import forms

from accounts.models import NotifyEvent


class ApiTokenForm(forms.Form):
    """A new API token: its name."""

    name = forms.CharField(
        max_length=100,
        strip=True,
        label="Name",
        help_text="Where you will use it, e.g. “laptop” or “CI”.",
        widget=forms.TextInput(attrs={"placeholder": "laptop", "autocomplete": "off"}),
    )


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
