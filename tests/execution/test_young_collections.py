"""The command line's process, once its start-up is frozen (freeze_start_up), collects its
youngest generation every YOUNG_COLLECTION_THRESHOLD allocations instead of CPython's 700
(a fresh interpreter: the threshold is for the rest of a process)."""

from __future__ import annotations

import json
import subprocess
import sys

CHILD = """\
import gc, json
from tap_bench.execution import (LocalBackend, YOUNG_COLLECTION_THRESHOLD,
                                 freeze_start_up)
freeze_start_up()
start = gc.get_threshold()
LocalBackend(processes=1).map(len, [[1], [2, 3]])
print(json.dumps({"start": start, "after": gc.get_threshold(),
                  "young": YOUNG_COLLECTION_THRESHOLD}))
"""


def test_the_young_generation_is_collected_less_often_after_the_freeze():
    done = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                          check=True)
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got["start"][0] == 700  # CPython's until the first task has ended
    assert got["after"] == [got["young"], *got["start"][1:]]
    assert got["young"] > 700
