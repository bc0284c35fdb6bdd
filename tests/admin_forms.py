"""Posting an admin add or change form back as a browser would (tests/test_admin.py,
tests/accounts/)."""

from __future__ import annotations

from typing import Any

from django.forms import BaseForm


def _fields(form: BaseForm) -> dict[str, Any]:
    data: dict[str, Any] = {}
    for name in form.fields:
        value = form[name].value()
        if value is None or value is False:
            continue  # an empty field, an unticked box: not posted
        data[form.add_prefix(name)] = "on" if value is True else value
    return data


def form_as_shown(response: Any) -> dict[str, Any]:
    """What a browser posts back from the admin page ``response`` when nobody changes a
    thing: every field as shown (a size in the unit it is shown in, the ticked boxes), and each
    inline's management form and rows."""
    data = _fields(response.context["adminform"].form)
    for inline in response.context["inline_admin_formsets"]:
        formset = inline.formset
        data |= _fields(formset.management_form)
        for form in formset.forms:
            data |= _fields(form)
    return data
