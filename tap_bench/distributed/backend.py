"""Where the work runs: one small protocol, a local backend and a Ray backend.

A backend maps a function over work items (shards, batches of seeds) and returns one
:class:`Outcome` per item, in the items' order. An item whose function raises, or whose
worker process dies, is retried; an item that still fails after its retries comes back as a
failed outcome with the error, and the other items are kept. The function and the items must
be picklable (module-level functions, dataclasses), since both backends run them in other
processes.

- :class:`LocalBackend`: this process (``workers=1``) or a pool of fresh processes.
- :class:`RayBackend`: Ray tasks on a running cluster (``address="auto"`` or
  ``"ray://host:10001"``) or on a local cluster it starts (``address=None``). Ray is an
  optional dependency (``pip install 'tap-bench[ray]'``); it is imported only here, when a
  :class:`RayBackend` is made.

A :class:`RayBackend` keeps at most ``in_flight`` tasks submitted (default: twice the
cluster's CPUs), so the object store and the driver hold that many tasks' arguments and
results at a time, whatever the number of items; the values returned are kept for the
caller, so functions should return summaries (counts, sorted samples) and write bulk
output themselves.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import time
import traceback
from collections.abc import Callable, Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar, runtime_checkable

from tap_bench.errors import TapBenchError, did_you_mean

__all__ = ["BACKENDS", "Backend", "LocalBackend", "Outcome", "RayBackend", "add_backend_arguments",
           "backend_from_args", "close_backend", "make_backend"]

T = TypeVar("T")
R = TypeVar("R")

BACKENDS = ("local", "ray")
DEFAULT_RETRIES = 2
"""Retries of a failed item after its first attempt (3 attempts in all)."""
DEFAULT_OBJECT_STORE_BYTES = 256 << 20
"""Object store of a local Ray cluster started here [B]: results are small summaries and
tables of one shard, and /dev/shm is small on many machines."""


@dataclass(frozen=True)
class Outcome(Generic[R]):
    """The result of one work item.

    Attributes:
        item: index of the item in the mapped sequence.
        value: what the function returned (None when it failed).
        error: the last error, one line, or "" when it succeeded.
        attempts: attempts made (1 when it succeeded first time). On Ray, a worker that
            dies is restarted by Ray within one attempt.
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
    """Maps a function over work items with retries (see the module docstring)."""

    name: str

    @property
    def workers(self) -> int:
        """Processes (CPUs) the work is spread over."""

    def map(self, fn: Callable[[T], R], items: Sequence[T], *, retries: int = DEFAULT_RETRIES,
            desc: str = "", unit: str = "item", progress: bool | None = None
            ) -> list[Outcome[R]]:
        """``fn(item)`` for each item; one :class:`Outcome` per item, in order."""


def _describe(err: BaseException) -> str:
    text = "".join(traceback.format_exception_only(type(err), err)).strip()
    return text.splitlines()[-1] if text else type(err).__name__


def _timed(fn: Callable[[T], R], item: T) -> tuple[R, float, float]:
    """``fn(item)``, its wall time and the CPU time of this process meanwhile [s]."""
    start, cpu = time.perf_counter(), time.process_time()
    value = fn(item)
    return value, time.perf_counter() - start, time.process_time() - cpu


def _check_retries(retries: int) -> int:
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ValueError(f"retries must be an integer >= 0, got {retries!r}.")
    return retries


def _bar(total: int, desc: str, unit: str, progress: bool | None) -> Any:
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc or None, unit=unit,
                disable=None if progress is None else not progress)


def _worker_init() -> None:
    # One BLAS thread per worker: the workers are the parallelism.
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("MKL_NUM_THREADS", "1")


@dataclass
class LocalBackend:
    """Work in this process (``workers=1``) or in a pool of ``workers`` fresh processes.

    In a pool, a worker that dies takes the pool down with it: the items left then run one
    at a time in a fresh single-worker pool, so that an item that kills its worker is the
    one charged with the attempt.
    """

    processes: int = 1
    name: str = field(default="local", init=False)

    def __post_init__(self) -> None:
        if isinstance(self.processes, bool) or not isinstance(self.processes, int) \
                or self.processes < 1:
            raise ValueError(f"workers must be a positive integer, got {self.processes!r}.")

    @property
    def workers(self) -> int:
        return self.processes

    def map(self, fn: Callable[[T], R], items: Sequence[T], *, retries: int = DEFAULT_RETRIES,
            desc: str = "", unit: str = "item", progress: bool | None = None
            ) -> list[Outcome[R]]:
        retries = _check_retries(retries)
        outcomes: dict[int, Outcome[R]] = {}
        attempts = dict.fromkeys(range(len(items)), 0)

        def record(i: int, result: tuple[R, float, float] | None, error: str, bar: Any
                   ) -> bool:
            """Store the attempt; True when item i is settled (done or out of retries)."""
            attempts[i] += 1
            if result is not None:
                value, seconds, cpu = result
                outcomes[i] = Outcome(i, value, "", attempts[i], seconds, cpu)
            elif attempts[i] > retries:
                outcomes[i] = Outcome(i, None, error, attempts[i])
            else:
                return False  # retried
            bar.update(1)
            return True

        with _bar(len(items), desc, unit, progress) as bar:
            if self.processes == 1:
                for i, item in enumerate(items):
                    while True:
                        try:
                            result, error = _timed(fn, item), ""
                        except Exception as err:  # one failing item must not end the run
                            result, error = None, _describe(err)
                        if record(i, result, error, bar):
                            break
            else:
                self._pool_map(fn, items, record, outcomes, bar)
        return [outcomes[i] for i in range(len(items))]

    def _pool_map(self, fn, items, record, outcomes, bar) -> None:
        context = multiprocessing.get_context("spawn")
        pending = list(range(len(items)))
        width = self.processes
        while pending:
            with cf.ProcessPoolExecutor(max_workers=min(width, len(pending)),
                                        mp_context=context, initializer=_worker_init) as pool:
                futures = {pool.submit(_timed, fn, items[i]): i for i in pending}
                broken = False
                for future in cf.as_completed(futures):
                    i = futures[future]
                    try:
                        record(i, future.result(), "", bar)
                    except BrokenProcessPool:
                        broken = True  # charged below, one item at a time
                    except Exception as err:
                        record(i, None, _describe(err), bar)
            if broken:
                # After a death, unfinished items cannot be told apart: run them alone.
                died = [i for i in pending if i not in outcomes]
                for i in died:
                    while i not in outcomes:
                        with cf.ProcessPoolExecutor(max_workers=1, mp_context=context,
                                                    initializer=_worker_init) as pool:
                            try:
                                record(i, pool.submit(_timed, fn, items[i]).result(), "", bar)
                            except BrokenProcessPool:
                                record(i, None, "the worker process died while running it",
                                       bar)
                            except Exception as err:
                                record(i, None, _describe(err), bar)
                pending = []
            else:
                pending = [i for i in pending if i not in outcomes]


