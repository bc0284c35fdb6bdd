"""``cpcc``: submit VV programs to a CPCC platform, watch them and fetch their results.

Environment: ``CPCC_URL`` (default http://127.0.0.1:8000) and ``CPCC_TOKEN``, your API token.
Make a token on the platform's Account page (``/accounts/tokens/``) and either set
``CPCC_TOKEN`` or run ``cpcc login``, which asks for it and keeps it for that address
(cpcc_client/credentials.py); ``CPCC_TOKEN`` wins when both are there.

``cpcc submit`` with several programs sends them in one request (``POST /api/v1/vvs/`` with a
list): all of them are queued, or none.

``cpcc submit --dry-run`` submits nothing: each program runs against a simulated copy of the
fleet, which says what it would do (every task, those no vehicle could serve, how long, which
quota would stop it).

``cpcc members`` lists the people of your customer with their roles (owner, developer,
viewer); an owner invites someone by e-mail (``members invite``), changes a member's role
(``members role``) and removes a member (``members remove``). A refused action prints the
platform's sentence naming the role it needs.

Exit codes: 0 success (``submit --wait``: every VV finished; ``--dry-run``: each would finish
within its quotas with every task served); 1 the server refused the request, could not be
reached, a VV ended otherwise than finished, or a dry run found a task no vehicle could serve
(or that it would not finish); 2 a usage or set-up problem, or
programs with syntax errors (each printed as ``FILE:LINE:COLUMN: message``); 3 ``--wait`` gave
up after ``--timeout`` seconds.
"""

from __future__ import annotations

import argparse
import getpass
import json
import os
import sys
import tempfile
import time
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from cpcc_client.client import ApiError, Client, Unreachable
from cpcc_client.credentials import credentials_path, forget_token, store_token, stored_token

DEFAULT_URL = "http://127.0.0.1:8000"
ENDED = ("finished", "failed", "killed", "cancelled")
VVS = "/api/v1/vvs/"

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_TIMEOUT = 3

# How --wait waits between two polls; a module attribute so that tests can step time.
_sleep: Callable[[float], None] = time.sleep


class UsageError(Exception):
    """A problem with the command line or the environment (exit code 2)."""


def _out(*parts: object) -> None:
    print(*parts, file=sys.stdout)


def _err(*parts: object) -> None:
    print(*parts, file=sys.stderr)


def _vv_path(vv_id: str, rest: str = "") -> str:
    return f"{VVS}{vv_id.strip()}/{rest}"


# --- commands ---------------------------------------------------------------------------------


def cmd_submit(client: Client, args: argparse.Namespace) -> int:
    sources = [Path(program) for program in args.program]
    if args.name is not None and len(sources) > 1:
        raise UsageError("--name names one VV: give one program, or leave --name out")
    items = [{"name": args.name or source.stem, "program": _read(source)} for source in sources]
    if args.dry_run:
        return _dry_runs(client, args, items)
    if len(items) == 1:
        return _submit_one(client, args, items[0])
    # Several programs: one request, one transaction on the server (all of them or none).
    try:
        vvs = client.call("POST", VVS, data=items)
    except ApiError as exc:
        errors = exc.body.get("errors") if isinstance(exc.body, dict) else None
        if exc.status == 400 and isinstance(errors, list) and len(errors) == len(items):
            return _refused(args.program, errors)
        raise
    for vv in vvs:
        _out(vv["id"])
    if not args.wait:
        return EXIT_OK
    return _wait_all(client, vvs, args.program, timeout_s=args.timeout, poll_s=args.poll)


def _read(source: Path) -> str:
    try:
        return source.read_text(encoding="utf-8")
    except OSError as exc:
        raise UsageError(f"cannot read {source}: {exc.strerror or exc}") from None


def _submit_one(client: Client, args: argparse.Namespace, item: dict[str, str]) -> int:
    try:
        vv = client.call("POST", VVS, data=item)
    except ApiError as exc:
        location = _syntax_error(args.program[0], exc.body) if exc.status == 400 else None
        if location is not None:
            _err(location)
            return EXIT_USAGE
        raise
    _out(vv["id"])
    if not args.wait:
        return EXIT_OK
    return _wait(client, vv, timeout_s=args.timeout, poll_s=args.poll)


