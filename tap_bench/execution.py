"""Where work runs: one execution layer for every parallel job of tap-bench.

A backend maps a function over work items (episodes, shards, batches of records) and gives
one :class:`Outcome` per item, in the items' order: :meth:`Backend.map` as a list,
:meth:`Backend.imap` as a bounded stream (at most ``window`` items submitted beyond the one
the caller is waiting for, so memory stays flat however many items there are).

**The recovery rule**, the same on every backend: an item whose function raises, or whose
worker process dies, is tried again ``retries`` times (default once); an item that still
fails comes back as a failed outcome with its error, and every other item is kept. A dead
worker costs only the item it was running: each worker runs one item at a time, so the one
that killed it is known, and a fresh worker takes its place.

- :class:`LocalBackend`: this process (``workers=1``) or a pool of worker processes. Workers
  are fresh interpreters running :func:`_worker_main` (not ``multiprocessing``): they never
  re-import the caller's script, so the API works from a plain script without an
  ``if __name__ == "__main__":`` guard; a worker whose parent dies (even by SIGKILL) is sent
  SIGTERM by the kernel (Linux) or sees its input close, and exits, leaving no orphan. No
  semaphore, shared memory or resource-tracker process is involved.
- :class:`RayBackend`: Ray tasks on a running cluster (``address="auto"``) or on a local
  cluster it starts. Ray is optional (``pip install 'tap-bench[ray]'``) and imported only
  when a :class:`RayBackend` is made.

Functions and items must be picklable by reference (module-level functions, dataclasses),
since both backends run them in other processes. Every worker imports the plugins its parent
loaded (:func:`tap_bench.plugins.loaded_plugins`: the modules that register a user's
measures, formats and policy kinds) before its first item.
"""

from __future__ import annotations

import contextlib
import gc
import os
import pickle
import selectors
import signal
import struct
import subprocess
import sys
import time
import traceback
import warnings
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import IO, Any, Generic, Protocol, TypeVar, runtime_checkable

from tap_bench.errors import ParameterError, TapBenchError, did_you_mean
from tap_bench.plugins import ENV_VAR as PLUGINS_ENV
from tap_bench.plugins import load_plugins, loaded_plugins

__all__ = ["BACKENDS", "DEFAULT_RETRIES", "Backend", "LocalBackend", "Outcome", "RayBackend",
           "add_backend_arguments", "backend_from_args", "capped_workers", "check_workers",
           "close_backend", "describe_error", "keep_freed_memory", "make_backend",
           "usable_cores"]

T = TypeVar("T")
R = TypeVar("R")

BACKENDS = ("local", "ray")
DEFAULT_RETRIES = 1
"""Retries of a failed item after its first attempt: a dead worker or an error is tried once
more, then reported."""
DEFAULT_OBJECT_STORE_BYTES = 256 << 20
"""Object store of a local Ray cluster started here [B]: results are small summaries and
tables of one shard, and /dev/shm is small on many machines."""
WORKER_THREADS_ENV = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                      "OPENBLAS_NUM_THREADS": "1", "OMP_WAIT_POLICY": "PASSIVE"}
"""Environment of a worker process: one BLAS/OpenMP thread each (the workers are the
parallelism), and OpenMP threads that sleep rather than spin while they wait."""

KEEP_FREED_BYTES = 64 << 20
"""Allocations up to this size [B] come from the heap, and freed heap memory up to this
much is kept for reuse (see :func:`keep_freed_memory`)."""


_START_UP = {"freeze": False, "frozen": False}  # freeze_start_up's request and its end

YOUNG_COLLECTION_THRESHOLD = 10_000
"""The garbage collector's first threshold (allocations of container objects, less those
freed, between two collections of the youngest generation; CPython's default is 700) in a
process that called :func:`freeze_start_up`. A scene's objects are freed by reference
counting when the next scene replaces them (:meth:`tap_bench.sim.womd_road.WomdRoad.release`,
the env's ``close``), so rarer collections find little more garbage and the peak memory
does not grow (measured in docs/closed_loop.md, "The round of 2026-12-04, evening")."""


