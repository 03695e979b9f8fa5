"""A run served whole from the cache (issue 24 section 3, :mod:`tap_bench.bench.run.served`):
an unchanged re-run writes the earlier run's files, byte for byte, without reading an
episode or scoring; every input that can change an output makes it miss, and the run made
instead equals a cold run; a damaged entry is made again; the pages that name the run are
filled with this run's name, time and timings exactly as a made run writes them."""

from __future__ import annotations

import dataclasses
import json
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pandas as pd
import pytest

from tap_bench.bench import cache as cache_module
from tap_bench.bench.cache import EpisodeCache, derived_key
from tap_bench.bench.run import served as run_cache
from tap_bench.bench.run.folder import write_results
from tap_bench.bench.run.runner import run_suite
from tap_bench.bench.suite import suite_from_dict
from tap_bench.errors import RunExistsError

ROOT = Path(__file__).resolve().parents[2]
PAGES = {"summary.json", "report.html", "viewer/data/index.js"}


def tiny(**changes):
    """A suite of one env, two policies and two seeds (4 episodes of 3 s): what a run entry
    holds and serves does not depend on how many envs the run has; the key test below
    checks that the envs, their order and their settings are in the key."""
    doc = {"name": "tiny", "envs": ["merge"], "policies": ["idm", "lane-keeping"],
           "seeds": "0-1", "reference_policy": "idm",
           "env_overrides": {"merge": {"duration": 3}},
           "bootstrap": {"n_resamples": 200}}
    doc.update(changes)
    return suite_from_dict(doc, check_names=False)


