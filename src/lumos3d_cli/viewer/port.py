"""Whether the viewer can listen where it is asked to: checked before a server starts, and by
`restore --view` before the restore runs (no viser or torch imported here)."""

from __future__ import annotations

import errno
import socket

from lumos3d_cli.errors import InputError


def port_in_use(host: str, port: int) -> InputError:
    """The refusal of a `port` something else already listens on."""
    return InputError(f"{port}: already in use on {host}; pick another port (0 picks a free one)", parameter="port")


def require_free_port(host: str, port: int) -> None:
    """InputError naming the port when something already listens there (viser itself would
    silently move to the next port, and the printed URL would lie)."""
    if not 0 <= port <= 65535:
        raise InputError(f"{port}: use a port between 1 and 65535 (0 picks a free one)", parameter="port")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as error:
        raise InputError(f"{host}: not an address of this machine ({error.strerror}); use 127.0.0.1 or 0.0.0.0",
                         parameter="host") from error
    family, _, _, _, address = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        # The same option the server sets: a port left in TIME_WAIT by a stopped viewer is free.
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as error:
            if error.errno == errno.EADDRINUSE:
                raise port_in_use(host, port) from error
            if error.errno == errno.EADDRNOTAVAIL:
                raise InputError(f"{host}: not an address of this machine ({error.strerror}); use 127.0.0.1 or 0.0.0.0",
                                 parameter="host") from error
            raise InputError(f"{port}: cannot listen there on {host} ({error.strerror})", parameter="port") from error
