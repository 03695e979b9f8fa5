"""Progress output: a bar on a terminal, a plain line every few seconds anywhere else (a log
file, CI), nothing with --no-progress. `bench run` printed nothing between its estimate and
"episodes done (381 s)", and `rollout` nothing for 49 s, when stderr was a file."""

from __future__ import annotations

import io
import time

import pytest

from tap_bench import progress
from tap_bench.execution import LocalBackend
from tap_bench.progress import ProgressLines, SilentProgress, progress_bar


def test_lines_every_interval_while_the_work_runs_and_a_last_one():
    stream = io.StringIO()
    with ProgressLines(4, "highway idm", "episode", every=0.05, stream=stream) as lines:
        lines.update(1)
        time.sleep(0.3)
        lines.update(1)
    text = stream.getvalue().splitlines()
    assert len(text) >= 3  # several while it ran, and the last one
    assert text[0].startswith("highway idm: 1/4 episodes, ") and "s left" in text[0]
    assert text[-1].startswith("highway idm: 2/4 episodes, ")


def test_work_done_sooner_than_a_line_prints_nothing():
    stream = io.StringIO()
    with ProgressLines(2, "quick", "task", every=5.0, stream=stream) as lines:
        lines.update(2)
    assert stream.getvalue() == ""


def test_a_bar_on_a_terminal_lines_elsewhere_nothing_when_asked(monkeypatch):
    from tqdm.auto import tqdm

    monkeypatch.setattr(progress, "_stderr_is_terminal", lambda: False)
    with progress_bar(3, "x", "task", None) as bar:
        assert isinstance(bar, ProgressLines)
    with progress_bar(3, "x", "task", False) as bar:  # nothing drawn, no tqdm imported
        assert isinstance(bar, SilentProgress)
        bar.update(2)
        assert bar.n == 2
    monkeypatch.setattr(progress, "_stderr_is_terminal", lambda: True)
    with progress_bar(3, "x", "task", None) as bar:
        assert isinstance(bar, tqdm)


def _slow(x: int) -> int:
    time.sleep(0.15)
    return x


def test_the_backends_map_reports_progress_when_stderr_is_a_file(monkeypatch, capsys):
    """The one place `bench run` and `rollout` run their episodes through (Backend.map):
    with stderr not a terminal (pytest's capture) and no --progress / --no-progress."""
    monkeypatch.setattr(progress, "LINE_EVERY", 0.05)
    assert [o.value for o in LocalBackend(1).map(_slow, [1, 2, 3], desc="bench demo",
                                                 unit="task")] == [1, 2, 3]
    err = capsys.readouterr().err
    assert "bench demo: " in err and "/3 tasks, " in err
    LocalBackend(1).map(_slow, [1, 2, 3], desc="bench demo", unit="task", progress=False)
    assert capsys.readouterr().err == ""


@pytest.mark.filterwarnings("ignore")
def test_rollout_to_a_file_is_not_silent(monkeypatch, capsys, tmp_path):
    from tap_bench.cli import main

    monkeypatch.setattr(progress, "LINE_EVERY", 0.05)
    assert main(["rollout", "--env", "highway", "--policy", "idm", "--seeds", "0-1",
                 "--duration", "2", "-o", str(tmp_path / "t.parquet")]) == 0
    err = capsys.readouterr().err
    assert "highway idm: " in err and "/2 episodes, " in err