def run(folder, cache, suite=None, **kwargs):
    """``run_suite`` of ``suite`` (``tiny()``), quietly; ``report=False`` where a test compares
    tables and keys only (the report is most of a tiny run's CPU)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_suite(suite or tiny(), folder, workers=kwargs.pop("workers", 1),
                         progress=False, cache=cache, **kwargs)


def served(result) -> bool:
    return (result.summary["cache"] or {}).get("run") == "served whole"


def files(folder: Path) -> dict[str, bytes]:
    """Every file of a run folder by its path (its marker, which lists them, left out)."""
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file() and p != folder /
            ".tap-bench-folder"}


def assert_tables_equal(a, b):
    """Every table of two runs equal, column for column, floats with ==; their scores too."""
    names = sorted(p.name for p in a.folder.glob("*.parquet"))
    assert names == sorted(p.name for p in b.folder.glob("*.parquet"))
    for name in names:
        if (a.folder / name).read_bytes() == (b.folder / name).read_bytes():
            continue  # the same file: the same table
        left, right = pd.read_parquet(a.folder / name), pd.read_parquet(b.folder / name)
        pd.testing.assert_frame_equal(left, right, check_exact=True, obj=name)
        assert left.equals(right), name
    pd.testing.assert_frame_equal(a.episodes, b.episodes, check_exact=True)
    for name, table in a.scores.tables().items():
        pd.testing.assert_frame_equal(table, b.scores.tables()[name], check_exact=True,
                                      obj=name)
    assert list(a.scores.methods.items()) == list(b.scores.methods.items())
    for key in ("headline", "verdict", "methods", "provenance", "measures", "suite"):
        assert a.summary[key] == b.summary[key], key


def _no_work(monkeypatch):
    def fail(*args, **kwargs):
        raise AssertionError("a served run made something")

    monkeypatch.setattr("tap_bench.bench.run.episodes._rollouts", fail)
    monkeypatch.setattr("tap_bench.bench.run.scoring.score", fail)
    monkeypatch.setattr("tap_bench.bench.run.runner.write_results", fail)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runcache")
    cache = EpisodeCache(root / "cache")
    cold = run(root / "cold", None)
    first = run(root / "first", cache, workers=2)
    return root, cold, first, cache


def test_an_unchanged_rerun_is_served_whole_and_equal(runs, tmp_path, monkeypatch):
    _, cold, first, cache = runs
    assert not served(first) and cache.derived_path("runs", run_key(cache, tiny())).is_file()
    _no_work(monkeypatch)
    again = run(tmp_path / "first", cache)  # the same folder name, another place
    assert served(again)
    assert again.summary["cache"]["cached"] == again.summary["cache"]["labelled_before"] == 4
    # every file the earlier run wrote, byte for byte, but those that name the run
    mine, theirs = files(again.folder), files(first.folder)
    assert set(mine) == set(theirs)
    assert {name for name in mine if mine[name] != theirs[name]} <= PAGES
    cold_files = files(cold.folder)  # and a run without a cache wrote the same bytes
    assert set(cold_files) == set(mine)
    assert {name for name in mine if mine[name] != cold_files[name]} <= PAGES
    # the tables equal a cold run's (floats with ==), whatever the worker count
    assert_tables_equal(cold, again)
    assert_tables_equal(first, again)
    # this run's own facts, honestly: its name, time, timings, and that it was served
    summary = json.loads((again.folder / "summary.json").read_text())
    assert summary == json.loads(json.dumps(again.summary, default=str))
    assert list(summary) == list(first.summary)
    assert summary["run"] == "first" and summary["cache"]["simulated"] == 0
    assert set(summary["timings"]) == {"reading_the_run_entry", "total"}
    assert summary["estimate"]["basis"] == "served whole from the cache"
    for key in set(summary) - set(run_cache.FRESH):
        assert summary[key] == json.loads(json.dumps(first.summary[key], default=str)), key
    page = (again.folder / "report.html").read_text()
    assert "reading_the_run_entry" in page and "rollouts_wall" not in page
    assert summary["created"] in page
    assert "tapbench" not in page and "tapbench" not in (
        again.folder / "viewer" / "data" / "index.js").read_text()


def test_no_file_of_a_kept_or_served_run_holds_a_placeholder(runs, tmp_path):
    """The report and the viewer are written from a summary whose name, time and timings
    are placeholders (page_templates); only the pages kept as templates are filled, so any
    other file written from that summary would carry a placeholder into the run folder,
    the entry and every served run (the byte-for-byte comparisons cannot see it: both
    sides hold the same one)."""
    _, _, first, cache = runs
    again = run(tmp_path / "again", cache)
    assert served(again)
    mark = re.compile(rb"tapbench(?:run|created|timings)[0-9a-f]{24}")
    for result in (first, again):
        for name, data in files(result.folder).items():
            assert not mark.search(data), name
    entry = cache.derived_path("runs", run_key(cache, tiny()))
    assert len(mark.findall(entry.read_bytes())) >= 2  # the templates hold them, and only
    # the templates: each placeholder found in the entry is inside one of the two pages
    kept, _ = cache.read_derived("runs", run_key(cache, tiny()))
    assert {name for name, data in kept.items() if mark.search(data)} == {
        f"run/{page}" for page in run_cache.PAGES}


def test_the_pages_filled_are_the_pages_written(runs, tmp_path):
    """A page kept as a template and filled is byte for byte the page written from the
    summary itself, whatever the run's name holds."""
    _, _, first, _ = runs
    summary = dict(first.summary)
    # HTML and script-breaking characters and non-ASCII in one name, and a name like the
    # placeholders themselves (each name writes the report and viewer twice)
    for k, name in enumerate(['r&un <b>"x"</b> é</script>ü', "tapbench"]):
        summary.update(run=name, created=f"2026-01-0{k + 1} 10:00:00",
                       timings={"a<b>": 1.25, "total": 3.0 + k})
        made, kept = tmp_path / f"made{k}" / "run", tmp_path / f"kept{k}" / "run"
        pages: dict[str, bytes] = {}
        for folder, keep in ((made, None), (kept, pages)):
            write_results(folder, False, summary, first.episodes,
                          pd.read_parquet(first.folder / "labels.parquet"),
                          pd.read_parquet(first.folder / "trajectories.parquet"),
                          first.scores, segments=pd.read_parquet(first.folder /
                                                                 "segments.parquet"),
                          roads=pd.read_parquet(first.folder / "roads.parquet"), pages=keep)
        assert files(made) == files(kept)
        assert set(pages) == {"nonce", *run_cache.PAGES}
        for page in run_cache.PAGES:
            nonce = pages["nonce"].decode()
            assert nonce.encode() in pages[page]
            assert run_cache.fill_page(page, pages[page], nonce, summary) == \
                (made / page).read_bytes()


