"""The user code a run loads (:func:`tap_bench.usercode.recording`): two runs whose code
runs at once in two threads of one process (Ray's local mode, a user's thread pool), or one
after the other, each get every module either loaded, whatever the order the threads enter
and leave (a thread no run entered, one a policy started, included): a module already
loaded is not imported again, so nothing tells which run uses it."""

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
    # every module a thread loaded, the one b's code started with no run of its own among
    # them, counts for both runs: nothing shows which of them uses a module already loaded
    every = {names["a"], names["b"], names["spawned"]}
    assert every <= loaded["a"] and every <= loaded["b"], loaded


def test_a_module_an_earlier_run_imported_counts_for_a_later_run(tmp_path, monkeypatch):
    # run b loads the helper by name after run a imported it: no import happens, yet b's
    # episodes depend on it, and an edit of it must not serve b's entries
    names = _modules(tmp_path, monkeypatch, "shared")
    first, later = (f"run-{uuid.uuid4().hex[:8]}" for _ in range(2))
    with recording(first):
        importlib.import_module(names["shared"])
    with recording(later):
        importlib.import_module(names["shared"])
    assert names["shared"] in loaded_user_code(later)