def freeze_start_up() -> None:
    """Keep what this process's start-up made out of the garbage collector's later full
    collections: once the first task run in this process has ended (:func:`_timed`), every
    object then alive is frozen (``gc.collect()``, then ``gc.freeze()``), once per process.

    Importing pandas, gymnasium, highway-env, numba and pyarrow, numba's registries and
    first kernels and the first scene's start leave some 170,000 objects that live as long
    as the process; every full collection walks them for nothing (docs/closed_loop.md,
    "The round of 2026-12-04"). Garbage made from then on is collected as before. From
    the call on, the youngest generation is collected every
    :data:`YOUNG_COLLECTION_THRESHOLD` allocations (the start-up's imports make objects that
    live as long as the process: the young collections among them found nothing). The
    command line asks for it when it runs as the process's program (``tap-bench``,
    ``python -m tap_bench``): a caller of :func:`tap_bench.cli.main` with its own arguments
    (a test, a notebook) keeps its objects collectable."""
    _START_UP["freeze"] = True
    gc.set_threshold(YOUNG_COLLECTION_THRESHOLD, *gc.get_threshold()[1:])


def _start_up_ended() -> None:
    """The freeze :func:`freeze_start_up` asked for, at the end of a task (the first one)."""
    if _START_UP["freeze"] and not _START_UP["frozen"]:
        _START_UP["frozen"] = True
        gc.collect()  # the start-up's garbage is freed, not frozen
        gc.freeze()


def idle_threads_sleep() -> None:
    """Let OpenBLAS's idle worker threads sleep at once instead of spinning.

    NumPy's OpenBLAS starts a worker thread per core when NumPy is imported, and each
    spins for 2^28 cycles (about 0.1 s) after it starts and after each BLAS call before it
    sleeps: CPU time of every command that imports NumPy, for no work (docs/tap.md).
    ``OPENBLAS_THREAD_TIMEOUT=4`` (2^4 cycles, OpenBLAS's least) unless set;
    the number of threads, and so how BLAS splits its work and every result, is unchanged.
    Read by OpenBLAS when NumPy is first imported: call it before.
    """
    os.environ.setdefault("OPENBLAS_THREAD_TIMEOUT", "4")


def keep_freed_memory() -> bool:
    """Let glibc's allocator keep freed memory for reuse instead of handing it back.

    By default glibc maps every allocation above 128 KiB to fresh pages and unmaps it when
    freed; a column of a million-row table (8 MB) is then faulted in page by page each time
    a temporary of its size is made: labelling 25,900 trajectories spent more CPU in the
    kernel (page faults, 1.5 s) than in the labelling itself. Allocations up to
    :data:`KEEP_FREED_BYTES` now come from the heap, which keeps freed memory (up to that
    much at its top) for the next allocation. The memory a command holds at its peak does
    not change. Arrow (Parquet reading and writing) takes its buffers from the same heap
    (``ARROW_DEFAULT_MEMORY_POOL=system`` unless set). Called by the command line and by
    every worker process; nothing happens on a C library without ``mallopt`` (macOS, musl).

    Returns:
        whether the allocator took the settings.
    """
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3
    kept = all([mallopt(m_mmap_threshold, KEEP_FREED_BYTES) == 1,
                mallopt(m_trim_threshold, KEEP_FREED_BYTES) == 1,
                mallopt(m_top_pad, 16 << 20) == 1])
    if kept:
        # Arrow's buffers from the same heap (its own allocator kept its memory apart and
        # faulted fresh pages in: reading and labelling 25,900 trajectories spent 1-2 s in
        # the kernel, 0.5 s with this); a pool the user chose is kept
        os.environ.setdefault("ARROW_DEFAULT_MEMORY_POOL", "system")
        if "pyarrow" in sys.modules and os.environ["ARROW_DEFAULT_MEMORY_POOL"] == "system":
            import pyarrow

            pyarrow.set_memory_pool(pyarrow.system_memory_pool())
    return kept


@dataclass(frozen=True)
class Outcome(Generic[R]):
    """The result of one work item.

    Attributes:
        item: index of the item in the mapped sequence.
        value: what the function returned (None when it failed).
        error: the last error, one line, or "" when it succeeded.
        attempts: attempts made (1 when it succeeded first time).
        seconds: wall time of the successful attempt, measured in the worker [s] (NaN when
            failed).
        cpu_seconds: CPU time of the worker process (all its threads) over that attempt [s]
            (NaN when failed); with ``seconds``, how much of a core the task got.
    """

    item: int
    value: R | None
    error: str = ""
    attempts: int = 1
    seconds: float = float("nan")
    cpu_seconds: float = float("nan")

    @property
    def ok(self) -> bool:
        return not self.error