def test_the_timings_table_is_the_reports_table():
    from tap_bench.bench.report.tables import html_table

    timings = {"rollouts_wall": 12.345, "a<b>": 0.04, "total": 100.0}
    table = pd.DataFrame({"stage": list(timings),
                          "seconds": [f"{v:.1f} s" for v in timings.values()]})
    assert run_cache.timings_html(timings) == "<h3>Timings</h3>" + html_table(
        table, table_id="timings", max_rows=50,
        caption="Wall time per stage; *_cpu_in_workers add up over the worker processes.")
    assert run_cache.timings_html({}) == ""


def _thresholds_file(tmp_path):
    from tap_bench.thresholds import PRESETS, save_thresholds

    paper = PRESETS["paper"]
    name = next(f.name for f in dataclasses.fields(paper)
                if isinstance(getattr(paper, f.name), float))
    path = tmp_path / "other.json"
    save_thresholds(dataclasses.replace(paper, **{name: getattr(paper, name) * 1.5}), path)
    return str(path)


def _policy_file(tmp_path):
    from tap_bench.sim.policies import get_definition

    doc = json.loads(get_definition("idm").path.read_text())
    doc["params"]["time_wanted"] = 2.0
    path = tmp_path / "idm.json"
    path.write_text(json.dumps(doc))
    return str(path)


def _changed_measure(monkeypatch):
    from tap_bench.bench.measures import MEASURES

    entries = dict(MEASURES._entries)
    entries["mean_speed"] = dataclasses.replace(entries["mean_speed"], label="fastest")
    monkeypatch.setattr(MEASURES, "_entries", entries)


# each: (what changes, how: a suite and run arguments, or a change of the process)
CHANGES = {
    "seeds": lambda tmp, mp: ({"seeds": "0-2"}, {}),
    "seeds given": lambda tmp, mp: ({}, {"seeds": "1-2"}),
    "an env's config": lambda tmp, mp: ({"envs": ["merge", "highway"], "env_overrides": {
        "merge": {"duration": 3},
        "highway": {"duration": 3, "config": {"vehicles_count": 12}}}}, {}),
    "a policy's file": lambda tmp, mp: ({"policies": [_policy_file(tmp), "lane-keeping"],
                                         "reference_policy": "lane-keeping"}, {}),
    "the thresholds": lambda tmp, mp: ({"thresholds": _thresholds_file(tmp)}, {}),
    "the level": lambda tmp, mp: ({"level": "trend"}, {}),
    "the bootstrap": lambda tmp, mp: ({"bootstrap": {"n_resamples": 300}}, {}),
    "the gate": lambda tmp, mp: ({"gate": {"margins": {"mean_speed": 0.5}}}, {}),
    "the reference": lambda tmp, mp: ({"reference_policy": "lane-keeping"}, {}),
    "the suite's name": lambda tmp, mp: ({"name": "tiny2"}, {}),
    "no trajectories": lambda tmp, mp: ({}, {"keep_trajectories": False}),
    "no report": lambda tmp, mp: ({}, {"report": False}),
    "a measure entry": lambda tmp, mp: (_changed_measure(mp) or {}, {}),
    "the package code": lambda tmp, mp: (mp.setattr(cache_module, "_PACKAGE_CODE", ["other"])
                                         or mp.setattr(cache_module, "_package_digest",
                                                       lambda: "other") or {}, {}),
    "the package data": lambda tmp, mp: (mp.setattr(run_cache, "_PACKAGE_DATA", ["other"])
                                         or mp.setattr(run_cache, "_package_data_digest",
                                                       lambda: "other") or {}, {}),
    "a library version": lambda tmp, mp: (mp.setattr(
        run_cache, "_version", lambda pkg: "0.0" if pkg == "scipy" else
        cache_module._version(pkg)) or {}, {}),
}