def _syntax_error(program: str, body: Any) -> str | None:
    """``FILE:LINE:COLUMN: message`` for a refusal that says where a program's error is."""
    error = body.get("error") if isinstance(body, dict) else None
    if isinstance(error, dict) and "line" in error:
        return f"{program}:{error['line']}:{error['column']}: {error['message']}"
    return None


def _refused(programs: Sequence[str], errors: list[Any]) -> int:
    """Each refused program of a bulk submission (nothing was submitted): exit 2 when they
    all have syntax errors, as for one program; 1 when another problem is among them."""
    other = False
    for program, error in zip(programs, errors, strict=True):
        if not error:
            continue
        location = _syntax_error(program, error)
        if location is None:
            other = True
            detail = error.get("detail") if isinstance(error, dict) else error
            location = f"{program}: {detail}"
        _err(location)
    _err("cpcc: nothing was submitted")
    return EXIT_ERROR if other else EXIT_USAGE


def _wait(client: Client, vv: dict[str, Any], *, timeout_s: float | None, poll_s: float) -> int:
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    while vv["status"] not in ENDED:
        if deadline is not None and time.monotonic() >= deadline:
            _out(vv["status"])
            _err(f"gave up waiting after {timeout_s:g} s: the VV is still {vv['status']}")
            return EXIT_TIMEOUT
        _sleep(poll_s)
        vv = client.call("GET", _vv_path(vv["id"]))
    _out(vv["status"])
    if vv["status"] != "finished":
        if vv.get("error"):
            _err(vv["error"])
        return EXIT_ERROR
    return EXIT_OK


def _wait_all(
    client: Client,
    vvs: list[dict[str, Any]],
    programs: Sequence[str],
    *,
    timeout_s: float | None,
    poll_s: float,
) -> int:
    """Wait until every VV has ended; print ``ID STATUS`` for each, in order."""
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    while any(vv["status"] not in ENDED for vv in vvs):
        if deadline is not None and time.monotonic() >= deadline:
            for vv in vvs:
                _out(f"{vv['id']} {vv['status']}")
            waiting = sum(vv["status"] not in ENDED for vv in vvs)
            _err(f"gave up waiting after {timeout_s:g} s: {waiting} VV(s) have not ended")
            return EXIT_TIMEOUT
        _sleep(poll_s)
        vvs = [
            vv if vv["status"] in ENDED else client.call("GET", _vv_path(vv["id"])) for vv in vvs
        ]
    code = EXIT_OK
    for vv, program in zip(vvs, programs, strict=True):
        _out(f"{vv['id']} {vv['status']}")
        if vv["status"] != "finished":
            code = EXIT_ERROR
            if vv.get("error"):
                _err(f"{program}: {vv['error']}")
    return code


def cmd_status(client: Client, args: argparse.Namespace) -> int:
    vv = client.call("GET", _vv_path(args.id))
    if args.json:
        _out(json.dumps(vv, indent=2))
        return EXIT_OK
    rows = [
        ("id", vv["id"]),
        ("name", vv["name"]),
        ("status", vv["status"]),
        ("host", vv.get("host") or "-"),
        ("tasks", f"{vv['tasks_done']} done, {vv['tasks_open']} open"),
        ("created", vv.get("created") or "-"),
        ("finished", vv.get("finished") or "-"),
    ]
    waiting = vv.get("waiting")
    if waiting:  # what it waits for, in the platform's words ("flying to your task, about 40 s")
        rows.append(("waiting", waiting["message"]))
    if vv.get("error"):
        where = ""
        if vv.get("error_line"):
            where = f" (line {vv['error_line']}, column {vv.get('error_column')})"
        rows.append(("error", vv["error"] + where))
    for label, value in rows:
        _out(f"{label:<9} {value}")
    return EXIT_OK


def cmd_list(client: Client, args: argparse.Namespace) -> int:
    query = {"status": args.status} if args.status else None
    vvs = list(client.pages(VVS, query=query))
    if args.json:
        _out(json.dumps(vvs, indent=2))
        return EXIT_OK
    if not vvs:
        _out("no VVs" + (f" with status {args.status}" if args.status else ""))
        return EXIT_OK
    _out(f"{'ID':<36}  {'STATUS':<9}  {'DONE':>5}  {'OPEN':>5}  {'CREATED':<20}  NAME")
    for vv in vvs:
        created = (vv.get("created") or "")[:19].replace("T", " ")
        _out(
            f"{vv['id']:<36}  {vv['status']:<9}  {vv['tasks_done']:>5}  "
            f"{vv['tasks_open']:>5}  {created:<20}  {vv['name']}"
        )
    return EXIT_OK


