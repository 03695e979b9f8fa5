"""idle_threads_sleep: the command line lets OpenBLAS's idle threads sleep at once
(OPENBLAS_THREAD_TIMEOUT), unless the user set it, and does so before NumPy is imported."""

from __future__ import annotations

import os
import subprocess
import sys

CHECK = """\
import os, sys
from tap_bench.execution import idle_threads_sleep
idle_threads_sleep()
print(os.environ["OPENBLAS_THREAD_TIMEOUT"])
"""


def _timeout(extra: dict[str, str]) -> str:
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_THREAD_TIMEOUT"}
    done = subprocess.run([sys.executable, "-c", CHECK], env={**env, **extra},
                          capture_output=True, text=True, check=True)
    return done.stdout.strip()


def test_the_timeout_is_set_unless_the_user_set_one():
    assert _timeout({}) == "4"
    assert _timeout({"OPENBLAS_THREAD_TIMEOUT": "20"}) == "20"  # theirs


def test_the_command_line_sets_it_before_numpy_is_imported():
    code = ("import os, sys\nimport tap_bench.cli\nassert 'numpy' not in sys.modules\n"
            "import tap_bench.execution as ex\nseen = []\n"
            "orig = ex.idle_threads_sleep\n"
            "def spy():\n    seen.append('numpy' in sys.modules)\n    orig()\n"
            "ex.idle_threads_sleep = spy\n"
            "from tap_bench.cli import main\n"
            "try:\n    main(['label', '--help'])\nexcept SystemExit:\n    pass\n"
            "print(seen, os.environ.get('OPENBLAS_THREAD_TIMEOUT'), 'numpy' in sys.modules)")
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_THREAD_TIMEOUT"}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          text=True, check=True)
    assert done.stdout.strip().splitlines()[-1] == "[False] 4 True"