@pytest.fixture(scope="module")
def without_report(runs, tmp_path_factory):
    """A cache holding a run of ``tiny()`` made without its report (the episodes read from
    ``runs``' cache): the changes below are made against it, since the report is
    most of a run's CPU and these tests compare the tables and the summary, not the page."""
    root = tmp_path_factory.mktemp("noreport")
    shutil.copytree(runs[3].root, root / "cache")
    cache = EpisodeCache(root / "cache")
    assert not served(run(root / "first", cache, report=False))
    return cache


COLD_IN_THE_FAST_SUITE = {"seeds", "a policy's file", "the thresholds", "the bootstrap",
                          "no report", "no trajectories"}
"""The changes whose missed run is compared with a cold run in the fast suite, one of each
kind: episodes simulated anew for some seeds or one policy, labels made again, scores made
again, other outputs. Every change's missed run is compared with a cold one in the slow
suite."""


KEY_IN_THE_FAST_SUITE = {"seeds given", "the level", "the reference", "an env's config"}
"""The changes whose runs are in the slow suite only: the fast suite checks that each moves
the run's key (test_the_key_holds_every_input, no run), and a missed and served run of the
same kind of change (a suite field, the seeds, the env) runs there ("seeds", "the
thresholds", "the suite's name")."""


def _change_cases():
    for change in sorted(CHANGES):
        if change in COLD_IN_THE_FAST_SUITE:
            yield pytest.param(change, True, id=change)
        else:
            slow = (pytest.mark.slow,) if change in KEY_IN_THE_FAST_SUITE else ()
            yield pytest.param(change, False, id=change, marks=slow)
            yield pytest.param(change, True, id=f"{change}, cold", marks=pytest.mark.slow)


@pytest.mark.parametrize(("change", "cold_too"), _change_cases())
def test_every_input_that_changes_an_output_misses(runs, without_report, tmp_path, monkeypatch,
                                                   change, cold_too):
    """The changed run misses, and is served when run again; the run made on the miss (and
    the served one) equals a cold run of the changed suite (without a cache)."""
    suite_changes, kwargs = CHANGES[change](tmp_path, monkeypatch)
    if change == "no report":  # against the run with its report
        cache = runs[3]
    else:
        cache, kwargs = without_report, {"report": False, **kwargs}
    # each case on its own copy: a case's kept entry must not serve the next case of the same
    # change (its cold variant), which must miss as well
    shutil.copytree(cache.root, tmp_path / "cache")
    cache = EpisodeCache(tmp_path / "cache")
    suite = tiny(**suite_changes)
    warm = run(tmp_path / "warm", cache, suite, **kwargs)
    assert not served(warm), change
    again = run(tmp_path / "again", cache, suite, **kwargs)  # now kept: served
    assert served(again)
    assert_tables_equal(warm, again)
    if cold_too:
        cold = run(tmp_path / "cold", None, suite, **kwargs)
        assert_tables_equal(cold, warm)


def run_key(cache, suite, keep=True, report=True, seeds=None):
    """The key of a run's entry."""
    from tap_bench.bench.run.plan import _tasks, plan_suite

    plan = plan_suite(suite, seeds=seeds)
    inputs = run_cache.run_inputs(plan, _tasks(plan, keep, cache), keep_trajectories=keep,
                                  report=report)
    return derived_key("runs", inputs)[0]


def test_the_key_holds_every_input(runs):
    """The keys of runs that differ in one input differ (no run needed)."""
    cache = runs[3]

    def key(suite, **kwargs):
        return run_key(cache, suite, **kwargs)

    base = key(tiny())
    assert key(tiny()) == base
    two = {"merge": {"duration": 3}, "highway": {"duration": 3}}
    variants = [key(tiny(seeds="0-2")), key(tiny(), seeds="1"), key(tiny(level="trend")),
                key(tiny(reference_policy="lane-keeping")), key(tiny(), keep=False),
                key(tiny(), report=False), key(tiny(description="other")),
                key(tiny(bootstrap={"n_resamples": 200, "seed": 7})),
                key(tiny(envs=["merge", "highway"], env_overrides=two)),
                key(tiny(envs=["highway", "merge"], env_overrides=two)),
                key(tiny(env_overrides={"merge": {"duration": 4}})),
                key(tiny(env_overrides={"merge": {"duration": 3,
                                                  "config": {"collision_reward": -2}}}))]
    assert len({base, *variants}) == len(variants) + 1


