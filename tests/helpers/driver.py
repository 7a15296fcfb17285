"""Small helpers shared by the driver tests."""
from __future__ import annotations


def child_pids(pid: int, command_has: str = '') -> list[int]:
    """Ids of the live child processes of process `pid` whose command line contains
    `command_has` (Linux /proc)."""
    from pathlib import Path
    out = []
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
            command = (stat.parent / 'cmdline').read_bytes().replace(b'\0', b' ').decode()
        except (OSError, IndexError):
            continue      # gone meanwhile
        if int(fields[1]) == pid and fields[0] != 'Z' and command_has in command:
            out.append(int(stat.parent.name))
    return out


def wait_until(predicate, timeout_s: float, interval_s: float = 0.01) -> bool:
    import time
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval_s)
    return predicate()


def distinct_words(backend) -> list[int]:
    """Latched LED words with repeats collapsed (a firmware may re-latch an unchanged word)."""
    out: list[int] = []
    for latched in backend.led_words():
        if not out or out[-1] != latched.word:
            out.append(latched.word)
    return out
