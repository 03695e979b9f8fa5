"""keep_freed_memory: glibc keeps freed memory for reuse and Arrow allocates from the same
heap, unless the user chose Arrow's pool (Linux only)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

CHILD = """\
from tap_bench.execution import keep_freed_memory
kept = keep_freed_memory()
import pyarrow
print(kept, pyarrow.default_memory_pool().backend_name)
"""


def _pool(extra_env: dict[str, str]) -> tuple[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "ARROW_DEFAULT_MEMORY_POOL"}
    done = subprocess.run([sys.executable, "-c", CHILD], env={**env, **extra_env},
                          capture_output=True, text=True, check=True)
    kept, pool = done.stdout.split()
    return kept, pool


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_arrow_allocates_from_the_heap_unless_the_user_chose_a_pool():
    assert _pool({}) == ("True", "system")
    assert _pool({"ARROW_DEFAULT_MEMORY_POOL": "mimalloc"})[1] == "mimalloc"  # theirs
