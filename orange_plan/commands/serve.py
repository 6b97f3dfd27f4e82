"""``orange-plan serve``: the mid-mission replanning HTTP API and the operator page."""

from __future__ import annotations

import errno
import ipaddress
import os
import socket
from pathlib import Path
from typing import Annotated

import typer

from orange_plan.cli import app, handles_errors
from orange_plan.errors import InputError
from orange_plan.files import require_folder


@app.command("serve")
@handles_errors
def serve_cmd(
    host: Annotated[str, typer.Option(help="Address to bind; a non-loopback address needs "
                                           "ORANGE_PLAN_TOKEN set.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(min=0, max=65535, help="TCP port.")] = 8000,
    db: Annotated[Path, typer.Option(
        help="SQLite file holding missions and their acknowledged telemetry.")] = Path(
        "orange_plan.sqlite"),
    scenarios: Annotated[Path | None, typer.Option(
        help="Folder of scenarios a mission may name (default: ./scenarios, else the "
             "installed examples).")] = None,
    maps: Annotated[Path | None, typer.Option(
        help="Folder of maps a scenario may name (default: ./maps, else the installed "
             "examples).")] = None,
    max_body_bytes: Annotated[int, typer.Option(
        min=1024, help="Largest request body accepted [bytes]; larger ones get 413.")]
        = 8 * 1024 * 1024,
) -> None:
    """Serve the replanning API (docs at /docs, OpenAPI at /openapi.json) and the operator
    page (/). Missions and every acknowledged telemetry batch live in --db; a restart replays
    them. With ORANGE_PLAN_TOKEN set, every /missions... request needs that bearer token."""
    import uvicorn

    from orange_plan.files import check_output
    from orange_plan.service.app import TOKEN_ENV, create_app
    from orange_plan.service.limits import Limits

    token = os.environ.get(TOKEN_ENV)
    check_bind(host, token)
    for folder, what in ((scenarios, "--scenarios"), (maps, "--maps")):
        if folder is not None:
            require_folder(folder, what)
    check_output(db, "--db")
    check_port_free(host, port)
    for folder, kind in ((scenarios, "scenarios"), (maps, "maps")):
        _say_where(folder, kind)
    service = create_app(db, token=token, scenarios_dir=scenarios, maps_dir=maps,
                         limits=Limits(max_body_bytes=max_body_bytes))
    uvicorn.run(service, host=host, port=port, log_level="info",
                h11_max_incomplete_event_size=64 * 1024)


def check_port_free(host: str, port: int) -> None:
    """Bind ``host:port`` once and let go, so a port in use (or an address this machine does
    not have) is one line here instead of the server's multi-line start-up failure.

    The test socket sets SO_REUSEADDR as the server's own does: a port only lingering in
    TIME_WAIT after a previous run is free for both.

    Raises
    ------
    InputError
        The host does not resolve, or binding any of its addresses fails.
    """
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except (OSError, UnicodeError) as exc:
        raise InputError(f"--host {host}: cannot resolve it ({exc})") from None
    for family, kind, proto, _, address in infos:
        with socket.socket(family, kind, proto) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                probe.bind(address)
            except OSError as exc:
                busy = exc.errno == errno.EADDRINUSE
                raise InputError(
                    f"--port {port}: already in use on {host} (another server runs there; "
                    "pick another --port)" if busy else
                    f"--host {host} --port {port}: cannot bind ({exc.strerror or exc})") from None


def _say_where(folder: Path | None, kind: str) -> None:
    """Tell the operator which folder names resolve in (or where none was found)."""
    from orange_plan.cli import err
    from orange_plan.examples import find_dir, looked_in

    folder = folder or find_dir(kind)
    err.print(f"{kind}: {folder}" if folder is not None else
              f"{kind}: none found (looked in {looked_in(kind)}); missions must send their "
              f"scenario as TOML text, or give --{kind} DIR", markup=False)


def is_loopback(host: str) -> bool:
    """True when every address ``host`` names is a loopback address."""
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        pass
    try:
        infos = socket.getaddrinfo(host, None)
    except OSError:
        return False
    return bool(infos) and all(ipaddress.ip_address(i[4][0].split("%")[0]).is_loopback
                               for i in infos)


def check_bind(host: str, token: str | None) -> None:
    """Refuse a non-loopback address without a token (anyone on the network could drive the
    robot's plan).

    Raises
    ------
    InputError
        Non-loopback ``host`` and no token.
    """
    if not is_loopback(host) and not (token and token.strip()):
        raise InputError(f"--host {host} is reachable from other machines: set "
                         "ORANGE_PLAN_TOKEN to a secret token first (clients then send "
                         "'Authorization: Bearer <token>'), or bind 127.0.0.1")