def cmd_log(client: Client, args: argparse.Namespace) -> int:
    for line in client.pages(_vv_path(args.id, "log/")):
        _out(f"{line['at']} {line['level']:<7} {line['message']}")
    return EXIT_OK


def cmd_cancel(client: Client, args: argparse.Namespace) -> int:
    vv = client.call("POST", _vv_path(args.id, "cancel/"))
    _out(f"{vv['id']} {vv['status']}")
    return EXIT_OK


def cmd_results(client: Client, args: argparse.Namespace) -> int:
    path = _vv_path(args.id, "results.zip")
    if args.extract:
        target = Path(args.extract)
        with tempfile.TemporaryFile() as archive:
            client.download(path, archive)
            archive.seek(0)
            count = _extract(archive, target)
        _out(f"{count} files in {target}")
        return EXIT_OK
    if args.output:
        destination = Path(args.output)
        with _writing(destination) as out:
            client.download(path, out)
    else:
        with tempfile.NamedTemporaryFile(dir=".", suffix=".part", delete=False) as out:
            try:
                suggested = client.download(path, out)
            except BaseException:
                out.close()
                Path(out.name).unlink(missing_ok=True)
                raise
        destination = Path(suggested or f"{args.id.strip()}-results.zip")
        Path(out.name).replace(destination)
    _out(destination)
    return EXIT_OK


class _writing:
    """Write a file under a temporary name and put it in place only once it is complete."""

    def __init__(self, destination: Path) -> None:
        self.destination = destination
        self.partial = destination.with_name(destination.name + ".part")

    def __enter__(self) -> Any:
        try:
            self.handle = self.partial.open("wb")
        except OSError as exc:
            raise UsageError(f"cannot write {self.destination}: {exc.strerror or exc}") from None
        return self.handle

    def __exit__(self, kind: object, error: object, trace: object) -> None:
        self.handle.close()
        if error is None:
            self.partial.replace(self.destination)
        else:
            self.partial.unlink(missing_ok=True)


def _extract(archive: Any, target: Path) -> int:
    """Unpack a results zip into ``target``, refusing members that would land outside it."""
    target.mkdir(parents=True, exist_ok=True)
    root = target.resolve()
    with zipfile.ZipFile(archive) as zipped:
        members = zipped.infolist()
        for member in members:
            where = (root / member.filename).resolve()
            if not where.is_relative_to(root):
                raise UsageError(f"refusing to extract {member.filename!r} outside {target}")
        zipped.extractall(root)
    return sum(1 for m in members if not m.is_dir())


# --- logging in with a token made on the Account page -----------------------------------------

TOKENS = "/api/v1/tokens/"


def _tokens_page(url: str) -> str:
    return f"{url.rstrip('/')}/accounts/tokens/"


def _login_token(url: str, args: argparse.Namespace) -> str:
    """The token to log in with: asked for, unechoed, on a terminal; otherwise (a pipe, a file,
    ``--token-stdin``) the first line of standard input, or CPCC_TOKEN when that is empty.
    getpass is not used without a terminal: it would warn (GetPassWarning) and echo."""
    if args.token_stdin or sys.stdin is None or not sys.stdin.isatty():
        piped = sys.stdin.readline().strip() if sys.stdin is not None else ""
        return piped or os.environ.get("CPCC_TOKEN", "").strip()
    _err(f"Make a token on {_tokens_page(url)} and paste it here.")
    return getpass.getpass("API token: ").strip()


def cmd_login(url: str, args: argparse.Namespace) -> int:
    """Check a token against the platform and keep it for this address."""
    token = _login_token(url, args)
    if not token:
        raise UsageError("no token given: paste it, pipe it in, or set CPCC_TOKEN")
    client = Client(url, token)
    try:
        mine = list(client.pages(TOKENS))
    except ApiError as exc:
        if exc.status == 401:
            raise UsageError(
                f"{url} does not accept that token ({exc.describe()}): copy it again from "
                f"{_tokens_page(url)}, or make a new one there"
            ) from None
        raise
    path = store_token(url, token)
    named = [t for t in mine if t.get("prefix") and token.startswith(str(t["prefix"]))]
    which = f" with the token {named[0]['name']!r}" if len(named) == 1 else ""
    _out(f"Logged in to {url}{which}; the token is kept in {path}")
    return EXIT_OK


