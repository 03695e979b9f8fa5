"""The user code a run loads (:func:`tap_bench.usercode.recording`) is noted per thread: two
runs whose code runs at once in two threads of one process (Ray's local mode, a user's
thread pool) each get the modules their own thread loaded, whatever the order the threads
enter and leave; a thread no run entered (one a policy started) notes for every active
run."""

from __future__ import annotations

import importlib
import sys
import threading
import uuid

from tap_bench.usercode import loaded_user_code, recording


def _modules(tmp_path, monkeypatch, *roles: str) -> dict[str, str]:
    """A fresh module of the user's code per role (its name unique to this test)."""
    tag = uuid.uuid4().hex[:8]
    names = {role: f"helper_{role}_{tag}" for role in roles}
    for name in names.values():
        (tmp_path / f"{name}.py").write_text("VALUE = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in names.values():
        monkeypatch.delitem(sys.modules, name, raising=False)
    return names


def test_two_runs_in_two_threads_note_their_own_modules(tmp_path, monkeypatch):
    names = _modules(tmp_path, monkeypatch, "a", "b", "spawned")
    runs = {role: f"run-{role}-{uuid.uuid4().hex[:8]}" for role in ("a", "b")}
    b_entered, a_done, spawned_done = threading.Event(), threading.Event(), threading.Event()
    errors = []

    def run_a():
        try:
            with recording(runs["a"]):
                assert b_entered.wait(10)  # b entered after a: b is the later one
                importlib.import_module(names["a"])
            a_done.set()
        except BaseException as err:  # reported in the main thread
            errors.append(err)
            a_done.set()

    def run_b():
        try:
            with recording(runs["b"]):
                b_entered.set()
                assert a_done.wait(10)  # a left first: b is still in its run
                worker = threading.Thread(
                    target=lambda: (importlib.import_module(names["spawned"]),
                                    spawned_done.set()))
                worker.start()
                worker.join(10)
                importlib.import_module(names["b"])
        except BaseException as err:  # reported in the main thread
            errors.append(err)

    threads = [threading.Thread(target=run_a), threading.Thread(target=run_b)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(20)
    assert not errors, errors
    assert spawned_done.is_set()
    loaded = {role: set(loaded_user_code(run)) for role, run in runs.items()}
    assert loaded["a"] == {names["a"]}, loaded
    # the thread b's code started, with no run of its own, counts for the run active then
    assert loaded["b"] == {names["b"], names["spawned"]}, loaded