@pytest.mark.parametrize("damage", [
    "torn", "foreign",
    # a bit flipped and an emptied file (1.4 CPU s each): the reader every entry kind shares
    # refuses them in the fast suite (tests/faults/test_cache_entries.py::
    # test_a_malformed_entry_is_refused_deleted_and_named, "payload bit flipped" and "empty
    # file"; derived entries torn, flipped or emptied: test_derived_cache.py::
    # test_a_damaged_entry_is_made_again)
    pytest.param("flipped", marks=pytest.mark.slow),
    pytest.param("emptied", marks=pytest.mark.slow)])
def test_a_damaged_run_entry_is_made_again(runs, tmp_path, damage):
    _, cold, _, cache = runs
    mine = EpisodeCache(tmp_path / "cache")
    shutil.copytree(cache.root, mine.root)
    entry = mine.derived_path("runs", run_key(mine, tiny()))
    data = entry.read_bytes()
    entry.write_bytes({"torn": data[:-11], "flipped": data[:-9] + bytes([data[-9] ^ 4])
                       + data[-8:], "emptied": b"",
                       "foreign": (mine.derived_folder / "scores").glob("*/*").__next__()
                       .read_bytes()}[damage])
    result = run(tmp_path / "run", mine)
    assert not served(result)
    assert_tables_equal(cold, result)
    assert run(tmp_path / "again", mine).summary["cache"]["run"] == "served whole"


def test_a_run_entry_that_is_not_a_run_is_made_again(runs, tmp_path):
    """A whole, checksummed entry whose files are not a run's (another version wrote it)."""
    _, cold, _, cache = runs
    mine = EpisodeCache(tmp_path / "cache")
    shutil.copytree(cache.root, mine.root)
    entry = mine.derived_path("runs", run_key(mine, tiny()))
    header = json.loads(entry.read_bytes().partition(b"\n")[0])
    mine.put_derived("runs", header["key"], header["doc"], {"pages.json": b"{}"})
    result = run(tmp_path / "run", mine)
    assert not served(result)
    assert_tables_equal(cold, result)


def test_a_served_run_never_replaces_a_folder_unless_asked(runs, tmp_path):
    from tap_bench.errors import OutputPathError

    _, _, _, cache = runs
    assert served(run(tmp_path / "run", cache))
    before = files(tmp_path / "run")
    with pytest.raises(RunExistsError):
        run(tmp_path / "run", cache)
    assert files(tmp_path / "run") == before
    assert served(run(tmp_path / "run", cache, overwrite=True))
    (tmp_path / "run" / "mine.txt").write_text("kept")  # not tap-bench's: never deleted
    with pytest.raises(OutputPathError, match=r"mine\.txt"):
        run(tmp_path / "run", cache, overwrite=True)
    assert (tmp_path / "run" / "mine.txt").read_text() == "kept"
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "thesis.tex").write_text("mine")
    with pytest.raises(OutputPathError, match="not written by tap-bench"):
        run(tmp_path / "other", cache, overwrite=True)
    assert (tmp_path / "other" / "thesis.tex").read_text() == "mine"


