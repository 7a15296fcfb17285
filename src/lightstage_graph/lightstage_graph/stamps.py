"""Stamps: ``builtin_interfaces/Time`` <-> integer nanoseconds, and a readable form."""
from builtin_interfaces.msg import Time

NS_PER_S = 1_000_000_000


def ns_to_stamp(ns: int) -> Time:
    return Time(sec=int(ns) // NS_PER_S, nanosec=int(ns) % NS_PER_S)


def stamp_to_ns(stamp) -> int:
    """A ``builtin_interfaces/Time`` (anything with ``sec`` and ``nanosec``) in nanoseconds."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def format_stamp(ns: int) -> str:
    return f"{ns // NS_PER_S}.{ns % NS_PER_S:09d}"
