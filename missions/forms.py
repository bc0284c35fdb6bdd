"""The program editor's form: a name, the program (typed, pasted or loaded from a .js file) and,
for a new VV, how many copies to submit at once."""

from __future__ import annotations

from typing import Any

from django import forms
from django.core.files.uploadedfile import UploadedFile

from missions.models import PROGRAM_MAX_CHARS, PROGRAM_TOO_LONG, VirtualVehicle, validate_vv_name
from vvm_worker.services import MAX_COPIES

NAME_MAX = VirtualVehicle._meta.get_field("name").max_length or 120


class ProgramForm(forms.Form):
    """A VV's name and program; a ``.js`` file is read when the program box is left empty (the
    page's script loads a chosen file into the editor instead)."""

    name = forms.CharField(max_length=NAME_MAX, strip=True, validators=[validate_vv_name])
    program = forms.CharField(
        required=False,
        strip=False,
        max_length=PROGRAM_MAX_CHARS,
        error_messages={"max_length": PROGRAM_TOO_LONG},
        widget=forms.Textarea(attrs={"rows": 24, "spellcheck": "false", "class": "program"}),
    )
    program_file = forms.FileField(
        required=False,
        label="or load a .js file",
        widget=forms.ClearableFileInput(attrs={"accept": ".js,.mjs,text/javascript"}),
    )

    def clean_program_file(self) -> str | None:
        upload: UploadedFile | None = self.cleaned_data.get("program_file")
        if not upload:
            return None
        if upload.size is not None and upload.size > PROGRAM_MAX_CHARS:
            raise forms.ValidationError("The file is larger than a program may be (1 MB).")
        try:
            return upload.read().decode("utf-8-sig")
        except UnicodeDecodeError:
            raise forms.ValidationError("The file is not UTF-8 text.") from None

    def clean(self) -> dict[str, Any]:
        data = super().clean()
        if not (data.get("program") or "").strip() and data.get("program_file"):
            data["program"] = data["program_file"]
        if data.get("program"):
            # Browsers send a text box with CRLF line ends; a program is kept as written, with
            # LF, the same whether it came from the page, a file or the REST API.
            data["program"] = data["program"].replace("\r\n", "\n")
        if not (data.get("program") or "").strip() and "program" not in self.errors:
            self.add_error("program", "Write a program, paste one, or load a .js file.")
        return data


class NewProgramForm(ProgramForm):
    """A new VV: also how many copies of it to submit (named "name", "name (2)", ...)."""

    copies = forms.IntegerField(min_value=1, max_value=MAX_COPIES, initial=1)

    field_order = ["name", "copies", "program", "program_file"]

    def clean(self) -> dict[str, Any]:
        data = super().clean()
        name, copies = data.get("name"), data.get("copies")
        if name and copies and copies > 1 and len(f"{name} ({copies})") > NAME_MAX:
            longest = NAME_MAX - len(f" ({copies})")
            self.add_error("name", f"With {copies} copies a name has {longest} characters at most.")
        return data
