"""The local backend and its recovery rule: outcomes in order, a failing item retried once
then reported, a dead worker costing only the item it ran, bounded streaming, no orphans."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from tap_bench.errors import ParameterError, TapBenchError, UnknownNameError
from tap_bench.execution import DEFAULT_RETRIES, LocalBackend, make_backend

sys.path.insert(0, str(Path(__file__).resolve().parent))  # for backend_tasks, in the workers too
from backend_tasks import die_if as _die_if
from backend_tasks import die_once as _die_once
from backend_tasks import pid as _pid
from backend_tasks import square_or_fail as _square_or_fail


def _check_outcomes(outcomes, retries: int) -> None:
    assert [o.item for o in outcomes] == [0, 1, 2, 3, 4]
    assert [o.value for o in outcomes] == [0, 1, 4, None, 16]
    bad = outcomes[3]
    assert not bad.ok and "item 3 is bad" in bad.error and "ValueError" in bad.error
    assert bad.attempts == retries + 1
    assert all(o.ok and o.attempts == 1 for o in outcomes if o.item != 3)


@pytest.mark.parametrize("workers", [1, 2])
def test_a_failing_item_is_retried_then_reported_and_the_others_kept(workers):
    _check_outcomes(LocalBackend(workers).map(_square_or_fail, list(range(5)), progress=False),
                    DEFAULT_RETRIES)
    _check_outcomes(LocalBackend(workers).map(_square_or_fail, list(range(5)), retries=2,
                                              progress=False), 2)


def test_the_default_recovery_rule_is_one_retry():
    assert DEFAULT_RETRIES == 1


def test_a_worker_killed_once_costs_nothing(tmp_path):
    markers = [str(tmp_path / f"attempts-{i}") for i in range(3)]
    outcomes = LocalBackend(2).map(_die_once, markers, progress=False)
    assert [o.value for o in outcomes] == [2, 2, 2]
    assert [o.attempts for o in outcomes] == [2, 2, 2]


def test_a_worker_that_always_dies_costs_only_its_own_item():
    # the killer is listed first: under the old pool every item after it failed too
    outcomes = LocalBackend(2).map(_die_if, list(range(8)), progress=False)
    assert not outcomes[0].ok and "died" in outcomes[0].error
    assert outcomes[0].attempts == DEFAULT_RETRIES + 1
    assert [o.value for o in outcomes[1:]] == list(range(1, 8))
    assert all(o.ok and o.attempts == 1 for o in outcomes[1:])


def test_workers_are_reused_across_items():
    outcomes = LocalBackend(2).map(_pid, list(range(6)), progress=False)
    assert len({o.value for o in outcomes}) <= 2 and os.getpid() not in {o.value for o in outcomes}


def test_imap_streams_in_order_and_reads_the_source_lazily():
    read = []

    def source():
        for i in range(20):
            read.append(i)
            yield i

    stream = LocalBackend(2).imap(_square_or_fail, source(), window=3, progress=False)
    first = next(stream)
    assert first.value == 0
    assert len(read) <= 3 + 2  # bounded: the window, not the whole source
    rest = list(stream)
    assert [o.item for o in [first, *rest]] == list(range(20))
    assert [o.value for o in rest][:3] == [1, 4, None]


def test_an_unpicklable_task_is_reported_not_raised():
    outcomes = LocalBackend(2).map(_square_or_fail, [1, lambda: 0], progress=False)
    assert outcomes[0].value == 1
    assert not outcomes[1].ok and "cannot" in outcomes[1].error


def test_bad_parameters_name_themselves():
    with pytest.raises(ParameterError, match=r"workers must be a positive integer.*got 0"):
        LocalBackend(0)
    with pytest.raises(ParameterError, match="retries"):
        LocalBackend(1).map(_square_or_fail, [1], retries=-1)
    with pytest.raises(UnknownNameError, match="ray"):
        make_backend("rey")
    with pytest.raises(TapBenchError, match="--backend ray"):
        make_backend("local", address="auto")


def _children(pid: int) -> list[int]:
    """Live (not zombie) child processes of ``pid``, from /proc."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            out.append(int(stat.parent.name))
    return out


