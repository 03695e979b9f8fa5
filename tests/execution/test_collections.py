"""The command line's start-up without the cyclic garbage collector (execution.
hold_collections): held from the start, released (start-up objects frozen, collector on)
at the end of the first in-process task or before a command that runs none, once per
process."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def test_the_collector_is_held_through_the_start_up_and_on_again_after_it():
    # a fresh interpreter: the test process's own collector is left as it is
    script = textwrap.dedent("""
        import gc
        from tap_bench import execution
        from tap_bench.cli import main
        execution.hold_collections()
        held = not gc.isenabled()
        value = execution._timed(lambda x: x + 1, 1)[0]
        after_task = gc.isenabled(), gc.get_freeze_count() > 0
        execution.hold_collections()  # once per process
        again = gc.isenabled()
        gc.unfreeze()
        main(["policies"])  # runs no task: released before it runs
        print(held, value, *after_task, again, gc.isenabled(), gc.get_freeze_count() == 0)
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[-7:] == ["True", "2", "True", "True", "True", "True", "True"]


def test_a_command_that_runs_no_task_runs_with_the_collector():
    script = textwrap.dedent("""
        import gc
        import tap_bench.cli as cli
        import tap_bench.cli.policies as command
        seen = []
        def run(args):
            seen.append(gc.isenabled())
            return 0
        command.run = run  # read by its add_parser when the parser is built
        cli.main(["policies"])
        print(seen[0], gc.get_freeze_count() > 0)
    """)
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[-2:] == ["True", "True"]
