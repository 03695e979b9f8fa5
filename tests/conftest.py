"""Every test session gets its own tap-bench cache folder (episodes of ``bench run``,
highway-env's defaults): runs in one session never reuse episodes another session, or the
developer's own runs, left in ``~/.cache/tap-bench``.

The fixtures every test folder shares live here, once: the real WOMD samples
(``womd_dir``), a small hand-made trajectory table (``two_cars_and_a_walker``) and tiny
scenario files (``write_scenario``).

Property tests (hypothesis) run under the ``ci`` profile unless told otherwise: derandomized,
so every run of the suite draws the same examples (a failure is the commit's, reproducible,
never a new draw's) and costs the same CPU, and no example database is written. Each test
sets its own ``max_examples``. ``pytest --hypothesis-profile=explore`` draws fresh examples
each run (and keeps failing ones in ``.hypothesis/``), to search further by hand."""

from __future__ import annotations

import functools
import json
import os
import re
import shutil
import signal
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest


def _hypothesis_left_unrewritten() -> None:
    """pytest rewrites the asserts of every module of a package that gives it a plugin
    (hypothesis' ``_hypothesis_pytestplugin``), hypothesis' own 100-odd modules included,
    in every process that imports them (the controller and each xdist worker), again in
    each run where ``PYTHONDONTWRITEBYTECODE`` keeps pytest from caching what it rewrote
    (the cost: docs/contributing.md, "The test suite's cost"). hypothesis is imported just
    below, its modules then unrewritten: its asserts are its own checks, never a test's,
    and their messages are unchanged. The suite's tests and conftest files are rewritten as
    before. Nothing here can fail the session (under a pytest whose internals differ,
    hypothesis is rewritten as before)."""
    import sys

    for hook in sys.meta_path:
        must = getattr(hook, "_must_rewrite", None)
        if isinstance(must, set):
            must.difference_update({"hypothesis", "_hypothesis_globals",
                                    "_hypothesis_ftz_detector"})
            getattr(hook, "_marked_for_rewrite_cache", {}).clear()


_hypothesis_left_unrewritten()
from hypothesis import settings  # noqa: E402  (after the function above)

# OpenMP's idle threads (torch's, in the in-process training tests) sleep instead of spinning
# on the other core, in this process and the processes it starts, as tap-bench's own workers
# and every measurement of the suite's CPU have them (unless the caller set it).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