def cmd_logout(url: str, args: argparse.Namespace) -> int:
    """Forget the token kept for this address (it keeps working until revoked)."""
    if forget_token(url):
        _out(
            f"Forgot the token for {url}. It still works until you revoke it on "
            f"{_tokens_page(url)}."
        )
    else:
        _out(f"No token kept for {url} (in {credentials_path()}).")
    return EXIT_OK


# --- members: the people of your customer and their roles -------------------------------------

MEMBERS = "/api/v1/members/"
INVITES = "/api/v1/invites/"
# The roles of a customer's members (the platform's accounts.roles), least allowed first.
ROLES = ("viewer", "developer", "owner")


def cmd_members(client: Client, args: argparse.Namespace) -> int:
    """List your customer's members: user name, e-mail address, role."""
    members = list(client.pages(MEMBERS))
    if args.json:
        _out(json.dumps(members, indent=2))
        return EXIT_OK
    if not members:
        _out("no members (only a customer's users have them)")
        return EXIT_OK
    width = max(len("USER"), *(len(m["username"]) for m in members))
    mail = max(len("E-MAIL"), *(len(m.get("email") or "-") for m in members))
    _out(f"{'USER':<{width}}  {'E-MAIL':<{mail}}  ROLE")
    for member in members:
        email = member.get("email") or "-"
        _out(f"{member['username']:<{width}}  {email:<{mail}}  {member['role']}")
    return EXIT_OK


def cmd_members_invite(client: Client, args: argparse.Namespace) -> int:
    invite = client.call("POST", INVITES, data={"email": args.email, "role": args.role})
    expires = (invite.get("expires") or "")[:16].replace("T", " ")
    _out(
        f"Invited {invite['email']} as {invite['role']}: the link in the e-mail works once"
        + (f", until {expires} UTC" if expires else "")
        + "."
    )
    return EXIT_OK


def cmd_members_role(client: Client, args: argparse.Namespace) -> int:
    member = _member(client, args.user)
    changed = client.call("PATCH", f"{MEMBERS}{member['id']}/", data={"role": args.role})
    _out(f"{changed['username']} is now {changed['role']}.")
    return EXIT_OK


def cmd_members_remove(client: Client, args: argparse.Namespace) -> int:
    member = _member(client, args.user)
    client.call("DELETE", f"{MEMBERS}{member['id']}/")
    _out(
        f"Removed {member['username']}: they can no longer log in, and their API tokens no "
        "longer work."
    )
    return EXIT_OK


class NoSuchMember(Exception):
    """The name given is none of the customer's members (exit code 1)."""


def _member(client: Client, user: str) -> dict[str, Any]:
    """The member a command names, by user name (or, failing that, by e-mail address)."""
    members: list[dict[str, Any]] = list(client.pages(MEMBERS))
    wanted = user.strip()
    folded = wanted.casefold()
    for matches in (
        [m for m in members if m["username"] == wanted],
        [m for m in members if m["username"].casefold() == folded],
        [m for m in members if (m.get("email") or "").casefold() == folded],
    ):
        if len(matches) == 1:
            return matches[0]
    names = ", ".join(m["username"] for m in members) or "none"
    raise NoSuchMember(f"no member {wanted!r} in your customer (its members: {names})")


# --- submit --dry-run: a program tried against a simulated copy of the fleet ------------------

DRY_RUN = "/api/v1/vvs/dry-run/"
# A dry run computes for up to 20 s on the server, after starting a process of its own.
DRY_RUN_TIMEOUT_S = 120.0


def _dry_runs(client: Client, args: argparse.Namespace, items: list[dict[str, str]]) -> int:
    """``submit --dry-run``: each program's dry run, one after the other; nothing is submitted.
    Exit 0 when each would finish within its quotas with every task served; 1 otherwise; 2
    for a syntax error (``FILE:LINE:COLUMN: message``, as a submission)."""
    if args.wait:
        raise UsageError("--dry-run submits nothing to wait for: leave --wait out")
    code = EXIT_OK
    for program, item in zip(args.program, items, strict=True):
        try:
            report = client.call("POST", DRY_RUN, data=item, timeout_s=DRY_RUN_TIMEOUT_S)
        except ApiError as exc:
            location = _syntax_error(program, exc.body) if exc.status == 400 else None
            if location is None:
                raise
            _err(location)
            code = max(code, EXIT_USAGE)
            continue
        if not _print_dry_run(program, report):
            code = max(code, EXIT_ERROR)
    return code


