"""What sockets a process has open, from the kernel's own tables: /proc/<pid>/net/{tcp,tcp6,
udp,udp6} joined with the socket inodes in /proc/<pid>/fd. Nothing is connected to: the tables
are the proof of where a process listens."""

from __future__ import annotations

import ipaddress
import os
import socket
from dataclasses import dataclass

TCP_LISTEN = 0x0A
"""The ``st`` column of a listening TCP socket (include/net/tcp_states.h)."""
TCP_ESTABLISHED = 0x01


@dataclass(frozen=True)
class Sock:
    """One socket of a process: protocol (``tcp``, ``tcp6``, ``udp``, ``udp6``), local and
    remote address and port, and the kernel's state number."""

    proto: str
    local: str
    port: int
    remote: str
    remote_port: int
    state: int

    @property
    def listening(self) -> bool:
        """A TCP socket in LISTEN, or any UDP socket (bound: it receives from anyone)."""
        return self.proto.startswith("udp") or self.state == TCP_LISTEN

    @property
    def loopback(self) -> bool:
        """Whether the local address is on loopback (127.0.0.0/8, ::1, ::ffff:127.x)."""
        addr = ipaddress.ip_address(self.local)
        if isinstance(addr, ipaddress.IPv6Address) and addr.ipv4_mapped is not None:
            addr = addr.ipv4_mapped
        return addr.is_loopback

    def __str__(self) -> str:
        return f"{self.proto} {self.local}:{self.port} (state {self.state:#x})"


def _address(field: str) -> tuple[str, int]:
    """``0100007F:1F90`` (the kernel's hex, 32-bit words in host order) as address and port."""
    hex_ip, hex_port = field.split(":")
    raw = bytes.fromhex(hex_ip)
    words = b"".join(raw[i : i + 4][::-1] for i in range(0, len(raw), 4))
    family = socket.AF_INET if len(raw) == 4 else socket.AF_INET6
    return socket.inet_ntop(family, words), int(hex_port, 16)


def process_sockets(pid: int) -> list[Sock]:
    """Every IP socket process ``pid`` holds (threads share the table of fds)."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:  # closed meanwhile
            continue
        if target.startswith("socket:["):
            inodes.add(int(target[8:-1]))
    found = []
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        with open(f"/proc/{pid}/net/{proto}") as f:
            next(f)
            for line in f:
                cols = line.split()
                if int(cols[9]) in inodes:
                    local, port = _address(cols[1])
                    remote, remote_port = _address(cols[2])
                    found.append(Sock(proto, local, port, remote, remote_port, int(cols[3], 16)))
    return found


def exposed(pid: int) -> list[Sock]:
    """The sockets of ``pid`` that another machine could reach: listening (TCP) or bound (UDP)
    on an address that is not loopback."""
    return [s for s in process_sockets(pid) if s.listening and not s.loopback]
