"""The tasks the local backend's tests send to its worker processes, in a module of their
own: a worker imports the module of the function it is sent, and this one imports only the
standard library, where the test module imports pytest and tap-bench (about 0.6 CPU s more
in every worker the tests start)."""

from __future__ import annotations

import os
import time
from pathlib import Path


def square_or_fail(x: int) -> int:
    """``x * x``; raises ValueError for ``x == 3``."""
    if x == 3:
        raise ValueError(f"item {x} is bad")
    return x * x


def die_once(marker: str) -> int:
    """Kills its own worker process on the first attempt; returns the attempt count after
    (counted in the file ``marker``)."""
    path = Path(marker)
    attempts = int(path.read_text()) + 1 if path.exists() else 1
    path.write_text(str(attempts))
    if attempts == 1:
        os._exit(1)  # a worker killed mid-task: no exception, the process is gone
    return attempts


def die_if(x: int) -> int:
    """Kills its worker on item 0, every time; returns the item for the others."""
    if x == 0:
        os._exit(3)
    time.sleep(0.05)
    return x


def pid(_: int) -> int:
    """The worker's process id, after 0.1 s (so that both workers get items)."""
    time.sleep(0.1)
    return os.getpid()