settings.register_profile("ci", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", derandomize=False, print_blob=True)
settings.load_profile("ci")

PROJECT_ROOT = Path(__file__).resolve().parents[1]
WOMD_DIR = (PROJECT_ROOT / ".." / "shared" / "data" / "womd").resolve()
"""The real WOMD samples: read from there, never copied into the project (Waymo's terms)."""

_CACHE = tempfile.mkdtemp(prefix="tap-bench-test-cache-")


def _compile_tap_bench() -> None:
    """Write the bytecode of tap-bench's modules (``__pycache__``, checked by the source's
    hash) where it is missing or stale, once a session, before any worker starts.

    Where ``PYTHONDONTWRITEBYTECODE`` is set (as in some containers) Python writes none, so
    each of the suite's hundreds of processes (xdist workers, ``bench run`` children, their
    worker processes) compiled tap-bench's source again: about 0.7 CPU s a child, a quarter
    of the CPU of tests/faults' child runs. Python reads bytecode whatever that setting; a
    module edited since is compiled afresh (its hash no longer matches), so nothing stale
    is ever run. Nothing is written where the tree is read-only."""
    import importlib.util
    import py_compile

    flags = (3).to_bytes(4, "little")  # hash-based, checked against the source
    for source in sorted((PROJECT_ROOT / "tap_bench").rglob("*.py")):
        cached = Path(importlib.util.cache_from_source(str(source)))
        try:
            with open(cached, "rb") as stream:
                head = stream.read(16)
            if head == (importlib.util.MAGIC_NUMBER + flags
                        + importlib.util.source_hash(source.read_bytes())):
                continue
        except OSError:
            pass
        py_compile.compile(str(source), cfile=str(cached), quiet=2,
                           invalidation_mode=py_compile.PycInvalidationMode.CHECKED_HASH)


def _rewrite_test_modules(config) -> None:
    """Write pytest's rewritten bytecode of the suite's test modules and conftest files
    (``__pycache__/*-pytest-*.pyc``, checked by the source's mtime and size) where it is
    missing or stale, once a session, before any worker starts.

    Where ``PYTHONDONTWRITEBYTECODE`` is set, pytest writes none, so each process that
    collects the suite (each xdist worker) rewrote the asserts of every test module again:
    about 14 CPU s of a worker's 20 s of collection. pytest reads such bytecode whatever
    that setting, and rewrites a module edited since. Nothing here can fail the session
    (pytest's own rewriting is the fallback), and nothing is written where the tree is
    read-only. Only the suite's own tree is written: the installed packages of pytest's
    plugins are left as the setting asks (pytest rewrites them in each process)."""
    if config.getoption("assertmode", "rewrite") != "rewrite":
        return
    try:
        from _pytest.assertion import rewrite

        state = config.stash[rewrite.assertstate_key]
        suite = [source for source in sorted(Path(__file__).parent.rglob("*.py"))
                 if source.name.startswith("test_") or source.name == "conftest.py"]
        for source in suite:
            folder = rewrite.get_cache_dir(source)
            pyc = folder / (source.name[:-3] + rewrite.PYC_TAIL)
            if not source.is_file() or rewrite._read_pyc(source, pyc) is not None:
                continue
            if not rewrite.try_makedirs(folder):
                continue
            stat, code = rewrite._rewrite_test(source, config)
            rewrite._write_pyc(state, code, stat, pyc)
    except Exception:  # another pytest's internals: its workers rewrite as before
        return


def _compile_kernels() -> None:
    """Compile tap-bench's numba kernels into their cache (``__pycache__``) once, in this
    process, by a short WOMD episode with IDM and with log traffic and a nearest-neighbour
    search: about 25 CPU s on a fresh checkout, 4 s when the cache holds them.

    On a fresh checkout every process of the suite that ran a kernel before another had
    cached it compiled it itself: the two workers at once, and each child process and pool
    worker of the early tests. Four test files of tests/sim and tests/bench took 37 CPU s
    more with an empty cache than with a full one, where one process compiles all the
    kernels they use in about 18 s. A kernel this misses is compiled when first run, as
    before; nothing here can fail the session (a failure is printed and the suite goes on)."""
    import sys

    womd = WOMD_DIR / "motion_data_one_scenario.tfrecord"
    try:
        from tap_bench.sim.rollout import rollout
        from tap_bench.sim.womd_env import make_womd_env
        from tap_bench.similarity import Shapes, ade_nearest, dtw_nearest

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if womd.is_file():
                for traffic in ("idm", "log"):
                    rollout(make_womd_env(womd, traffic=traffic), "idm", [0], duration=2,
                            progress=False)
            rng = np.random.default_rng(0)
            lines = [np.cumsum(rng.normal(1.0, 0.3, (n, 2)), axis=0) for n in (8, 11, 9)]
            points = np.concatenate(lines)
            shapes = Shapes(points=points, offsets=np.cumsum([0] + [len(p) for p in lines]),
                            speed=np.zeros(len(points)), t=np.zeros(len(points)),
                            keys=pd.DataFrame(index=range(len(lines))))
            ade_nearest(shapes)
            dtw_nearest(shapes)
    except Exception as error:  # the tests of that code will say what is wrong
        print(f"conftest: compiling the kernels before the workers start failed ({error!r}); "
              "each process compiles what it runs", file=sys.stderr)


def _kernels_cached() -> bool:
    """Whether numba's cache holds an index for each of tap-bench's cached kernels (a
    decorator line with ``cache=True``: ``<module>.<kernel>-<its line>.py*.nbi`` in its
    folder's ``__pycache__``) written since its module was last changed. Then every process
    reads the kernels from the cache, and :func:`_compile_kernels` would only cost its
    rollouts (about 2 CPU s). A kernel this misses (a decorator over several lines, a
    signature not yet compiled) is compiled when first run, as before."""
    for source in sorted((PROJECT_ROOT / "tap_bench").rglob("*.py")):
        try:
            text = source.read_text(encoding="utf-8")
            since = source.stat().st_mtime
        except OSError:
            return False
        if "cache=True" not in text:
            continue
        folder = source.parent / "__pycache__"
        for number, line in enumerate(text.splitlines(), 1):
            if line.lstrip().startswith("@") and "cache=True" in line and not any(
                    index.stat().st_mtime >= since
                    for index in folder.glob(f"{source.stem}.*-{number}.py*.nbi")):
                return False
    return True


def pytest_configure(config) -> None:
    os.environ["TAP_BENCH_CACHE"] = _CACHE
    if not hasattr(config, "workerinput"):  # xdist's workers start after this
        _compile_tap_bench()
        _rewrite_test_modules(config)
        # -n: before the workers start, unless the cache holds every kernel already
        if getattr(config.option, "numprocesses", None) and not _kernels_cached():
            _compile_kernels()


def pytest_unconfigure(config) -> None:
    shutil.rmtree(_CACHE, ignore_errors=True)


def pytest_collection_finish(session) -> None:
    """Once the tests are collected, the objects alive (the modules imported, tap-bench's,
    the libraries' and the test modules', the collected tests) are moved out of the cyclic
    garbage collector's reach (``gc.freeze``, after one last collection): they live until
    the session ends, and each full collection of a pytest worker walked them all again
    (about 200,000 objects after the fast suite is collected). Objects made
    later are collected as before; nothing alive is ever freed either way.

    From then on the collector runs when 10,000 more objects than were freed were made
    (``gc.set_threshold(10_000, 10, 10)``) where Python's default is 700: in a worker of the
    fast suite it ran about 5,400 times and took 5.7 and 9.0 CPU s of the two workers' 551
    (gc.callbacks, 2eeb39a's tests); the tests made and dropped the same objects either
    way, a cycle of them being freed a few thousand allocations later. Child processes keep
    Python's default."""
    import gc

    gc.collect()
    gc.freeze()
    gc.set_threshold(10_000, 10, 10)


_CPU_RECORD = os.environ.get("TAP_BENCH_TEST_CPU")
"""A folder: when set, each process of the suite appends one JSON line per test to
``<folder>/<pid>.jsonl`` (the test's id, its CPU seconds in this process, those of the child
processes it reaped, and wall seconds, setup and teardown included), to see where the
suite's CPU goes. Processes that a test's children start and reap themselves count in
those children; Ray's processes, not children of the test's process, count nowhere."""


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    if not _CPU_RECORD:
        yield
        return
    import resource
    import time

    def cpu(who: int) -> float:
        usage = resource.getrusage(who)
        return usage.ru_utime + usage.ru_stime

    own, children = cpu(resource.RUSAGE_SELF), cpu(resource.RUSAGE_CHILDREN)
    wall = time.perf_counter()
    yield
    line = {"id": item.nodeid, "self": cpu(resource.RUSAGE_SELF) - own,
            "child": cpu(resource.RUSAGE_CHILDREN) - children,
            "wall": time.perf_counter() - wall}
    os.makedirs(_CPU_RECORD, exist_ok=True)
    with open(os.path.join(_CPU_RECORD, f"{os.getpid()}.jsonl"), "a") as stream:
        stream.write(json.dumps(line) + "\n")


@pytest.fixture(autouse=True, scope="module")
def _plugins_loaded_by_this_module_only():
    """The plugins a test module loaded (:func:`tap_bench.plugins.load_plugins`; a suite
    planned while a test module's own function was a registered measure records that test
    module as one) are forgotten when the module ends: every worker process the execution
    layer starts imports the loaded plugins first, so a test module recorded once made every
    later worker of that pytest process import it (pytest and much of tap-bench: about 1
    CPU s a worker; tests/execution's 20 worker starts took 40 CPU s in the suite against 4
    alone). What was imported stays imported in this process."""
    from tap_bench import plugins

    before = dict(plugins._LOADED)
    yield
    plugins._LOADED.clear()
    plugins._LOADED.update(before)


_RAY_FIXTURES = ("ray_backend", "ray_cluster")


@functools.cache
def uses_ray(test_file: str) -> bool:
    """Whether the test file ``test_file`` (a path from the project root, as in a test's
    node id) asks for the suite's Ray cluster (names the fixture ``ray_backend`` or
    ``ray_cluster``)."""
    try:
        source = (PROJECT_ROOT / test_file).read_text(encoding="utf-8")
    except OSError:
        return False
    return any(name in source for name in _RAY_FIXTURES)


_VIEWER_RUN_FIXTURES = ("tiny_run", "browser")
"""Session fixtures of the report and viewer tests: a finished run with its report and
viewer (about 2.5 CPU s to make; tests/viewer/conftest.py) and a headless Chromium
(:func:`browser`, about 1.3 CPU s to start)."""


@functools.cache
def uses_viewer_run(test_file: str) -> bool:
    """Whether a test of the test file ``test_file`` (a path from the project root) asks for
    tests/viewer's session run or the suite's browser (a test function's argument
    ``tiny_run`` or ``browser``)."""
    try:
        source = (PROJECT_ROOT / test_file).read_text(encoding="utf-8")
    except OSError:
        return False
    names = "|".join(_VIEWER_RUN_FIXTURES)
    return re.search(rf"^def test_\w*\([^)]*\b({names})\b", source, flags=re.M) is not None


@functools.cache
def uses_torch(test_file: str) -> bool:
    """Whether the test file ``test_file`` (a path from the project root) names
    Stable-Baselines3 (``stable_baselines3``: imported, or skipped without): its tests train
    or load agents, importing Stable-Baselines3 and torch (about 2.5 CPU s in a process,
    and torch's first calls). A file that only names it (in a child's script, say) is
    counted too: it then runs beside the others, at no cost but the workers' balance."""
    try:
        source = (PROJECT_ROOT / test_file).read_text(encoding="utf-8")
    except OSError:
        return False
    return "stable_baselines3" in source


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """Under pytest-xdist (``-n N``), each test file runs whole in one worker (xdist's
    ``--dist loadfile``) where ``-n`` alone would hand a file's tests to several workers in
    chunks: a file's module fixtures (the runs that many tests of a file compare) are then
    made once, not once in each worker that got some of its tests. The files that use the
    Ray cluster (:func:`uses_ray`) run together, one after the other in one worker, so that
    one cluster serves them all (:func:`ray_cluster`); so do the files that import
    Stable-Baselines3 and torch (:func:`uses_torch`), so that one worker imports them, where
    each worker that ran one of them did; and so do the files whose tests use the report and
    viewer tests' session run or browser (:func:`uses_viewer_run`), so that one worker makes
    the run and starts Chromium, where in most runs of the suite both workers did (the
    files split between them). Such a group is one unit of work:
    xdist hands out the units with the most tests first, so the groups start early and the
    workers end about together. ``--dist load`` (the default ``-n`` implies) becomes this,
    given or not; any other ``--dist`` is kept."""
    if config.getvalue("dist") != "load":
        return None
    from xdist.scheduler import LoadFileScheduling

    class FileAndRayScheduling(LoadFileScheduling):
        def _split_scope(self, nodeid: str) -> str:
            test_file = nodeid.split("::", 1)[0]
            if uses_ray(test_file):
                return "the Ray cluster's tests"
            if uses_viewer_run(test_file):
                return "the tests of the viewer's session run"
            return "the tests that import torch" if uses_torch(test_file) else test_file

    return FileAndRayScheduling(config, log)


class RayCluster:
    """The suite's local Ray cluster (2 CPUs, a 100 MB object store), started when a test
    first asks for it and stopped once the tests of the files that use it have run (a
    cluster started and stopped costs about 5 CPU s and its workers' imports; it was started
    once per package and per pytest worker, four times in a run of the suite)."""

    def __init__(self) -> None:
        self._backend = None

    @property
    def backend(self):
        """A :class:`tap_bench.execution.RayBackend` on the cluster, started if need be."""
        if self._backend is None:
            from tap_bench.execution import RayBackend

            self._backend = RayBackend(num_cpus=2, object_store_memory=100 << 20)
        return self._backend

    def stop(self) -> None:
        if self._backend is not None:
            import ray

            self._backend = None
            ray.shutdown()


_RAY = RayCluster()


@pytest.fixture(scope="session")
def ray_cluster() -> RayCluster:
    """The suite's Ray cluster (:class:`RayCluster`); skips where Ray is not installed."""
    pytest.importorskip("ray")
    yield _RAY
    _RAY.stop()


@pytest.fixture
def ray_backend(ray_cluster: RayCluster):
    """A :class:`tap_bench.execution.RayBackend` on the suite's local Ray cluster."""
    return ray_cluster.backend


@pytest.hookimpl(trylast=True)
def pytest_runtest_teardown(item, nextitem):
    """The Ray cluster stops after the last test of the files that use it (the next test is
    of another file, or none): its processes do not idle through the rest of the run."""
    if _RAY._backend is not None and (
            nextitem is None or not uses_ray(nextitem.nodeid.split("::", 1)[0])):
        _RAY.stop()


CHROMIUM: str | None = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER: str | None = shutil.which("chromedriver")
BROWSER_FLAGS = ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--window-size=1400,1000")

@pytest.fixture(scope="session")
def browser(tmp_path_factory):
    """Headless Chromium (Debian's chromium and chromium-driver) with its console log, one
    for the session: the report and viewer tests (tests/viewer, tests/bench/test_report_html.py)
    run in one pytest worker (:func:`uses_viewer_run`) and share it."""
    if not (CHROMIUM and CHROMEDRIVER):
        pytest.skip("needs Debian's chromium and chromium-driver (apt-get install chromium "
                    "chromium-driver; .ci/run installs them)")
    webdriver = pytest.importorskip("selenium.webdriver")
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (*BROWSER_FLAGS, f"--user-data-dir={tmp_path_factory.mktemp('profile')}"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_script_timeout(20)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture(scope="session")
def womd_dir() -> Path:
    """The folder of real WOMD samples (``../shared/data/womd``); skips when absent."""
    if not (WOMD_DIR / "motion_data_one_scenario.tfrecord").is_file():
        pytest.skip(f"real WOMD samples not found in {WOMD_DIR}")
    return WOMD_DIR


@pytest.fixture
def two_cars_and_a_walker() -> pd.DataFrame:
    """Two scenarios of 2 s: in ``s1`` an ego car driving +x at 10 m/s, a car turning left
    with a 5-step gap, and a pedestrian; in ``s2`` one parked car."""
    t = np.round(np.arange(20) * 0.1, 10)
    rows = []
    for i, tt in enumerate(t):
        rows.append(("s1", "100", tt, 10 * tt, 0.0, 0.0, 10.0, 0.0, "vehicle", True, True))
        heading = 0.2 * tt
        rows.append(("s1", "7", tt, 5 * tt, 3.0 + tt, heading, 5 * np.cos(heading),
                     5 * np.sin(heading), "vehicle", False, not 5 <= i < 10))
        rows.append(("s1", "8", tt, 1.0, 1.0 + 1.2 * tt, np.pi / 2, 0.0, 1.2, "pedestrian",
                     False, True))
        rows.append(("s2", "1", tt, 2.0, -4.0, -1.0, 0.0, 0.0, "vehicle", False, True))
    table = pd.DataFrame(rows, columns=["scenario_id", "track_id", "t", "x", "y", "heading",
                                        "vx", "vy", "object_type", "is_ego", "valid"])
    table["speed"] = np.hypot(table["vx"], table["vy"])
    return table


@pytest.fixture(autouse=True)
def _quiet_gymnasium_checker():
    # The passive checker warns that highway-env's AttributesObservation space is generic.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*within the observation space.*")
        warnings.filterwarnings("ignore", message=".*is not within the observation space.*")
        yield


@pytest.fixture(autouse=True)
def _sigint_kept(request):
    """A test that leaves this process's SIGINT handler changed (ignored, say) has it put
    back, with a warning naming the test: every process started later inherits an ignored
    SIGINT, and a test of Ctrl-C in a later test of the same pytest worker then fails."""
    before = signal.getsignal(signal.SIGINT)
    yield
    after = signal.getsignal(signal.SIGINT)
    if after is not before and after != before:
        signal.signal(signal.SIGINT, before)
        warnings.warn(f"{request.node.nodeid} left SIGINT's handler {after!r} (was {before!r}); "
                      "put back", stacklevel=1)


@pytest.fixture
def write_scenario(tmp_path: Path):
    """Write a scenario file (a dict, with overrides of a valid highway scenario) and return
    its path."""

    def write(name: str = "tiny", **fields) -> Path:
        doc = {"name": name, "version": 0, "highway_env_id": "highway-v0",
               "description": "test scenario", "duration": 2, "default_seeds": "0-2",
               "lane_change": "realistic",
               "config": {"lanes_count": 2, "vehicles_count": 3, "policy_frequency": 1}}
        doc.update(fields)
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(doc))
        return path

    return write