@runtime_checkable
class Backend(Protocol):
    """Maps a function over work items under the recovery rule (module docstring)."""

    name: str

    @property
    def workers(self) -> int:
        """Processes (CPUs) the work is spread over."""

    def imap(self, fn: Callable[[T], R], items: Iterable[T], *,
             retries: int = DEFAULT_RETRIES, window: int | None = None, desc: str = "",
             unit: str = "item", progress: bool | None = None, total: int | None = None
             ) -> Iterator[Outcome[R]]:
        """``fn(item)`` for each item, yielded in the items' order, at most ``window``
        items in flight (None: twice the workers)."""

    def map(self, fn: Callable[[T], R], items: Sequence[T], *,
            retries: int = DEFAULT_RETRIES, desc: str = "", unit: str = "item",
            progress: bool | None = None) -> list[Outcome[R]]:
        """``fn(item)`` for each item; one :class:`Outcome` per item, in order."""


def describe_error(err: BaseException) -> str:
    """One line naming an exception: its type and message."""
    text = "".join(traceback.format_exception_only(type(err), err)).strip()
    return text.splitlines()[-1] if text else type(err).__name__


def _timed(fn: Callable[[T], R], item: T) -> tuple[R, float, float]:
    """``fn(item)``, its wall time and the CPU time of this process meanwhile [s]."""
    start, cpu = time.perf_counter(), time.process_time()
    value = fn(item)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    _start_up_ended()  # the first task ends the start-up (freeze_start_up)
    return value, wall, cpu


def _timed_with_plugins(plugins: tuple[str, ...], paths: tuple[str, ...],
                        fn: Callable[[T], R], item: T) -> tuple[R, float, float]:
    """:func:`_timed` in a Ray worker, after importing the parent's plugins (a no-op after
    the first task of the worker: Python's module cache). The parent's import path is added
    behind the worker's own, as a local worker gets it as PYTHONPATH, so a plugin found by
    the parent is found here (on a machine that has the same folders)."""
    if plugins:
        sys.path.extend(p for p in paths if p not in sys.path)
        load_plugins(plugins, source="worker")
    return _timed(fn, item)


def check_workers(workers: Any, name: str = "workers") -> int:
    """``workers`` as a positive int, or a :class:`ParameterError` naming it."""
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ParameterError(name, workers, "a positive integer (processes)")
    return workers


def usable_cores() -> int:
    """How many cores this process may run on (its CPU affinity where known)."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def capped_workers(workers: Any, name: str = "--workers") -> int:
    """``workers`` (checked: :func:`check_workers`) capped at :func:`usable_cores`, with a
    warning when it asked for more: local worker processes beyond the cores only take
    turns on them (and each holds its own memory)."""
    workers = check_workers(workers, name)
    cores = usable_cores()
    if workers > cores:
        warnings.warn(f"{name} {workers} is more than the {cores} core(s) this process may "
                      f"use; running {cores} worker(s) (more would only take turns on the "
                      "same cores).", UserWarning,
                      stacklevel=2)
        return cores
    return workers


def _check_retries(retries: Any) -> int:
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ParameterError("retries", retries, "an integer >= 0")
    return retries


def _bar(total: int | None, desc: str, unit: str, progress: bool | None) -> Any:
    from tap_bench.progress import progress_bar  # a bar, or lines where no terminal

    return progress_bar(total, desc, unit, progress)


class _Attempts:
    """Bookkeeping of the recovery rule: attempts per item and the outcome once settled."""

    def __init__(self, retries: int):
        self.retries = retries
        self.count: dict[int, int] = {}

    def settle(self, i: int, result: tuple[Any, float, float] | None, error: str
               ) -> Outcome | None:
        """Record an attempt of item ``i``: its outcome, or None when it is to be retried."""
        self.count[i] = self.count.get(i, 0) + 1
        if result is not None:
            value, seconds, cpu = result
            return Outcome(i, value, "", self.count[i], seconds, cpu)
        if self.count[i] > self.retries:
            return Outcome(i, None, error, self.count[i])
        return None


class _Window:
    """What every pool keeps the same way: items read from the source only as room frees up
    (at most ``size`` in flight beyond the one the caller waits for), attempts under the
    recovery rule, and outcomes released in the items' order."""

    def __init__(self, items: Iterable[Any], size: int, retries: int, bar: Any):
        self.source = enumerate(items)
        self.size = size
        self.attempts = _Attempts(retries)
        self.bar = bar
        self.waiting: deque[int] = deque()  # items to (re)submit, first come first served
        self.held: dict[int, Any] = {}  # items submitted or waiting, by index
        self.done: dict[int, Outcome] = {}  # finished, not yet released (order)
        self.next_out = 0
        self.exhausted = False

    def fill(self) -> None:
        """Read items from the source until the window is full."""
        while not self.exhausted and len(self.held) + len(self.done) < self.size + 1:
            try:
                i, item = next(self.source)
            except StopIteration:
                self.exhausted = True
                return
            self.held[i] = item
            self.waiting.append(i)

    def settle(self, i: int, result: tuple[Any, float, float] | None, error: str) -> None:
        """An attempt of item ``i`` ended: retried (back in the queue) or finished."""
        outcome = self.attempts.settle(i, result, error)
        if outcome is None:
            self.waiting.append(i)
        else:
            self.finish(outcome)

    def finish(self, outcome: Outcome) -> None:
        del self.held[outcome.item]
        self.done[outcome.item] = outcome
        self.bar.update(1)

    def release(self) -> Iterator[Outcome]:
        """The finished outcomes that are next in order."""
        while self.next_out in self.done:
            yield self.done.pop(self.next_out)
            self.next_out += 1

    @property
    def finished(self) -> bool:
        return self.exhausted and not self.held and not self.done


