"""The command line's process (freeze_start_up asked for) collects its youngest generation
every YOUNG_COLLECTION_THRESHOLD allocations instead of CPython's 700, from the request on
(a fresh interpreter: the threshold is for the rest of a process)."""

from __future__ import annotations

import json
import subprocess
import sys

CHILD = """\
import gc, json
from tap_bench.execution import (LocalBackend, YOUNG_COLLECTION_THRESHOLD,
                                 freeze_start_up)
before = gc.get_threshold()
freeze_start_up()
asked = gc.get_threshold()
LocalBackend(processes=1).map(len, [[1], [2, 3]])
print(json.dumps({"before": before, "asked": asked, "after": gc.get_threshold(),
                  "young": YOUNG_COLLECTION_THRESHOLD}))
"""


def test_the_young_generation_is_collected_less_often_once_the_freeze_is_asked_for():
    done = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                          check=True)
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got["before"][0] == 700  # CPython's until asked
    assert got["asked"] == got["after"] == [got["young"], *got["before"][1:]]
    assert got["young"] > 700