def _print_dry_run(program: str, report: dict[str, Any]) -> bool:
    """The report on stdout, each task no vehicle could serve on stderr as
    ``FILE:LINE:COLUMN: message``; True when the VV would finish within its quotas with every
    task served."""
    tasks, unservable = report["tasks"], report["unservable"]
    _out(f"{program}: dry run of {report['name']!r} (nothing was submitted)")
    _out(f"  {len(tasks)} task(s), {len(unservable)} that no vehicle in service could serve")
    for number, task in enumerate(tasks, 1):
        lat, lng, alt = task["position"]
        where = f"line {task['line']}, column {task['column']}" if task["line"] else "-"
        if not task["servable"]:
            outcome = "NOT SERVABLE"
        elif task["done_s"] is not None and task["status"] == "done":
            outcome = f"read at {_duration(task['done_s'])}"
        else:
            outcome = task["status"]
        _out(
            f"  {number:>4}  ({lat:.6f}, {lng:.6f}, {alt:g} m)  {', '.join(task['sensors'])}"
            f"  [{where}]  {outcome}"
        )
    for task in unservable:
        _err(f"{program}:{task['line'] or 1}:{task['column'] or 1}: {task['message']}")
    ending = report["status"]
    if report.get("error"):  # its place is in it: "... (line 4, column 9)"
        ending += f": {report['error']}"
    waits = report.get("message_wait_s") or 0
    unless = f" (not counting up to {_duration(waits)} of waiting for messages)" if waits else ""
    _out(f"  ends: {ending}, after about {_duration(report['duration_s'])}{unless}")
    if report.get("assumes"):
        _out(f"  assumes: {report['assumes']}")
    quota = report.get("quota")
    if quota is None:
        _out("  quotas: within your quotas")
    else:
        place = f" at line {quota['line']}, column {quota['column']}" if quota["line"] else ""
        _out(f"  quotas: stopped{place} after {quota['tasks_before']} task(s): {quota['message']}")
    return report["status"] == "finished" and not unservable and quota is None


def _duration(seconds: float) -> str:
    minutes, rest = divmod(round(seconds), 60)
    return f"{minutes} min {rest} s" if minutes else f"{seconds:.1f} s"


