"""A MAVLink link (pymavlink) for ``watch`` and ``fake-vehicle``: opening it from a URL, the
dialect, and the unit conversions both ends share.

A link URL is what pymavlink's ``mavlink_connection`` takes: ``udp:HOST:PORT`` or
``udpin:HOST:PORT`` (listen), ``udpout:HOST:PORT`` (send to), ``tcp:HOST:PORT`` (connect),
``tcpin:HOST:PORT`` (listen), or a serial device path with an optional ``,BAUD``. Anything
else is refused in one line before a socket is opened.

MAVLink 2 and the ``ardupilotmega`` dialect (a superset of ``common``: it adds ArduPilot's
``WIND``) are chosen through pymavlink's own switches (``MAVLINK20`` and ``set_dialect``).
Positions travel in WGS84 and the map frame is reached through the map's ``origin`` with the
exact conversion of ``export.autopilot`` (``enu_to_geodetic`` / ``latlon_to_xy``).
"""

from __future__ import annotations

import os
from pathlib import Path

from orange_plan.errors import InputError

DIALECT = "ardupilotmega"
"""ArduPilot's dialect: every ``common`` message plus ``WIND``."""
UINT16_UNKNOWN = 65535
"""A uint16 battery field (voltage [mV]) the vehicle does not know."""
INT_UNKNOWN = -1
"""A signed battery field (current [cA], remaining [%]) the vehicle does not know."""
NETWORK_SCHEMES = ("udp", "udpin", "udpout", "udpbcast", "tcp", "tcpin")
MAX_SERIAL_BAUD = 10_000_000
"""Fastest serial baud rate taken [bit/s]: beyond any UART a telemetry radio uses."""


def mavlink_module():
    """pymavlink's ``mavutil`` with MAVLink 2 and the ``ardupilotmega`` dialect."""
    os.environ["MAVLINK20"] = "1"  # read by set_dialect: MAVLink 2 framing
    from pymavlink import mavutil

    mavutil.set_dialect(DIALECT)
    return mavutil


def check_url(url: str) -> str:
    """``url`` if pymavlink can open it as a link, else InputError (one line).

    Parameters
    ----------
    url : ``SCHEME:HOST:PORT`` (module docstring) or a serial device ``PATH[,BAUD]``
    """
    text = str(url).strip()
    scheme, _, rest = text.partition(":")
    if scheme in NETWORK_SCHEMES:
        host, _, port = rest.rpartition(":")
        if not host or not port.isdigit() or not 0 < int(port) <= 65535:
            raise InputError(f"--connect {url!r}: a network link is {scheme}:HOST:PORT with a "
                             "port in 1-65535 (e.g. udp:127.0.0.1:14550)")
        return text
    device, _, baud = text.partition(",")
    if baud and not (baud.isdigit() and 0 < int(baud) <= MAX_SERIAL_BAUD):
        raise InputError(f"--connect {url!r}: the baud rate after ',' must be a whole number "
                         f"in 1-{MAX_SERIAL_BAUD}")
    if device.startswith(("/dev/", "COM")) and (device.startswith("COM")
                                                  or Path(device).exists()):
        return text
    raise InputError(f"--connect {url!r} is not a link: give udp:HOST:PORT, udpin:, udpout:, "
                     "tcp:, tcpin: or an existing serial device (e.g. /dev/ttyUSB0,57600)")


def open_link(url: str, system_id: int, component_id: int):
    """A pymavlink connection for ``url`` (``check_url``) speaking as (system, component).

    Raises
    ------
    InputError
        A URL that is not a link, or one the system refuses (address in use, unknown host,
        no such device), in one line.
    """
    mavutil = mavlink_module()
    text = check_url(url)
    device, _, baud = text.partition(",")
    kwargs = {"source_system": system_id, "source_component": component_id}
    if baud and text.split(":", 1)[0] not in NETWORK_SCHEMES:
        kwargs["baud"] = int(baud)
        text = device
    try:
        return mavutil.mavlink_connection(text, **kwargs)
    except (OSError, ValueError) as exc:
        raise InputError(f"--connect {url!r}: cannot open the link ({exc})") from None


def text_bytes(text: str, size: int) -> bytes:
    """``text`` as ASCII for a fixed-size MAVLink char field (cut to ``size`` bytes)."""
    return str(text).encode("ascii", "replace")[:size]


def degE7(deg: float) -> int:
    """Degrees as the MAVLink integer [1e-7 deg]."""
    return round(float(deg) * 1e7)


def send_mission_item(mav, target: tuple[int, int], seq: int, item) -> None:
    """MISSION_ITEM_INT for an ``export.autopilot.MissionItem`` (latitude/longitude in
    params 5 and 6 of a waypoint or take-off, as integers of 1e-7 degree)."""
    p = item.params
    placed = item.command in (16, 22)  # NAV_WAYPOINT, NAV_TAKEOFF
    mav.mission_item_int_send(target[0], target[1], seq, item.frame, item.command,
                              int(seq == 0), 1, p[0], p[1], p[2], p[3],
                              degE7(p[4]) if placed else 0, degE7(p[5]) if placed else 0,
                              p[6], 0)


def item_from_message(msg):
    """An ``export.autopilot.MissionItem`` from a MISSION_ITEM_INT message."""
    from orange_plan.export.autopilot import MissionItem

    return MissionItem(msg.command, msg.frame, (msg.param1, msg.param2, msg.param3,
                                                msg.param4, msg.x / 1e7, msg.y / 1e7, msg.z))