@dataclass
class RayBackend:
    """Ray tasks, one per item, on a running cluster or on a local one started here.

    Args:
        address: a running cluster (``"auto"``, ``"ray://head:10001"``, ``"10.0.0.1:6379"``);
            None starts a local cluster (or uses the one this process already joined).
        num_cpus: CPUs of a local cluster started here (None: all of this machine's).
        object_store_memory: object store of a local cluster started here [B].
        in_flight: items submitted at once (None: twice the cluster's CPUs).

    A worker process or node that dies is retried by Ray itself (the task's
    ``max_retries``); an exception raised by the function is resubmitted by :meth:`map`.
    """

    address: str | None = None
    num_cpus: int | None = None
    object_store_memory: int = DEFAULT_OBJECT_STORE_BYTES
    in_flight: int | None = None
    name: str = field(default="ray", init=False)
    started: bool = field(default=False, init=False)

    def __post_init__(self) -> None:
        try:
            import ray
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

    def map(self, fn: Callable[[T], R], items: Sequence[T], *, retries: int = DEFAULT_RETRIES,
            desc: str = "", unit: str = "item", progress: bool | None = None
            ) -> list[Outcome[R]]:
        import ray
        from ray.exceptions import RayError, RayTaskError

        retries = _check_retries(retries)
        # Ray retries an attempt whose worker or node dies (max_retries); an exception raised
        # by the function is resubmitted from here, so that its attempts are counted.
        task = ray.remote(_timed).options(max_retries=retries, num_cpus=1)
        fn_ref = ray.put(fn)
        limit = self.in_flight or 2 * self.workers
        outcomes: list[Outcome[R] | None] = [None] * len(items)
        attempts = [0] * len(items)
        running: dict[Any, int] = {}
        queue: list[int] = list(range(len(items)))[::-1]
        with _bar(len(items), desc, unit, progress) as bar:
            while queue or running:
                while queue and len(running) < limit:
                    i = queue.pop()
                    attempts[i] += 1
                    running[task.remote(fn_ref, items[i])] = i
                done, _ = ray.wait(list(running), num_returns=1)
                for ref in done:
                    i = running.pop(ref)
                    try:
                        value, seconds, cpu = ray.get(ref)
                    except RayTaskError as err:
                        if attempts[i] <= retries:
                            queue.append(i)
                            continue
                        outcomes[i] = Outcome(i, None, _describe(err.as_instanceof_cause()),
                                              attempts[i])
                    except RayError as err:  # its worker or node died on every Ray retry
                        outcomes[i] = Outcome(i, None, f"{type(err).__name__}: the worker "
                                              "process died while running it", attempts[i])
                    else:
                        outcomes[i] = Outcome(i, value, "", attempts[i], seconds, cpu)
                    bar.update(1)
        return outcomes  # type: ignore[return-value]


def make_backend(name: str = "local", *, workers: int | None = None,
                 address: str | None = None) -> LocalBackend | RayBackend:
    """The backend a command line asked for.

    Args:
        name: ``"local"`` or ``"ray"``.
        workers: local processes, or the CPUs of a local Ray cluster started here (None:
            1 locally, all CPUs for Ray).
        address: the Ray cluster to join (``"auto"``, ``"ray://head:10001"``); only with
            ``name="ray"``.
    """
    if name not in BACKENDS:
        raise did_you_mean("backend", name, BACKENDS)
    if name == "local":
        if address is not None:
            raise TapBenchError("--address joins a Ray cluster; use it with --backend ray.")
        return LocalBackend(workers or 1)
    return RayBackend(address=address, num_cpus=workers if address is None else None)


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
                        help=f"retries of a failed task before it is reported "
                        f"(default {DEFAULT_RETRIES})")
    if shards:
        parser.add_argument("--resume", action="store_true",
                            help="with a directory output: keep the parts already written "
                            "and do the missing ones")


def backend_from_args(args: Any, workers: int | None = None) -> LocalBackend | RayBackend:
    """The backend that ``--backend`` and ``--address`` ask for (``workers``: local
    processes, or the CPUs of a local Ray cluster started here)."""
    if args.retries < 0:
        raise TapBenchError(f"--retries must be 0 or more, not {args.retries}.")
    return make_backend(args.backend, workers=workers, address=args.address)


def close_backend(backend: LocalBackend | RayBackend) -> None:
    """Stop a local Ray cluster that :func:`backend_from_args` started."""
    if isinstance(backend, RayBackend):
        backend.shutdown()
