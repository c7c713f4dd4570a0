"""Whether the service listens beyond this machine, and the one warning when it does with no API keys.

The app does not know the address it is served on (``reglib serve --host``, ``uvicorn --host``, a
gunicorn bind or an inherited socket), and the server binds only after the app's start-up. So
:func:`watch_exposure`, started by the lifespan, waits for this process's listening TCP sockets to
appear (read from Linux's ``/proc``; elsewhere nothing is found and nothing is said) and, when one
of them is not a loopback address (``0.0.0.0`` included) and no ``REGLIB_API_KEYS_FILE`` is set,
logs one warning.
"""
from __future__ import annotations

import asyncio
import ipaddress
import logging
import os

__all__ = ["listening_addresses", "watch_exposure", "EXPOSED_WARNING"]

log = logging.getLogger("service")

EXPOSED_WARNING = ("the service listens on %s, beyond this machine, and has no API keys: anyone who can reach it "
                   "may use it. Set REGLIB_API_KEYS_FILE (a file of keys, one a line), or bind 127.0.0.1")

_WAIT_S = 30.0
_STEP_S = 0.1


def _address(hex_addr: str) -> str:
    raw = bytes.fromhex(hex_addr)
    # /proc/net/tcp* print each 32-bit word in host order (little-endian here)
    raw = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
    return str(ipaddress.ip_address(raw))


def listening_addresses() -> list[str]:
    """The local addresses of the TCP sockets this process listens on (empty where ``/proc`` is absent)."""
    inodes = set()
    try:
        fds = os.listdir("/proc/self/fd")
    except OSError:
        return []
    for fd in fds:
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            with open(table, encoding="ascii") as f:
                rows = f.read().splitlines()[1:]
        except OSError:
            continue
        for row in rows:
            fields = row.split()
            if len(fields) > 9 and fields[3] == "0A" and fields[9] in inodes:  # 0A: LISTEN
                found.append(_address(fields[1].split(":")[0]))
    return found


def _exposed(addresses: list[str]) -> list[str]:
    out = []
    for address in addresses:
        ip = ipaddress.ip_address(address)
        mapped = getattr(ip, "ipv4_mapped", None)
        if not (mapped or ip).is_loopback:
            out.append(address)
    return sorted(set(out))


async def watch_exposure(has_keys: bool) -> None:
    """Wait (up to 30 s) for the server's listening sockets; warn once if one is beyond loopback without keys."""
    if has_keys:
        return
    loop = asyncio.get_running_loop()
    deadline = loop.time() + _WAIT_S
    while loop.time() < deadline:
        addresses = listening_addresses()
        if addresses:
            exposed = _exposed(addresses)
            if exposed:
                log.warning(EXPOSED_WARNING, ", ".join(exposed))
            return
        await asyncio.sleep(_STEP_S)
