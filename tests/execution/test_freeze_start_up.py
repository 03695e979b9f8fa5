"""freeze_start_up: what a process made before its first task's end is kept out of later
garbage collections, once, after its garbage is collected; asked for only by the command
line run as the process's program (each case in a fresh interpreter: a freeze is for the
rest of a process)."""

from __future__ import annotations

import json
import subprocess
import sys

CHILD = """\
import gc, json, sys, weakref
from tap_bench.execution import LocalBackend, freeze_start_up
if sys.argv[1] == "asked":
    freeze_start_up()
class Node:
    pass
node = Node()
node.self = node  # a cycle: garbage once dropped
dropped = weakref.ref(node)
del node
kept = Node()  # alive at the first task's end
before = gc.get_freeze_count()
LocalBackend(processes=1).map(len, [[1], [2, 3]])
first = gc.get_freeze_count()
more = [Node() for _ in range(100)]  # made after the first task
LocalBackend(processes=1).map(len, [[4]])
print(json.dumps({"before": before, "first": first, "second": gc.get_freeze_count(),
                  "cycle_freed": dropped() is None,
                  "kept_frozen": first > before}))
"""

MAIN = """\
import json, sys
import tap_bench.cli
from tap_bench import execution
argv = None if sys.argv[1] == "program" else ["no-such-command"]
sys.argv = ["tap-bench", "no-such-command"]
try:
    tap_bench.cli.main(argv)
except SystemExit:  # argparse refuses the command
    pass
print(json.dumps(execution._START_UP["freeze"]))
"""


def _run(code: str, *args: str) -> object:
    done = subprocess.run([sys.executable, "-c", code, *args], capture_output=True,
                          text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_the_start_up_is_frozen_once_after_the_first_task_its_garbage_freed():
    got = _run(CHILD, "asked")
    assert got["before"] == 0 and got["kept_frozen"]
    assert got["second"] == got["first"]  # once per process: later objects stay collectable
    assert got["cycle_freed"]  # collected before the freeze, not frozen


def test_nothing_is_frozen_unless_asked():
    got = _run(CHILD, "not asked")
    assert got["before"] == got["first"] == got["second"] == 0


def test_the_command_line_asks_only_as_the_processs_program():
    assert _run(MAIN, "program") is True
    assert _run(MAIN, "caller") is False