# -- local processes ---------------------------------------------------------------------
_HEADER = struct.Struct("<Q")


def _send(stream: IO[bytes], obj: Any) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)))
    stream.write(data)
    stream.flush()


def _receive(stream: IO[bytes]) -> Any:
    """The next message, or raise EOFError when the other side has gone."""
    header = stream.read(_HEADER.size)
    if len(header) < _HEADER.size:
        raise EOFError
    size = _HEADER.unpack(header)[0]
    data = stream.read(size)
    if len(data) < size:
        raise EOFError
    return pickle.loads(data)


class _Worker:
    """One worker process and the item it runs (None when idle)."""

    def __init__(self) -> None:
        env = {**os.environ, **WORKER_THREADS_ENV}
        env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p)
        env[PLUGINS_ENV] = ",".join(loaded_plugins())  # imported before the first item
        # Interrupts are the parent's to handle: a worker ignores the terminal's SIGINT and
        # ends when the parent closes its input or terminates it.
        self.process = subprocess.Popen(
            [sys.executable, "-c", "from tap_bench.execution import _worker_main; "
             "_worker_main()"], stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, env=env, cwd=os.getcwd(),
            preexec_fn=_worker_preexec if os.name == "posix" else None)
        self.running: int | None = None

    def submit(self, i: int, fn: Callable, item: Any) -> None:
        self.running = i
        _send(self.process.stdin, (fn, item))  # type: ignore[arg-type]

    def close(self, timeout: float = 2.0) -> None:
        """Stop the worker: close its input, then terminate and kill if it lingers."""
        process = self.process
        for stream in (process.stdin, process.stdout):
            try:
                stream.close()  # type: ignore[union-attr]
            except OSError:
                pass
        try:
            process.wait(timeout=timeout if self.running is None else 0.05)
        except subprocess.TimeoutExpired:
            process.terminate()
            try:
                process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def _worker_preexec() -> None:
    """In the new worker, before Python starts: ignore the terminal's SIGINT, and on Linux
    ask the kernel for SIGTERM when the parent dies, so that a worker busy with a long item
    does not outlive a parent killed by SIGKILL."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass  # the closed input still ends an idle worker


def _worker_main() -> None:
    """The loop of a worker process: read (fn, item), reply with the timed result."""
    import warnings

    keep_freed_memory()
    # The protocol owns the original stdout; what the work prints goes to stderr.
    output = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    source = sys.stdin.buffer
    warnings.simplefilter("ignore")  # the parent reports failures; workers stay quiet
    plugins = [name for name in os.environ.get(PLUGINS_ENV, "").split(",") if name]
    try:
        load_plugins(plugins, source="worker")
        broken = ""
    except Exception as err:  # every item says why, rather than a worker that dies
        broken = f"the worker cannot import the run's plugins: {describe_error(err)}"
    while True:
        try:
            fn, item = _receive(source)
        except EOFError:
            return  # the parent closed our input (or died): nothing is left to do
        except Exception as err:  # an item that cannot be unpickled here
            _send(output, ("error", f"cannot load the task in the worker: "
                                    f"{describe_error(err)}"))
            continue
        try:
            if broken:
                raise TapBenchError(broken)
            reply: tuple = ("ok", _timed(fn, item))
        except Exception as err:
            reply = ("error", describe_error(err))
        try:
            _send(output, reply)
        except (pickle.PicklingError, TypeError, AttributeError) as err:
            _send(output, ("error", f"the result cannot be sent back: {describe_error(err)}"))


@dataclass
class LocalBackend:
    """Work in this process (``workers=1``) or in a pool of ``workers`` worker processes.

    Workers start once per :meth:`imap` / :meth:`map` call (or once per :meth:`kept` block)
    and are reused for its items, so per-process caches (an env, a policy) pay off across
    items; each runs one item at a time. Workers are stopped when the call (or block) ends,
    also on an exception, Ctrl-C or SIGTERM (the command line turns SIGTERM into an
    interrupt).
    """

    processes: int = 1
    name: str = field(default="local", init=False)
    _kept: tuple[list[_Worker], Any] | None = field(default=None, init=False, repr=False,
                                                    compare=False)

    def __post_init__(self) -> None:
        check_workers(self.processes)

    @contextlib.contextmanager
    def kept(self) -> Iterator[LocalBackend]:
        """Within the block, this backend's :meth:`map` and :meth:`imap` calls share their
        worker processes: started by the first call that needs them, reused by the next,
        stopped when the block ends. A run that maps twice (its first episodes for the
        estimate, then the rest) starts its workers once. A worker busy when a call ends
        early (an error, an interrupt) is stopped, never reused."""
        if self._kept is not None:  # already kept by an enclosing block
            yield self
            return
        self._kept = ([], selectors.DefaultSelector())
        try:
            yield self
        finally:
            workers, selector = self._kept
            self._kept = None
            for worker in workers:
                worker.close()
            selector.close()

    @property
    def workers(self) -> int:
        return self.processes

    def map(self, fn: Callable[[T], R], items: Sequence[T], *,
            retries: int = DEFAULT_RETRIES, desc: str = "", unit: str = "item",
            progress: bool | None = None) -> list[Outcome[R]]:
        return list(self.imap(fn, items, retries=retries, window=len(items) or 1, desc=desc,
                              unit=unit, progress=progress, total=len(items)))

    def imap(self, fn: Callable[[T], R], items: Iterable[T], *,
             retries: int = DEFAULT_RETRIES, window: int | None = None, desc: str = "",
             unit: str = "item", progress: bool | None = None, total: int | None = None
             ) -> Iterator[Outcome[R]]:
        retries = _check_retries(retries)
        if total is None and isinstance(items, Sequence):
            total = len(items)
        with _bar(total, desc, unit, progress) as bar:
            if self.processes == 1:
                yield from self._inline(fn, items, retries, bar)
            else:
                yield from self._pool(fn, items, retries, window or 2 * self.processes, bar)

    @staticmethod
    def _inline(fn, items, retries, bar) -> Iterator[Outcome]:
        attempts = _Attempts(retries)
        for i, item in enumerate(items):
            outcome = None
            while outcome is None:
                try:
                    result, error = _timed(fn, item), ""
                except Exception as err:  # one failing item must not end the run
                    result, error = None, describe_error(err)
                outcome = attempts.settle(i, result, error)
            bar.update(1)
            yield outcome

    def _pool(self, fn, items, retries, size, bar) -> Iterator[Outcome]:
        window = _Window(items, size, retries, bar)
        kept = self._kept
        workers, selector = kept if kept is not None else ([], selectors.DefaultSelector())
        try:
            while True:
                window.fill()
                while window.waiting:
                    worker = next((w for w in workers if w.running is None), None)
                    if worker is None and len(workers) < self.processes:
                        worker = _Worker()
                        workers.append(worker)
                        selector.register(worker.process.stdout, selectors.EVENT_READ, worker)
                    if worker is None:
                        break
                    i = window.waiting.popleft()
                    try:
                        worker.submit(i, fn, window.held[i])
                    except (BrokenPipeError, OSError):
                        window.waiting.appendleft(i)  # the worker died idle: replace it
                        worker.running = None
                        self._retire(worker, workers, selector)
                    except (pickle.PicklingError, TypeError, AttributeError) as err:
                        worker.running = None
                        window.finish(Outcome(i, None, "the task cannot be sent to a worker: "
                                              f"{describe_error(err)}", 1))
                yield from window.release()
                if window.finished:
                    return
                if not any(w.running is not None for w in workers):
                    continue
                for key, _ in selector.select():
                    worker = key.data
                    i = worker.running
                    try:
                        status, payload = _receive(worker.process.stdout)
                    except (EOFError, OSError, pickle.UnpicklingError):
                        code = worker.process.poll()
                        worker.running = None
                        self._retire(worker, workers, selector)
                        window.settle(i, None, "the worker process died while running it"
                                      + (f" (exit code {code})" if code is not None else ""))
                    else:
                        worker.running = None
                        window.settle(i, payload if status == "ok" else None,
                                      "" if status == "ok" else payload)
        finally:
            if kept is None:
                for worker in workers:
                    worker.close()
                selector.close()
            else:  # kept for the next call: idle workers only
                for worker in [w for w in workers if w.running is not None]:
                    self._retire(worker, workers, selector)

    @staticmethod
    def _retire(worker: _Worker, workers: list[_Worker], selector: Any) -> None:
        try:
            selector.unregister(worker.process.stdout)
        except (KeyError, ValueError):
            pass
        worker.close(timeout=0.5)
        workers.remove(worker)


# -- Ray ------------------------------------------------------------------------------------
@dataclass
class RayBackend:
    """Ray tasks, one per item, on a running cluster or on a local one started here.

    Args:
        address: a running cluster (``"auto"``, ``"ray://head:10001"``, ``"10.0.0.1:6379"``);
            None starts a local cluster (or uses the one this process already joined).
        num_cpus: CPUs of a local cluster started here (None: all of this machine's).
        object_store_memory: object store of a local cluster started here [B].
        in_flight: items submitted at once (None: twice the cluster's CPUs).

    A worker that dies, or a function that raises, is resubmitted from here, so both count
    as attempts under the recovery rule.
    """

    address: str | None = None
    num_cpus: int | None = None
    object_store_memory: int = DEFAULT_OBJECT_STORE_BYTES
    in_flight: int | None = None
    name: str = field(default="ray", init=False)
    started: bool = field(default=False, init=False)

    def __post_init__(self) -> None:
        try:
            import ray  # optional: only a RayBackend needs it
        except ImportError as err:
            raise TapBenchError("the ray backend needs Ray: pip install 'tap-bench[ray]' "
                                "(or pip install 'ray[data]>=2.9').") from err
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
            if self.address is None:
                kwargs.update(num_cpus=self.num_cpus,
                              object_store_memory=self.object_store_memory)
            try:
                ray.init(address=self.address, **kwargs)
            except ConnectionError as err:
                raise TapBenchError(
                    f"cannot join the Ray cluster at --address {self.address!r}: {err}. "
                    "Start one with 'ray start --head', or leave out --address to start a "
                    "local cluster.") from err
            self.started = True

    @property
    def workers(self) -> int:
        import ray

        return max(1, int(ray.cluster_resources().get("CPU", 1)))

    def shutdown(self) -> None:
        """Leave the cluster (and stop it, when it was started here)."""
        import ray

        if self.started:
            ray.shutdown()
            self.started = False

    def map(self, fn: Callable[[T], R], items: Sequence[T], *,
            retries: int = DEFAULT_RETRIES, desc: str = "", unit: str = "item",
            progress: bool | None = None) -> list[Outcome[R]]:
        return list(self.imap(fn, items, retries=retries, desc=desc, unit=unit,
                              progress=progress, total=len(items)))

    def imap(self, fn: Callable[[T], R], items: Iterable[T], *,
             retries: int = DEFAULT_RETRIES, window: int | None = None, desc: str = "",
             unit: str = "item", progress: bool | None = None, total: int | None = None
             ) -> Iterator[Outcome[R]]:
        import ray
        from ray.exceptions import RayError, RayTaskError

        retries = _check_retries(retries)
        if total is None and isinstance(items, Sequence):
            total = len(items)
        task = ray.remote(_timed_with_plugins).options(max_retries=0, num_cpus=1)
        fn_ref = ray.put(fn)
        plugins, paths = loaded_plugins(), tuple(p for p in sys.path if p)
        queue = _Window(items, window or self.in_flight or 2 * self.workers, retries, None)
        running: dict[Any, int] = {}
        with _bar(total, desc, unit, progress) as queue.bar:
            while True:
                queue.fill()
                while queue.waiting:
                    i = queue.waiting.popleft()
                    running[task.remote(plugins, paths, fn_ref, queue.held[i])] = i
                yield from queue.release()
                if queue.finished:
                    return
                if not running:
                    continue
                ready, _ = ray.wait(list(running), num_returns=1)
                for ref in ready:
                    i = running.pop(ref)
                    try:
                        result, error = ray.get(ref), ""
                    except RayTaskError as err:
                        result, error = None, describe_error(err.as_instanceof_cause())
                    except RayError as err:  # its worker or node died
                        result, error = None, (f"{type(err).__name__}: the worker process "
                                               "died while running it")
                    queue.settle(i, result, error)


def make_backend(name: str = "local", *, workers: int | None = None,
                 address: str | None = None) -> LocalBackend | RayBackend:
    """The backend a command line or a caller asked for.

    Args:
        name: ``"local"`` or ``"ray"``.
        workers: local processes, or the CPUs of a local Ray cluster started here (None:
            1 locally, all CPUs for Ray).
        address: the Ray cluster to join (``"auto"``, ``"ray://head:10001"``); only with
            ``name="ray"``.
    """
    if name not in BACKENDS:
        raise did_you_mean("backend", name, BACKENDS)
    if workers is not None:
        check_workers(workers)
    if name == "local":
        if address is not None:
            raise TapBenchError("--address joins a Ray cluster; use it with --backend ray.")
        return LocalBackend(workers or 1)
    return RayBackend(address=address, num_cpus=workers if address is None else None)


def resolve_backend(backend: Backend | None, workers: int) -> Backend:
    """``backend`` when given, else a :class:`LocalBackend` of ``workers`` processes (capped
    at the usable cores, with a warning: :func:`capped_workers`)."""
    return backend if backend is not None else LocalBackend(capped_workers(workers,
                                                                           "workers"))


# -- command line -------------------------------------------------------------------------
def add_backend_arguments(parser: Any, *, shards: bool = True) -> None:
    """Add ``--backend``, ``--address``, ``--retries`` (and ``--resume``) to a sub-command."""
    parser.add_argument("--backend", default="local", choices=BACKENDS,
                        help="where the work runs: local (default) or ray (joins --address, "
                        "or starts a local Ray cluster; pip install 'tap-bench[ray]')")
    parser.add_argument("--address", default=None,
                        help="the Ray cluster to join: 'auto' (the one 'ray start' made on "
                        "this node), 'ray://head:10001' or 'head:6379' (default: start a "
                        "local cluster)")
    parser.add_argument("--retries", type=int, default=DEFAULT_RETRIES,
                        help=f"retries of a failed task (an error, or a worker that died) "
                        f"before it is reported (default {DEFAULT_RETRIES})")
    if shards:
        parser.add_argument("--resume", action="store_true",
                            help="with a directory output: keep the parts already written "
                            "and do the missing ones")


def backend_from_args(args: Any, workers: int | None = None) -> LocalBackend | RayBackend:
    """The backend that ``--backend`` and ``--address`` ask for (``workers``: local
    processes, or the CPUs of a local Ray cluster started here)."""
    _check_retries_arg(args.retries)
    if workers is not None and args.backend == "local":
        workers = capped_workers(workers)
    return make_backend(args.backend, workers=workers, address=args.address)


def _check_retries_arg(retries: Any) -> None:
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ParameterError("--retries", retries, "an integer >= 0")


def close_backend(backend: Backend | None) -> None:
    """Stop a local Ray cluster that :func:`backend_from_args` started."""
    if isinstance(backend, RayBackend):
        backend.shutdown()

