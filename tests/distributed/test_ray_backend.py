"""The Ray backend: each item's outcome in order, failures retried then reported, a killed worker's
task retried."""

from __future__ import annotations

import os
from pathlib import Path


def _square_or_fail(x: int) -> int:
    if x == 3:
        raise ValueError(f"item {x} is bad")
    return x * x


def _die_once(marker: str) -> int:
    """Kills its own worker process on the first attempt; returns the attempt count after."""
    path = Path(marker)
    attempts = int(path.read_text()) + 1 if path.exists() else 1
    path.write_text(str(attempts))
    if attempts == 1:
        os._exit(1)  # a worker killed mid-task: no exception, the process is gone
    return attempts


def _check_outcomes(outcomes) -> None:
    assert [o.item for o in outcomes] == [0, 1, 2, 3, 4]
    assert [o.value for o in outcomes] == [0, 1, 4, None, 16]
    bad = outcomes[3]
    assert not bad.ok and "item 3 is bad" in bad.error and "ValueError" in bad.error
    assert bad.attempts == 3  # the first attempt and 2 retries
    assert all(o.ok and o.attempts == 1 for o in outcomes if o.item != 3)


def test_ray_backend_reports_a_failing_item_after_its_retries_and_keeps_the_others(
        ray_backend):
    _check_outcomes(ray_backend.map(_square_or_fail, list(range(5)), retries=2,
                                    progress=False))


def test_a_ray_task_whose_worker_is_killed_mid_run_is_retried(ray_backend, tmp_path):
    markers = [str(tmp_path / f"attempts-{i}") for i in range(2)]
    outcomes = ray_backend.map(_die_once, markers, retries=1, progress=False)
    assert [o.ok for o in outcomes] == [True, True]
    assert [o.value for o in outcomes] == [2, 2]  # each ran twice: killed, then completed


def test_a_ray_task_killed_on_every_retry_is_reported(ray_backend, tmp_path):
    outcomes = ray_backend.map(_die_once, [str(tmp_path / "m")], retries=0, progress=False)
    assert not outcomes[0].ok and "died" in outcomes[0].error


def test_ray_imap_streams_in_order(ray_backend):
    got = list(ray_backend.imap(_square_or_fail, iter([0, 1, 2, 4]), window=1, progress=False))
    assert [o.value for o in got] == [0, 1, 4, 16]
