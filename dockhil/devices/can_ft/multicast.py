"""CAN frames over python-can's udp_multicast, kept on this host's loopback and to the bus's own group.

python-can's udp_multicast joins its group on the interface the routing table gives it (on a lab PC
the LAN's) and binds the port on every address, and Linux then hands such a socket the datagrams of
every group any socket on the host has joined on that port (IP_MULTICAST_ALL): two graphs on two
groups would read each other's frames. `on_loopback` turns an open bus's socket to its own group
only, joined and sent on loopback (127.0.0.1), so the frames never leave the host. Only the socket's
public file descriptor is used, never python-can's internals.

A group python-can cannot join (no route for it: a host without a network, or a multicast route
missing) is refused in one line, `join_failure`, saying what to do.
"""

from __future__ import annotations

import errno
import os
import socket
import struct
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import can

LOOPBACK = "127.0.0.1"
IP_MULTICAST_ALL = getattr(socket, "IP_MULTICAST_ALL", 49)  # Linux; Python 3.11's socket lacks the name


def on_loopback(bus: can.BusABC, group: str) -> None:
    """Restrict an open udp_multicast `bus` on IPv4 `group` to that group on loopback (OSError if refused)."""
    sock = socket.socket(fileno=os.dup(bus.fileno()))  # the same socket: options set here are the bus's
    try:
        sock.setsockopt(socket.IPPROTO_IP, IP_MULTICAST_ALL, 0)
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(LOOPBACK))
        joined = socket.inet_aton(group)
        try:  # python-can's membership, on the routed interface
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_DROP_MEMBERSHIP, joined + struct.pack("@I", 0))
        except OSError as exc:
            if exc.errno != errno.EADDRNOTAVAIL:  # routed to loopback already: kept below
                raise
        try:
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, joined + socket.inet_aton(LOOPBACK))
        except OSError as exc:
            if exc.errno != errno.EADDRINUSE:  # already a member on loopback
                raise
    finally:
        sock.close()


def join_failure(device: str, group: str, exc: BaseException) -> str:
    """The one line for a group that cannot be joined."""
    cause = exc.__cause__ or exc
    why = getattr(cause, "strerror", None) or str(cause) or type(cause).__name__
    return (
        f"{device}: cannot join multicast group {group} on loopback ({why}): this host has no route for it; "
        f"add one (sudo ip route add 239.74.0.0/16 dev lo), or launch with can_interface:=pty "
        f"(an emulated slcan adapter on a pseudo-terminal)"
    )


def check_params(node: str, values: dict) -> None:
    """Refuse (ParamError, one line) a node's udp_multicast channel on loopback that is not an IPv4 group."""
    from dockhil.errors import ParamError

    if values["interface"] == "udp_multicast" and values["loopback"]:
        why = check_group(values["channel"])
        if why:
            raise ParamError(
                f"node {node!r} parameter 'channel': {why}; give a group such as 239.74.1.2 "
                f"(hil.yaml with emulators:=true and can_interface:=auto draws one per graph)"
            )


def check_group(group: str) -> str | None:
    """Why `group` is not an IPv4 multicast address (one clause), or None."""
    try:
        first = socket.inet_aton(group)[0]
    except OSError:
        return f"{group!r} is not an IPv4 address"
    if group.count(".") != 3 or not 224 <= first <= 239:
        return f"{group!r} is not an IPv4 multicast group (224.0.0.0 to 239.255.255.255)"
    return None