def test_runs_that_cannot_be_keyed_are_never_kept(tmp_path, monkeypatch):
    from tap_bench.bench.measures import MEASURES
    from tap_bench.bench.run import tasks as run_tasks

    # an episode failed: tried again next run, never served as failed
    cache = EpisodeCache(tmp_path / "cache")
    real = run_tasks.rollout_episode

    def flaky(scenario, definition, seed):
        if seed == 1:
            raise RuntimeError("a worker's bad day")
        return real(scenario, definition, seed)

    monkeypatch.setattr(run_tasks, "rollout_episode", flaky)
    suite = tiny(envs=["merge"], env_overrides={"merge": {"duration": 3}})
    result = run(tmp_path / "failed", cache, suite, report=False)
    assert result.summary["n_failed"] > 0
    assert not (cache.derived_folder / "runs").exists()
    monkeypatch.setattr(run_tasks, "rollout_episode", real)
    assert not served(run(tmp_path / "ok", cache, suite, report=False))
    assert served(run(tmp_path / "ok2", cache, suite, report=False))
    # a measure registered by the user's script (not tap-bench's code): never kept whole
    entry = dataclasses.replace(MEASURES["mean_speed"], name="script_speed")
    entries = dict(MEASURES._entries)
    entries["script_speed"] = dataclasses.replace(entry, function=lambda *a: None)
    monkeypatch.setattr(MEASURES, "_entries", entries)
    assert run_cache.registered_outside() == [
        f"measure script_speed ({__name__})"]
    from tap_bench.bench.run.plan import _tasks, plan_suite

    plan = plan_suite(suite)
    assert run_cache.run_inputs(plan, _tasks(plan, True, cache), keep_trajectories=True,
                                report=True) is None


def _modules_after(code: str, cache: Path, cwd: Path) -> tuple[set[str], str]:
    script = (f"import sys\n{code}\nimport json\n"
              "print(json.dumps(sorted(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", script], cwd=cwd, check=True,
                         capture_output=True, text=True,
                         env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin",
                              "TAP_BENCH_CACHE": str(cache), "OMP_WAIT_POLICY": "PASSIVE"})
    lines = out.stdout.strip().splitlines()
    return set(json.loads(lines[-1])), "\n".join(lines[:-1])


def test_the_command_line_serves_without_numpy_pandas_gymnasium_scoring_or_report(runs,
                                                                                  tmp_path):
    """``bench run`` in a fresh process, its suite's run kept whole in the cache (the module's
    run of the same suite, made in this process, where a first child process made it in
    2.3 CPU s more), serves it without importing what a run makes its outputs with."""
    _, _, first, cache = runs
    suite = tmp_path / "tiny.json"
    suite.write_text(json.dumps({
        "name": "tiny", "envs": ["merge"], "policies": ["idm", "lane-keeping"], "seeds": "0-1",
        "reference_policy": "idm", "env_overrides": {"merge": {"duration": 3}},
        "bootstrap": {"n_resamples": 200}}))
    shutil.copytree(cache.root, tmp_path / "cache")
    # with highway-env's defaults as this process keeps them (read when the run was made
    # here), as a first run from the command line would have left them in its cache folder
    from tap_bench.sim import schema

    shutil.copy(schema._path(), tmp_path / "cache")
    call = ("from tap_bench.cli import main\n"
            f"main(['bench', 'run', '--suite', {str(suite)!r}, '-o', {str(tmp_path / 'b')!r}, "
            "'--no-progress', '--workers', '1'])")
    modules, said = _modules_after(call, tmp_path / "cache", tmp_path)
    assert "served from the cache" in said and "served whole" in said
    heavy = {"tap_bench.bench.scores.scoring", "tap_bench.bench.report.page",
             "tap_bench.bench.report.viewer",
             "tap_bench.bench.run.runner", "tap_bench.labelling", "highway_env", "scipy",
             "matplotlib", "numba", "google.protobuf", "pandas", "pyarrow", "gymnasium", "numpy"}
    assert not modules & heavy, modules & heavy
    assert {p.relative_to(first.folder).as_posix() for p in first.folder.rglob("*")} \
        == {p.relative_to(tmp_path / "b").as_posix() for p in (tmp_path / "b").rglob("*")}
    text = (tmp_path / "b" / "report.html").read_text()
    assert re.search(r"<h1>tap-bench run b</h1>", text)