def test_no_worker_outlives_the_map_even_when_the_consumer_stops_early():
    before = set(_children(os.getpid()))  # other tests may have left helpers (Ray) running
    stream = LocalBackend(2).imap(_pid, range(10), progress=False)
    next(stream)
    workers = set(_children(os.getpid())) - before
    assert len(workers) == 2
    stream.close()
    assert not workers & set(_children(os.getpid()))


def test_a_plain_script_without_a_main_guard_works(tmp_path):
    # Workers never re-import the caller's script: the API works as written in a script.
    script = tmp_path / "plain.py"
    script.write_text(textwrap.dedent("""
        from tap_bench.execution import LocalBackend
        from tests_helper_square import square
        print("ran", [o.value for o in LocalBackend(2).map(square, [1, 2, 3], progress=False)])
    """))
    (tmp_path / "tests_helper_square.py").write_text("def square(x):\n    return x * x\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("ran") == 1 and "[1, 4, 9]" in done.stdout
    assert "Traceback" not in done.stderr


def test_a_killed_parent_leaves_no_worker_behind(tmp_path):
    script = tmp_path / "parent.py"
    script.write_text(textwrap.dedent("""
        import time
        from tap_bench.execution import LocalBackend
        for o in LocalBackend(2).imap(time.sleep, [30] * 4, progress=False):
            pass
    """))
    # a process group of its own, killed whatever happens: a test that fails or times out
    # under load leaves no orphan behind
    parent = subprocess.Popen([sys.executable, str(script)], cwd=tmp_path,
                              start_new_session=True)
    try:
        deadline = time.time() + 180  # generous under load, bounded
        while time.time() < deadline and len(_children(parent.pid)) < 2:
            time.sleep(0.2)
        workers = _children(parent.pid)
        assert len(workers) == 2
        parent.kill()  # SIGKILL: no cleanup code runs in the parent
        parent.wait(timeout=120)
        deadline = time.time() + 120
        alive = workers
        while time.time() < deadline and alive:
            alive = [w for w in workers if _alive(w)]
            time.sleep(0.2)
        assert alive == [], "workers outlived their killed parent"
    finally:
        with contextlib.suppress(OSError):
            os.killpg(parent.pid, signal.SIGKILL)
        with contextlib.suppress(subprocess.TimeoutExpired):
            parent.wait(timeout=120)


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_calls_in_a_kept_block_share_their_workers_and_the_block_stops_them(tmp_path):
    """Two map calls in one kept() block run on the same two worker processes (the run's
    estimate and its episodes start the workers once); a worker that dies in the block is
    replaced; the block's end stops every worker. Outside a block each call has its own."""
    backend = LocalBackend(2)
    with backend.kept():
        first = {o.value for o in backend.map(_pid, list(range(6)), progress=False)}
        second = {o.value for o in backend.map(_pid, list(range(6)), progress=False)}
        workers = list(backend._kept[0])
        assert len(first) == 2 and first == second
        died = backend.map(_die_if, [0, 1, 2], retries=0, progress=False)
        assert not died[0].ok and [o.value for o in died[1:]] == [1, 2]
        after = {o.value for o in backend.map(_pid, list(range(6)), progress=False)}
        assert len(after) == 2 and len(after & first) == 1  # one replaced, one kept
    assert backend._kept is None
    for worker in workers:
        assert worker.process.wait(timeout=5) is not None  # stopped with the block
    apart = [{o.value for o in backend.map(_pid, list(range(6)), progress=False)}
             for _ in range(2)]
    assert not apart[0] & apart[1]  # outside a block: new workers per call
    _check_outcomes(backend.map(_square_or_fail, list(range(5)), progress=False),
                    DEFAULT_RETRIES)