# --- the command line -------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """The ``cpcc`` command line."""
    parser = argparse.ArgumentParser(
        prog="cpcc",
        description="Submit virtual vehicles (VV programs) to a CPCC platform, watch them and "
        "download their results.",
        epilog=f"Environment: CPCC_URL (default {DEFAULT_URL}) and CPCC_TOKEN (your API token; "
        "or run `cpcc login` once).",
    )
    parser.add_argument("--url", help="the platform's address (default: $CPCC_URL)")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    submit = commands.add_parser(
        "submit",
        help="submit VV programs, print their ids",
        description="Submit one VV per program and print their ids, one a line. Several "
        "programs go in one request: all of them are queued, or none (each refused one is "
        "printed).",
    )
    submit.add_argument(
        "program", metavar="PROG.js", nargs="+", help="the programs (JavaScript), one VV each"
    )
    submit.add_argument("--name", help="the VV's name, with one program (default: the file name)")
    submit.add_argument(
        "--wait",
        action="store_true",
        help="wait until they end, print their status (with several: ID STATUS a line)",
    )
    submit.add_argument(
        "--timeout", type=float, default=None, metavar="S", help="stop waiting after S seconds"
    )
    submit.add_argument(
        "--poll", type=float, default=2.0, metavar="S", help="seconds between polls (2)"
    )
    submit.add_argument(
        "--dry-run",
        action="store_true",
        help="submit nothing: try each program against a simulated copy of the fleet and print "
        "what it would do (exit 1 when a task could not be served or it would not finish)",
    )
    submit.set_defaults(handler=cmd_submit)

    status = commands.add_parser("status", help="show one VV")
    status.add_argument("id")
    status.add_argument("--json", action="store_true", help="print the API's JSON")
    status.set_defaults(handler=cmd_status)

    listing = commands.add_parser("list", help="list your VVs")
    listing.add_argument(
        "--status", choices=["queued", "running", "migrating", *ENDED], help="only these"
    )
    listing.add_argument("--json", action="store_true", help="print the API's JSON")
    listing.set_defaults(handler=cmd_list)

    log = commands.add_parser("log", help="print a VV's log")
    log.add_argument("id")
    log.set_defaults(handler=cmd_log)

    cancel = commands.add_parser("cancel", help="cancel a VV")
    cancel.add_argument("id")
    cancel.set_defaults(handler=cmd_cancel)

    results = commands.add_parser("results", help="download a VV's results (a zip)")
    results.add_argument("id")
    where = results.add_mutually_exclusive_group()
    where.add_argument("-o", "--output", metavar="FILE.zip", help="where to save the zip")
    where.add_argument("--extract", metavar="DIR", help="unpack the zip into DIR instead")
    results.set_defaults(handler=cmd_results)

    login = commands.add_parser(
        "login",
        help="keep an API token for this platform",
        description="Ask for an API token (make one on the platform's Account page, "
        "/accounts/tokens/), check it, and keep it for this address, readable by you only. "
        "Without a terminal (echo TOKEN | cpcc login) the token is the first line of standard "
        "input, or CPCC_TOKEN when that is empty. CPCC_TOKEN, when set, is used instead of "
        "the kept token.",
    )
    login.add_argument(
        "--token-stdin",
        action="store_true",
        help="read the token from standard input even on a terminal",
    )
    login.set_defaults(handler=cmd_login)
    logout = commands.add_parser("logout", help="forget the token kept for this platform")
    logout.set_defaults(handler=cmd_logout)

    members = commands.add_parser(
        "members",
        help="list your customer's members and their roles; owners invite, change, remove",
        description="Without an action: list the people of your customer (user name, e-mail, "
        "role). Roles: viewer (read only), developer (also submit, edit and cancel VVs, "
        "webhooks), owner (also the members). Inviting, changing a role and removing a member "
        "need the owner role; a refused action prints what it needs and exits 1.",
    )
    members.add_argument("--json", action="store_true", help="print the API's JSON")
    members.set_defaults(handler=cmd_members)
    actions = members.add_subparsers(dest="members_action", metavar="[ACTION]")
    invite = actions.add_parser(
        "invite",
        help="invite someone by e-mail (owners)",
        description="Send an invitation to EMAIL: a link that works once and expires; they "
        "choose a user name and password and join your customer with ROLE.",
    )
    invite.add_argument("email", metavar="EMAIL")
    invite.add_argument("--role", required=True, choices=ROLES, help="their role once they join")
    invite.set_defaults(handler=cmd_members_invite)
    role = actions.add_parser(
        "role",
        help="change a member's role (owners)",
        description="Give the member USER (a user name, or their e-mail address) ROLE. The "
        "last owner stays owner; their tokens carry at most the new role.",
    )
    role.add_argument("user", metavar="USER")
    role.add_argument("role", metavar="ROLE", choices=ROLES, help=", ".join(ROLES))
    role.set_defaults(handler=cmd_members_role)
    remove = actions.add_parser(
        "remove",
        help="remove a member (owners): their tokens stop working",
        description="Remove the member USER (a user name, or their e-mail address): they can "
        "no longer log in and their API tokens stop working. The last owner cannot be removed.",
    )
    remove.add_argument("user", metavar="USER")
    remove.set_defaults(handler=cmd_members_remove)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one ``cpcc`` command; returns the exit code."""
    args = build_parser().parse_args(argv)
    url = args.url or os.environ.get("CPCC_URL") or DEFAULT_URL
    try:
        if args.command in ("login", "logout"):
            return int(args.handler(url, args))
        token = os.environ.get("CPCC_TOKEN", "").strip() or stored_token(url)
        if not token:
            raise UsageError(
                f"run `cpcc login` with a token made on {_tokens_page(url)}, "
                "or set CPCC_TOKEN to your API token"
            )
        if args.command == "submit" and args.poll <= 0:
            raise UsageError("--poll must be more than 0 seconds")
        return int(args.handler(Client(url, token), args))
    except UsageError as exc:
        _err(f"cpcc: {exc}")
        return EXIT_USAGE
    except NoSuchMember as exc:
        _err(f"cpcc: {exc}")
        return EXIT_ERROR
    except ApiError as exc:
        _err(f"cpcc: {exc.describe()}")
        return EXIT_ERROR
    except Unreachable as exc:
        _err(f"cpcc: {exc}")
        return EXIT_ERROR
    except KeyboardInterrupt:
        _err("cpcc: interrupted")
        return 130