def test_a_policy_changed_while_the_run_goes_on_is_not_kept(tmp_path, monkeypatch):
    """A policy's file changed during a run (a model retrained in place, a module edited):
    a worker may load the new content, so nothing made after the change is kept under the
    key of the content the run started with; when the old content comes back (a checkout),
    the run is made again and equals a cold run, not served from what the new one made."""
    from tap_bench.bench.run import tasks as run_tasks
    from tap_bench.bench.run.plan import _tasks, plan_suite

    cache = EpisodeCache(tmp_path / "cache")
    path = Path(_policy_file(tmp_path))
    original = path.read_text()
    suite = tiny(envs=["merge"], env_overrides={"merge": {"duration": 3}},
                 policies=[str(path), "lane-keeping"], reference_policy="lane-keeping")
    keys = {(t.policy, t.seed): t.key for t in _tasks(plan_suite(suite), True, cache)}
    real = run_tasks.rollout_episode

    def retrained(scenario, definition, seed):
        out = real(scenario, definition, seed)
        doc = json.loads(original)
        doc["params"]["time_wanted"] = 0.8
        path.write_text(json.dumps(doc))
        return out

    monkeypatch.setattr(run_tasks, "rollout_episode", retrained)
    run(tmp_path / "during", cache, suite, report=False)
    assert not (cache.derived_folder / "runs").exists()
    kept = {k: cache.read(key)[0] is not None for k, key in keys.items()}
    assert kept == {k: k[0] == "lane-keeping" for k in keys}
    monkeypatch.setattr(run_tasks, "rollout_episode", real)
    path.write_text(original)  # the old content is back
    again = run(tmp_path / "again", cache, suite, report=False)
    assert not served(again)
    assert_tables_equal(run(tmp_path / "cold", None, suite, report=False), again)


def test_a_fingerprint_that_cannot_be_read_at_the_end_costs_only_reuse(tmp_path, monkeypatch):
    """A policy file that cannot be read any more when the run re-checks its inputs (removed
    mid-read, permissions changed, a package grown past what is hashed): the run still
    ends with its tables, equal to a cold run's, and nothing of it is kept in the cache
    (its content is not known to be the key's); review4."""
    from tap_bench.bench.run import tasks as run_tasks

    cache = EpisodeCache(tmp_path / "cache")
    path = Path(_policy_file(tmp_path))
    suite = tiny(envs=["merge"], env_overrides={"merge": {"duration": 3}},
                 policies=[str(path), "lane-keeping"], reference_policy="lane-keeping")
    real_rollout, real_fingerprint = run_tasks.rollout_episode, cache_module.policy_fingerprint
    unreadable = []

    def fingerprint(definition):
        if unreadable and definition.path is not None:
            raise PermissionError(13, "Permission denied", str(definition.path))
        return real_fingerprint(definition)

    def rollout(scenario, definition, seed):
        out = real_rollout(scenario, definition, seed)
        unreadable.append(True)  # from the first rollout on
        return out

    monkeypatch.setattr(run_tasks, "rollout_episode", rollout)
    monkeypatch.setattr(run_tasks, "policy_fingerprint", fingerprint)
    monkeypatch.setattr(run_cache, "policy_fingerprint", fingerprint)
    during = run(tmp_path / "during", cache, suite, report=False)
    assert (during.episodes["status"] == "ok").all()
    assert not (cache.derived_folder / "runs").exists()
    monkeypatch.undo()
    assert_tables_equal(run(tmp_path / "cold", None, suite, report=False), during)


