"""Printing a command's output to a reader that may go away (`lightstage bag info BAG | head
-1`): the rest is dropped quietly, as `cat` does, instead of a BrokenPipeError traceback.
No rclpy here."""
from __future__ import annotations

import os
import sys


def print_out(text: str) -> bool:
    """Print `text` (and a newline) to stdout and flush; False when the reader has closed the
    pipe. stdout is then pointed at /dev/null, so that the interpreter's own flush at exit
    does not fail a second time ("Exception ignored ... BrokenPipeError")."""
    try:
        print(text, flush=True)
        return True
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, sys.stdout.fileno())
        finally:
            os.close(devnull)
        return False
