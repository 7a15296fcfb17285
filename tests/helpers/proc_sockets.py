"""Which internet sockets a process holds, and which of them listen beyond loopback.

Reads /proc/<pid>/fd (socket inodes) and /proc/<pid>/net/{udp,udp6,tcp,tcp6} (addresses,
in the process's network namespace). Linux only.
"""
from __future__ import annotations

import ipaddress
import os
import re
from dataclasses import dataclass

TCP_LISTEN = '0A'


@dataclass(frozen=True)
class InetSocket:
    proto: str  # 'udp', 'udp6', 'tcp', 'tcp6'
    address: ipaddress.IPv4Address | ipaddress.IPv6Address
    port: int
    state: str  # hex state from /proc (TCP: '0A' = LISTEN)

    @property
    def loopback(self) -> bool:
        a = self.address
        if isinstance(a, ipaddress.IPv6Address) and a.ipv4_mapped is not None:
            a = a.ipv4_mapped
        return a.is_loopback

    def __str__(self) -> str:
        return f'{self.proto} {self.address}:{self.port}'


def parse_address(hex_address: str) -> tuple[ipaddress.IPv4Address | ipaddress.IPv6Address, int]:
    """'0100007F:1B58' -> (127.0.0.1, 7000); IPv6 is four little-endian 32-bit words."""
    host, port = hex_address.split(':')
    raw = bytes.fromhex(host)
    if len(raw) == 4:
        return ipaddress.IPv4Address(raw[::-1]), int(port, 16)
    words = b''.join(raw[i:i + 4][::-1] for i in range(0, 16, 4))
    return ipaddress.IPv6Address(words), int(port, 16)


def parse_proc_net(text: str, proto: str) -> dict[str, InetSocket]:
    """inode -> socket for the lines of one /proc/net/<proto> table."""
    sockets = {}
    for line in text.splitlines()[1:]:
        fields = line.split()
        if len(fields) < 10:
            continue
        address, port = parse_address(fields[1])
        sockets[fields[9]] = InetSocket(proto, address, port, fields[3])
    return sockets


def sockets_of(pid: int) -> list[InetSocket]:
    inodes = set()
    for fd in os.listdir(f'/proc/{pid}/fd'):
        try:
            target = os.readlink(f'/proc/{pid}/fd/{fd}')
        except OSError:  # closed meanwhile
            continue
        m = re.fullmatch(r'socket:\[(\d+)\]', target)
        if m:
            inodes.add(m.group(1))
    found = []
    for proto in ('udp', 'udp6', 'tcp', 'tcp6'):
        with open(f'/proc/{pid}/net/{proto}') as f:
            table = parse_proc_net(f.read(), proto)
        found += [s for inode, s in table.items() if inode in inodes]
    return found


def ephemeral_port_low() -> int:
    with open('/proc/sys/net/ipv4/ip_local_port_range') as f:
        return int(f.read().split()[0])


def listening_beyond_loopback(sockets: list[InetSocket], ephemeral_low: int) -> list[InetSocket]:
    """Sockets that accept traffic from other machines on a port chosen on purpose.

    TCP: any LISTEN socket not on loopback. UDP: any socket not on loopback whose port lies
    below the ephemeral range, i.e. was bound explicitly (DDS's discovery and data ports);
    UDP sockets on ephemeral ports are DDS's send sockets, which the kernel numbers.
    """
    bad = []
    for s in sockets:
        if s.loopback:
            continue
        if s.proto.startswith('tcp') and s.state == TCP_LISTEN:
            bad.append(s)
        elif s.proto.startswith('udp') and s.port < ephemeral_low:
            bad.append(s)
    return bad