def test_a_vehicle_class_changed_while_the_run_goes_on_is_not_kept(tmp_path, monkeypatch):
    """A user vehicle class the scenario names (its module hashed in the episode's key)
    edited during a run: a worker process imports it at its first episode, maybe after the
    edit, so no episode or label made after the change is kept under the key of the code
    the run started with, as for a policy changed mid-run; review4."""
    import uuid

    from tap_bench.bench.run import tasks as run_tasks
    from tap_bench.bench.run.plan import _tasks, plan_suite

    package = f"cars_{uuid.uuid4().hex[:8]}"
    (tmp_path / package).mkdir()
    (tmp_path / package / "__init__.py").write_text("")
    module = tmp_path / package / "vehicles.py"
    module.write_text("from highway_env.vehicle.behavior import IDMVehicle\n\n\n"
                      "class MyVehicle(IDMVehicle):\n    TIME_WANTED = 1.2\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps({
        "name": "scene", "version": 1, "highway_env_id": "highway-v0", "description": "d",
        "duration": 3, "default_seeds": "0-1", "lane_change": "realistic",
        "config": {"lanes_count": 2, "vehicles_count": 4,
                   "other_vehicles_type": f"{package}.vehicles.MyVehicle"}}))
    cache = EpisodeCache(tmp_path / "cache")
    suite = tiny(envs=[str(scene)], env_overrides={}, policies=["idm", "lane-keeping"],
                 reference_policy="idm")
    keys = {(t.policy, t.seed): t.key for t in _tasks(plan_suite(suite), True, cache)}
    assert all(keys.values())
    real = run_tasks.rollout_episode

    def edited(scenario, definition, seed):
        out = real(scenario, definition, seed)
        module.write_text(module.read_text().replace("1.2", "2.4"))
        return out

    monkeypatch.setattr(run_tasks, "rollout_episode", edited)
    run(tmp_path / "during", cache, suite, report=False)
    assert not (cache.derived_folder / "runs").exists()
    assert not any(cache.read(key)[0] is not None for key in keys.values())


def test_tap_bench_or_its_data_edited_while_the_run_goes_on_keeps_nothing_of_the_run(
        tmp_path, monkeypatch):
    """Three things in one cache, one run after another (each run's key would serve the
    next; the runs an edit leaves out are made again):

    - The run's key holds tap-bench's code as hashed at its start; the report, the viewer
      and scoring are imported later. Edited in between, the run is written but not kept
      whole. Workers import the labelling and simulation code at their first episode,
      perhaps after the edit; their episode and label entries would be kept under keys
      naming the code as it was when the run started: edited mid-run, nothing of the run
      stays in the cache, and the entries of earlier runs do.
    - The package's data files (the viewer's page, script, style) are hashed into the run's
      key at its start and the viewer is written at its end: edited in between, the run is
      written but not kept whole, so a later run on the old files is not served the new
      ones.
    - Unedited, the same run is kept whole (made, then served)."""
    cache = EpisodeCache(tmp_path / "cache")
    suite = tiny(envs=["merge"], env_overrides={"merge": {"duration": 3}})
    start = cache_module.package_code()
    before = run(tmp_path / "before", cache, tiny(envs=["merge"], seeds="5",
                                                  env_overrides={"merge": {"duration": 3}}))
    kept = {p for p, _ in cache._entries()}
    assert kept and not served(before)

    def whole_runs() -> set[Path]:
        return set((cache.derived_folder / "runs").rglob("*.derived"))

    kept_whole = whole_runs()
    assert len(kept_whole) == 1  # the earlier run's
    put_derived, stored = EpisodeCache.put_derived, []

    def spy(self, kind, *args):  # a run entry written, even if dropped later on
        stored.append(kind)
        return put_derived(self, kind, *args)

    monkeypatch.setattr(EpisodeCache, "put_derived", spy)
    # tap-bench's code edited mid-run
    monkeypatch.setattr(cache_module, "_package_digest", lambda: "edited mid-run")
    result = run(tmp_path / "edited", cache, suite)
    assert (tmp_path / "edited" / "summary.json").exists() and not served(result)
    assert whole_runs() == kept_whole and "runs" not in stored
    assert {p for p, _ in cache._entries()} == kept  # the earlier run's, not this one's
    monkeypatch.setattr(cache_module, "_package_digest", lambda: start)
    # the viewer's files edited mid-run: the digest taken at the start differs from the
    # files at the end
    monkeypatch.setattr(run_cache, "_PACKAGE_DATA", ["the files at the start"])
    result = run(tmp_path / "edited-data", cache, suite)
    assert (tmp_path / "edited-data" / "summary.json").exists() and not served(result)
    assert whole_runs() == kept_whole and "runs" not in stored
    monkeypatch.setattr(run_cache, "_PACKAGE_DATA", [])  # unchanged from start to end
    assert not served(run(tmp_path / "kept", cache, suite))
    assert {p for p, _ in cache._entries()} > kept and len(whole_runs()) == 2
    assert "runs" in stored
    assert served(run(tmp_path / "served", cache, suite))
