"""Training Stable-Baselines3 agents on a scenario, on the CPU: ``tap-bench train``.

The model is written atomically to the ``.zip`` given, and beside it a policy definition
(``.json``, kind ``sb3``) that records the scenario, the observation config, the algorithm,
its hyper-parameters, the seed, the number of timesteps, how it was trained and the
command, so that the model loads by name (``tap-bench rollout --policy dqn-highway``) and
can be rebuilt; and the behaviour-coverage learning curve (``<name>.curve.csv``, a table,
and ``<name>.curve.png``; :mod:`tap_bench.rl.curve`).

Where the time goes (``benchmarks/profile_train.py``): almost all of it is highway-env's
simulation (IDM and MOBIL for every vehicle, neighbour searches and collision checks, at
every simulated step), then the observation; the gradient steps of the small MLPs are a
small part (docs/simulation.md, "Speed"). So training runs

- on the scenario's fast variant (``fast=True``: 5 Hz simulation, collisions checked for
  the ego only, as highway-env's ``highway-fast-v0``): half the simulated steps;
  decisions, observation, actions and reward are the scenario's, and the curve evaluates
  on the scenario itself;
- with the traffic driven by tap-bench's own vectorised core (:mod:`tap_bench.sim.traffic`,
  in every scenario env), and the Kinematics observation without pandas
  (:mod:`tap_bench.sim.observation`);
- on ``n_envs`` envs stepped in parallel: with about ``n_envs`` free cores (a 2-core
  machine), env 0 in this process between the learner's steps and the others in worker
  processes (:mod:`tap_bench.rl.vec_env`: ``n_envs`` busy processes on ``n_envs``
  cores); with a core more, each in a worker process (``SubprocVecEnv``); with ``n_envs=1``
  the env runs in this process. DQN's gradient steps overlap the workers' simulation
  (:mod:`tap_bench.rl.overlap`); the workers are forked from a forkserver that has
  imported their modules (SB3, torch, highway-env, tap-bench's envs) once
  (:data:`WORKER_MODULES`). When the machine's cores are busy with other work at the start
  (:func:`idle_cores`), all are stepped one after the other in this process
  (``DummyVecEnv``): less CPU in all, and more steps per second on busy cores.
  The same weights in all three (``benchmarks/bench_train_speed.py``, variants
  ``2-envs-one``, ``2-envs-workers`` and ``2-envs-in-process``; docs/simulation.md);
- with one torch thread: the workers are the parallelism, and batches of 32 to 64 rows
  gain nothing from more (more threads compete with the env workers).
"""

from __future__ import annotations

import ast
import contextlib
import copy
import dataclasses
import functools
import json
import os
import shlex
import signal
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import pandas as pd

from tap_bench.errors import ParameterError
from tap_bench.rl.curve import CurveConfig, coverage_reference, plot_curve
from tap_bench.rl.heldout import EGOS, SceneSplit, SceneSubset, split_scenes
from tap_bench.sim.sb3 import algorithm_class
from tap_bench.sim.scenario_env import ScenarioEnv, get_scenario
from tap_bench.sim.scenario_format import Scenario
from tap_bench.sim.schema import env_class
from tap_bench.sim.womd_scene import WomdScenes
from tap_bench.tableio import atomic_path, check_replace, write_table

__all__ = ["CHECKPOINTS", "DEFAULT_N_ENVS", "HYPERPARAMETERS", "MAX_N_ENVS", "WORKER_MODULES",
           "TrainingResult", "idle_cores", "train"]

HYPERPARAMETERS: dict[str, dict[str, Any]] = {
    # highway-env's published Stable-Baselines3 settings for its highway tasks.
    "dqn": {"policy_kwargs": {"net_arch": [256, 256]}, "learning_rate": 5e-4,
            "buffer_size": 15000, "learning_starts": 200, "batch_size": 32, "gamma": 0.8,
            "train_freq": 1, "gradient_steps": 1, "target_update_interval": 50,
            "exploration_fraction": 0.7},
    "ppo": {"policy_kwargs": {"net_arch": {"pi": [256, 256], "vf": [256, 256]}},
            "n_steps": 256, "batch_size": 64, "n_epochs": 10, "learning_rate": 5e-4,
            "gamma": 0.8},
    "a2c": {"policy_kwargs": {"net_arch": [256, 256]}, "learning_rate": 7e-4, "gamma": 0.8},
}
"""Default hyper-parameters per algorithm; ``train(..., hyperparameters=...)`` overrides.
With several envs, ``n_steps`` (PPO, A2C) is per env and ``train_freq`` (DQN) counts steps
of all envs together."""

CHECKPOINTS = 10
"""With a log folder, the weights are saved there this many times during training
(``weights_<steps>_steps.zip``)."""

DEFAULT_N_ENVS = 2
"""Training envs stepped in parallel processes by default: one per core of a 2-core machine."""
MAX_N_ENVS = 64
"""The most training envs (each a worker process, about 50 MB of memory): more than any
machine tap-bench is run on has cores to step them."""


@dataclass(frozen=True)
class TrainingResult:
    """What :func:`train` wrote.

    Attributes:
        model_path: the ``.zip``.
        definition_path: the policy definition ``.json`` beside it.
        timesteps: env steps trained.
        seconds: wall time of the training, evaluations for the curve included [s].
        train_seconds: wall time of the training alone [s].
        episodes: training episodes finished.
        curve: the learning curve (:data:`tap_bench.rl.curve.CURVE_COLUMNS`), or None
            without it.
        curve_path, plot_path: the curve table (``.curve.csv``) and its plot
            (``.curve.png``), or None.
        kept_timesteps: the env steps at which the saved weights were evaluated best
            (``keep="best"``), or None when the last weights were saved.
    """

    model_path: Path
    definition_path: Path
    timesteps: int
    seconds: float
    train_seconds: float
    episodes: int
    curve: pd.DataFrame | None = None
    curve_path: Path | None = None
    plot_path: Path | None = None
    kept_timesteps: int | None = None

    @property
    def coverage(self) -> float | None:
        """The coverage of the last point of the curve (None without a curve)."""
        if self.curve is None or self.curve.empty:
            return None
        return float(self.curve["coverage"].iloc[-1])

    @property
    def steps_per_second(self) -> float:
        """Training env steps per second of training wall time (evaluations excluded)."""
        return self.timesteps / self.train_seconds


def _make_training_env(scenario: Scenario, fast: bool, worker: bool = False,
                       scenes: tuple[int, ...] | None = None, egos: str = "sdc") -> gym.Env:
    """One training env (a module-level function: worker processes build it by name);
    on recorded scenes, only the ``scenes`` indexes (None: all), driving their egos or all
    their drivers (``egos``: :class:`~tap_bench.rl.heldout.SceneSubset`)."""
    from stable_baselines3.common.monitor import Monitor

    if worker:  # Ctrl-C stops the training in the main process, which then saves the model
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    if isinstance(scenario, WomdScenes):  # recorded scenes, one after the other
        from tap_bench.sim.womd_env import WomdEnv

        env = WomdEnv(scenario, record=False, cycle=True)
        if scenes is None and egos != "sdc":
            scenes = tuple(range(len(env.catalog)))
        return Monitor(env if scenes is None else SceneSubset(env, scenes, egos))
    return Monitor(ScenarioEnv(scenario, record=False, fast=fast))


@contextlib.contextmanager
def _main_not_rerun() -> Iterator[None]:
    """Start worker processes without running an unguarded caller's script in them.

    multiprocessing's forkserver and spawn start methods import the ``__main__`` module (by
    file or by module name) in every worker. A script with an ``if __name__ ==
    "__main__":`` guard expects that (its top level may register envs the workers need); a
    plain script without one would run its ``train`` call again there and fail. So for a
    ``__main__`` whose source has no such guard, ``__main__`` is hidden from
    multiprocessing while the workers start (they build their env from this module and
    need nothing of it); any other ``__main__`` is left as it is.
    """
    main = sys.modules.get("__main__")
    if main is None or _has_main_guard(main):
        yield
        return
    saved = {key: vars(main)[key] for key in ("__file__", "__spec__") if key in vars(main)}
    vars(main).pop("__file__", None)
    main.__spec__ = None
    try:
        yield
    finally:
        vars(main).pop("__spec__", None)
        vars(main).update(saved)


def _has_main_guard(main: Any) -> bool:
    """Whether ``main``'s source has a top-level ``if __name__ == "__main__":`` (True when
    its source cannot be read: multiprocessing's usual behaviour then)."""
    spec = getattr(main, "__spec__", None)
    path = getattr(main, "__file__", None) or getattr(spec, "origin", None)
    if not path:
        return True  # python -c, an interactive session: nothing to import
    try:
        tree = ast.parse(Path(path).read_text(encoding="utf-8"), filename=str(path))
    except (OSError, SyntaxError, UnicodeDecodeError, ValueError):
        return True
    for node in tree.body:
        if (isinstance(node, ast.If) and isinstance(node.test, ast.Compare)
                and len(node.test.ops) == 1 and isinstance(node.test.ops[0], ast.Eq)):
            sides = [node.test.left, *node.test.comparators]
            names = [s.id for s in sides if isinstance(s, ast.Name)]
            constants = [s.value for s in sides if isinstance(s, ast.Constant)]
            if names == ["__name__"] and constants == ["__main__"]:
                return True
    return False


WORKER_MODULES = ("stable_baselines3.common.vec_env.subproc_vec_env",
                  "stable_baselines3.common.monitor", "highway_env", "tap_bench.rl.vec_env",
                  "tap_bench.rl.training", "tap_bench.sim.scenario_env",
                  "tap_bench.sim.traffic", "tap_bench.sim.observation")
"""What every training env worker imports (the worker loops, SB3's and tap-bench's, and SB3's
Monitor, which import torch; highway-env; tap-bench's env code), imported once in the
forkserver the workers are forked from rather than once in each worker (the CPU this saves:
docs/simulation.md)."""


@contextlib.contextmanager
def _workers_preloaded(scenario: Scenario | WomdScenes) -> Iterator[None]:
    """Have the forkserver this process starts next import :data:`WORKER_MODULES` (and the
    WOMD env for recorded scenes) before it forks the workers, as well as ``__main__``
    (multiprocessing's default). The modules are only imported there, nothing is built;
    a forkserver already running is kept as it is (multiprocessing starts one per process),
    and the previous preload list is restored afterwards."""
    import multiprocessing
    import multiprocessing.forkserver

    server = multiprocessing.forkserver._forkserver
    previous = list(getattr(server, "_preload_modules", ["__main__"]))
    extra = ["tap_bench.sim.womd_env"] if isinstance(scenario, WomdScenes) else []
    wanted = [*previous, *(m for m in (*WORKER_MODULES, *extra) if m not in previous)]
    multiprocessing.get_context("forkserver").set_forkserver_preload(wanted)
    try:
        yield
    finally:
        multiprocessing.get_context("forkserver").set_forkserver_preload(previous)


def idle_cores(seconds: float = 0.3) -> float | None:
    """How many of the CPU cores this process may run on were idle, on average, over the
    next ``seconds`` (Linux: the idle and I/O-wait time of ``/proc/stat``'s lines of the
    cores in this process's affinity, ``os.sched_getaffinity``: a job given 2 cores of a
    64-core node by taskset, a cpuset or a batch scheduler counts its own 2 cores, not the
    node's idle ones; None where it cannot be read).

    Training picks where its envs run by it (``train(in_process=None)``, :func:`envs_where`:
    in this process below 1.5 idle cores, half a core of margin for the sample's noise):
    without a second idle core, worker processes only take turns with other work on the
    busy cores, for more CPU per env step and fewer steps per second than the envs stepped
    in the training process (measured: docs/simulation.md)."""
    cpus = _affinity()  # the lines of this process's cores; else (not Linux) the all-CPU line
    lines = {"cpu"} if cpus is None else {f"cpu{k}" for k in cpus}
    n_cores = _usable_cores()

    def read() -> tuple[int, int]:
        idle = total = seen = 0
        with open("/proc/stat", encoding="ascii") as handle:
            for line in handle:
                name, _, rest = line.partition(" ")
                if name in lines:
                    values = [int(v) for v in rest.split()[:8]]
                    idle += values[3] + values[4]  # idle + iowait
                    total += sum(values)  # all (guest is in user)
                    seen += 1
                elif not name.startswith("cpu"):
                    break
        if seen != len(lines):
            raise ValueError("/proc/stat lacks a core's line")
        return idle, total

    try:
        idle0, total0 = read()
        time.sleep(seconds)
        idle1, total1 = read()
    except (OSError, ValueError, IndexError):
        return None
    if total1 <= total0:
        return None
    return n_cores * (idle1 - idle0) / (total1 - total0)


def envs_where(idle: float | None, n_envs: int, cores: float) -> bool | str:
    """Where ``train(in_process=None)`` steps ``n_envs`` training envs (``n_envs`` > 1):
    ``True`` (all in this process, on one core) with fewer than 1.5 idle cores (no second
    core for a worker), ``"one"`` (env 0 in this process, the others in workers) with fewer
    than ``n_envs + 0.5``, else ``False`` (each in a worker, the learner on a core of its
    own). With 2 or more idle cores the envs run in parallel even when there are more envs
    than idle cores: 16 envs on 14 idle cores take turns on 14 cores, not one after the
    other on one. ``idle``: the idle cores measured (:func:`idle_cores`); where unknown
    (None), the ``cores`` this process may run on are taken as idle. Half a core of margin
    for the sample's noise."""
    free = cores if idle is None else idle
    if free < 1.5:
        return True
    return "one" if free < n_envs + 0.5 else False


def cpu_quota(root: str | os.PathLike = "/sys/fs/cgroup",
              membership: str | os.PathLike = "/proc/self/cgroup") -> float | None:
    """The CPU time this process's control group may use, in cores (Linux cgroups: a
    container started with ``--cpus 2``, a Kubernetes CPU limit, a systemd ``CPUQuota``),
    the smallest along its path up to the root; None where there is no quota or it cannot
    be read. ``/proc/stat`` shows the host's idle cores, which such a process cannot use
    beyond its quota: :func:`train` counts at most this many idle cores.

    Args:
        root: where the cgroup file systems are mounted.
        membership: the file listing this process's cgroups (``/proc/self/cgroup``).
    """
    root = Path(root)
    try:
        lines = Path(membership).read_text(encoding="ascii").splitlines()
    except (OSError, ValueError):
        return None
    quotas = []
    for line in lines:
        fields = line.split(":", 2)
        if len(fields) != 3:
            continue
        hierarchy, controllers, path = fields
        parts = [part for part in path.strip().split("/") if part]
        if hierarchy == "0" and controllers == "":  # v2: cpu.max "QUOTA PERIOD"/"max PERIOD"
            dirs, name = [root], ("cpu.max",)
        elif "cpu" in controllers.split(","):  # cgroup v1: cfs_quota_us (-1: none)
            dirs, name = [root / controllers, root / "cpu"], ("cpu.cfs_quota_us",
                                                               "cpu.cfs_period_us")
        else:
            continue
        for base in dirs:
            for depth in range(len(parts) + 1):
                folder = base.joinpath(*parts[:depth])
                try:
                    values = [(folder / n).read_text(encoding="ascii").split()
                              for n in name]
                except OSError:
                    continue
                try:
                    quota, period = (values[0] if len(name) == 1
                                     else [values[0][0], values[1][0]])
                    if quota not in ("max", "-1") and float(period) > 0:
                        quotas.append(float(quota) / float(period))
                except (ValueError, IndexError):
                    continue
    return min(quotas) if quotas else None


def _affinity() -> set[int] | None:
    """The cores this process may run on (its CPU affinity; None where unknown)."""
    try:
        return os.sched_getaffinity(0)
    except (AttributeError, OSError):
        return None


def _usable_cores() -> int:
    """How many cores this process may run on (its CPU affinity where known)."""
    cpus = _affinity()
    return (os.cpu_count() or 1) if cpus is None else len(cpus)


def _vec_env(scenario: Scenario, *, n_envs: int, fast: bool, seed: int,
             in_process: bool | str = False, scenes: tuple[int, ...] | None = None,
             egos: str = "sdc") -> Any:
    from stable_baselines3.common.vec_env import DummyVecEnv

    here = functools.partial(_make_training_env, scenario, fast, scenes=scenes, egos=egos)
    if n_envs == 1 or in_process is True:
        vec = DummyVecEnv([here] * n_envs)
    else:
        from tap_bench.rl.vec_env import training_vec_env  # imports SB3

        factory = functools.partial(_make_training_env, scenario, fast, worker=True,
                                    scenes=scenes, egos=egos)
        # forkserver: workers start from a clean interpreter, not a copy of this process
        # (which may hold torch's threads and highway-env's shared classes)
        with _main_not_rerun(), _workers_preloaded(scenario):
            vec = training_vec_env(here, factory, n_envs, one_here=in_process == "one",
                                   start_method="forkserver")
    vec.seed(seed)
    return vec


def train(algo: str, env: str | WomdScenes, *, timesteps: int, seed: int, output: str | os.PathLike,
          hyperparameters: Mapping[str, Any] | None = None, n_envs: int = DEFAULT_N_ENVS,
          fast: bool = True, curve: CurveConfig | None = None,
          log_dir: str | os.PathLike | None = None, verbose: int = 0,
          command: str | None = None, keep: str = "last", overwrite: bool = False,
          announce: Callable[[str], None] | None = None,
          in_process: bool | str | None = None,
          hold_out: str | Sequence[int] | None = None, egos: str = "sdc") -> TrainingResult:
    """Train ``algo`` on scenario ``env`` for ``timesteps`` decisions and save it.

    Args:
        algo: ``"dqn"``, ``"ppo"`` or ``"a2c"``.
        env: scenario name, id or file, or recorded WOMD scenes
            (:class:`~tap_bench.sim.womd_scene.WomdScenes`: every scenario of the files in
            turn, 10 Hz, no fast variant and no learning curve).
        timesteps: decisions (env steps, over all envs) to train for. Ctrl-C (SIGINT) stops
            the training early: the model and the curve so far are saved, and the definition
            records the steps trained and ``interrupted_of``.
        seed: seeds SB3 (torch, numpy) and the envs' first resets (env i gets seed + i).
        output: the ``.zip`` to write; the definition goes to the same name with ``.json``,
            the curve to ``.curve.csv`` and ``.curve.png``.
        hyperparameters: overrides of :data:`HYPERPARAMETERS`.
        n_envs: training envs, stepped in parallel processes when more than one.
        fast: train on the scenario's fast variant (see the module docstring); False trains
            on the scenario itself.
        curve: record the behaviour-coverage learning curve with these settings
            (:class:`tap_bench.rl.curve.CurveConfig`); None (the default here; ``tap-bench
            train`` records one unless ``--no-curve``): no curve.
        log_dir: write SB3's log, with the ``tap/*`` curve keys, there as CSV.
        verbose: SB3's verbosity; 1 also prints the log and each curve point.
        command: the command line to record (default: this process's).
        keep: which weights to save: ``"last"`` (the end of training) or ``"best"`` (those
            of the curve's evaluation with the highest mean return, the first of equal
            ones: model selection on the curve's seeds, which the benchmark's evaluation
            seeds 1000+ do not overlap; needs the curve). The definition records which.
        overwrite: replace an earlier model of ``tap-bench train`` at ``output`` (its
            ``.zip``, ``.json``, ``.curve.csv`` and ``.curve.png``); files tap-bench did not
            write are never replaced.
        announce: called with one line per phase (the curve's reference, the envs
            starting, training progress every tenth of ``timesteps``, each curve
            evaluation, saving), whether or not on a terminal: ``tap-bench train`` prints
            them, as ``demo`` and ``bench run`` print theirs.
        in_process: where the ``n_envs`` envs are stepped; the same training, bit for bit
            (the same weights), at different speeds (docs/simulation.md). True: one after
            the other in this process (SB3's ``DummyVecEnv``): the least CPU in all (no
            workers to start, nothing sent between processes, no contention between them),
            but on one core, so the fastest only when the machine's cores are busy with
            other work. ``"one"``: env 0 in this process, between the learner's steps, and
            each other env in a worker process (:mod:`tap_bench.rl.vec_env`): ``n_envs``
            busy processes, the fastest when about ``n_envs`` cores are free. False: each
            env in a worker process, the learner beside them: the fastest with a core more
            than ``n_envs`` free. None (the default): chosen by the cores idle at the start
            (:func:`idle_cores`, :func:`envs_where`).
        hold_out: on recorded scenes, the scene indexes (seeds) never trained on
            (:mod:`tap_bench.rl.heldout`), recorded in the definition with the scenes
            trained on; None: train on every scene.
        egos: on recorded scenes, who the agent drives: ``"sdc"`` (each scene's ego) or
            ``"all"`` (every vehicle that drives in the training scenes, in turn:
            :func:`~tap_bench.rl.heldout.drivers`); the definition records it.

    Raises:
        ParameterError: ``timesteps``, ``n_envs``, ``output`` or ``keep`` is not usable.
        RunExistsError: an output exists and ``overwrite`` is False.
        OutputPathError: an output exists that ``tap-bench train`` did not write.
    """
    output = Path(output)
    _check_arguments(output, timesteps=timesteps, n_envs=n_envs, keep=keep,
                     in_process=in_process, curve=curve, overwrite=overwrite)
    cls = algorithm_class(algo)
    algo = algo.lower()
    import torch

    torch.set_num_threads(1)  # a shared CPU; the env workers are the parallelism
    scenario = _training_scenario(env, curve)
    split = _split(scenario, hold_out)
    _check_egos(egos, scenario)
    params = {**HYPERPARAMETERS[algo], **(hyperparameters or {})}
    observation = _observation_config(scenario)
    say = announce or (lambda line: None)
    curve_callback = _curve_callback(curve, scenario, output, timesteps=timesteps,
                                     observation=observation, keep=keep, verbose=verbose,
                                     announce=announce, say=say)
    in_process, why = _where_envs_run(in_process, n_envs)
    say(f"starting {n_envs} training env(s) of {scenario.env_id}"
        + (" (fast variant)" if fast and not isinstance(scenario, WomdScenes) else "")
        + _where_phrase(n_envs, in_process) + why + " ...")
    vec = _vec_env(scenario, n_envs=n_envs, fast=fast, seed=seed, in_process=in_process,
                   scenes=None if split is None or not split.held_out else split.train,
                   egos=egos)
    say(f"training {algo.upper()} for {timesteps} steps"
        + (f", {curve.points} learning-curve evaluations on the way" if curve else "")
        + " ...")
    learned = _learn(cls, vec, params, seed=seed, timesteps=timesteps, verbose=verbose,
                     log_dir=log_dir, curve_callback=curve_callback, announce=announce)
    if learned.interrupted and curve_callback is not None:
        curve_callback.on_training_end()  # the last point of the curve
    eval_seconds = sum(curve_callback.eval_seconds) if curve_callback is not None else 0.0
    model = learned.model
    trained = int(model.num_timesteps)
    say(f"trained {trained} steps ({learned.seconds:.0f} s, learning-curve evaluations "
        f"{eval_seconds:.0f} s of it); saving the model ...")
    kept = curve_callback.best if keep == "best" else None
    if kept is not None:
        model.policy.load_state_dict(curve_callback.best_weights)
    definition = _write_model(model, output, _definition(
        output, algo=algo, scenario=scenario, observation=observation, trained=trained,
        asked=timesteps, interrupted=learned.interrupted, kept=kept, n_envs=n_envs, fast=fast,
        seed=seed, params=params, curve=curve, train_seconds=learned.seconds - eval_seconds,
        cpu_seconds=learned.cpu_seconds, command=command, split=split, egos=egos))
    result = TrainingResult(model_path=output, definition_path=definition,
                            timesteps=trained, seconds=learned.seconds,
                            train_seconds=learned.seconds - eval_seconds,
                            episodes=learned.episodes,
                            kept_timesteps=None if kept is None else int(kept["timesteps"]))
    if curve_callback is not None:
        result = _write_curve(result, curve_callback, algo=algo, scenario=scenario,
                              seeds=curve.seeds)
    return result


def _check_egos(egos: str, scenario: Any) -> None:
    """Refuse an ``egos`` :func:`train` cannot drive: not one of :data:`EGOS`, or not the
    scene's ego on a synthetic scenario."""
    if egos not in EGOS or (egos != "sdc" and not isinstance(scenario, WomdScenes)):
        raise ParameterError("egos", egos, f"one of {EGOS} (recorded scenes only: a "
                             "synthetic scenario has one ego)")


def _write_model(model: Any, output: Path, definition: dict[str, Any]) -> Path:
    """Write the model's ``.zip`` at ``output`` and its definition beside it (``.json``),
    each atomically; returns the definition's path."""
    output.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(output) as tmp, open(tmp, "wb") as handle:
        model.save(handle)
    path = output.with_suffix(".json")
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(definition, indent=2, default=_json_record) + "\n")
    return path


def _check_arguments(output: Path, *, timesteps: Any, n_envs: Any, keep: Any, in_process: Any,
                     curve: CurveConfig | None, overwrite: bool) -> None:
    """Refuse :func:`train`'s arguments that are not usable, before any work (see its
    Raises)."""
    if output.suffix != ".zip":
        raise ParameterError("output", str(output), "a .zip file (a Stable-Baselines3 model)",
                             hint=f"Name it {output.with_suffix('.zip').name}.")
    if isinstance(timesteps, bool) or not isinstance(timesteps, int) or timesteps < 1:
        raise ParameterError("timesteps", timesteps, "an integer >= 1")
    if isinstance(n_envs, bool) or not isinstance(n_envs, int) or n_envs < 1:
        raise ParameterError("n_envs", n_envs, "an integer >= 1 (training envs)")
    if n_envs > MAX_N_ENVS:
        raise ParameterError("n_envs", n_envs, f"at most {MAX_N_ENVS}", message=(
            f"n_envs (--n-envs) {n_envs} is more than the limit of {MAX_N_ENVS} "
            "(tap_bench.rl.training.MAX_N_ENVS): each training env is a process of about "
            "50 MB, and more envs than cores only take turns on them."))
    if keep not in ("last", "best"):
        raise ParameterError("keep", keep, "'last' or 'best'")
    if not (in_process is None or isinstance(in_process, bool) or in_process == "one"):
        raise ParameterError("in_process", in_process, "True, False, 'one' or None")
    if keep == "best" and curve is None:
        raise ParameterError("keep", keep, "'last' without a learning curve", message=(
            "keeping the best weights needs the learning curve's evaluations: train with a "
            "curve (tap-bench train: drop --no-curve; train(): pass curve=CurveConfig()), "
            "or keep the last weights."))
    check_replace(training_outputs(output), overwrite, ours=lambda _: _trained_here(output))


def _split(scenario: Scenario | WomdScenes, hold_out: str | Sequence[int] | None
           ) -> SceneSplit | None:
    """The scenes trained on and held out (None on a synthetic scenario, where ``hold_out``
    is refused)."""
    if not isinstance(scenario, WomdScenes):
        if hold_out is not None:
            raise ParameterError("hold_out", hold_out, "None on a synthetic scenario",
                                 message="hold_out (--hold-out) names recorded scenes; a "
                                 "synthetic scenario's curve evaluates on seeds of its own.")
        return None
    return split_scenes(scenario, hold_out)


def _training_scenario(env: str | WomdScenes, curve: CurveConfig | None) -> Scenario | WomdScenes:
    """The scenario (or recorded scenes) ``env`` names; recorded scenes refused with a
    curve (it evaluates on synthetic seeds)."""
    scenario = env if isinstance(env, WomdScenes) else get_scenario(env)
    if isinstance(scenario, WomdScenes) and curve is not None:
        raise ParameterError("curve", curve, "None on recorded scenes", message=(
            "the learning curve evaluates on synthetic seeds; train on recorded scenes "
            "without it (tap-bench train --no-curve) and compare the agent with the human "
            "afterwards (tap-bench rollout --womd ... --policy MODEL.zip)."))
    return scenario


def _curve_callback(curve: CurveConfig | None, scenario: Scenario, output: Path, *,
                    timesteps: int, observation: dict[str, Any], keep: str, verbose: int,
                    announce: Callable[[str], None] | None,
                    say: Callable[[str], None]) -> Any:
    """The callback that records the learning curve (its reference computed first), or
    None without a curve."""
    if curve is None:
        return None
    # callbacks.py subclasses SB3's BaseCallback: imported only where SB3 is installed
    from tap_bench.rl.callbacks import CoverageCallback

    say(f"learning curve: the coverage reference ({curve.reference}, level "
        f"{curve.level}, seeds {curve.seeds}) ...")
    reference = coverage_reference(curve, scenario)
    return CoverageCallback(
        # ceil: points - 1 evaluations during training, the last one at its end
        scenario, reference, curve, every=max(1, -(-timesteps // curve.points)),
        observation=observation, name=output.stem, keep_best=keep == "best",
        until=timesteps, verbose=verbose, announce=announce)


def _where_envs_run(in_process: bool | str | None, n_envs: int) -> tuple[bool | str, str]:
    """Where the envs are stepped (``in_process``, chosen by the idle cores when None:
    :func:`envs_where`) and why, as the start line says it (``""`` when given)."""
    if in_process is not None:
        return in_process, ""
    if n_envs == 1:
        return True, ""
    idle, cores, quota = idle_cores(), _usable_cores(), cpu_quota()
    if quota is not None and quota < cores:  # a container's CPU limit, say
        cores = quota
        idle = None if idle is None else min(idle, quota)
    why = (f", {idle:.1f} of {cores:g} cores idle" if idle is not None
           else f", {cores:g} cores (idle time unknown)")
    if cores == quota:
        why += " (the CPU quota of its control group)"
    return envs_where(idle, n_envs, cores), why


def _where_phrase(n_envs: int, in_process: bool | str) -> str:
    """Where the start line says the ``n_envs`` envs run."""
    if n_envs == 1:
        return ""
    if in_process is True:
        return " in this process"
    if in_process == "one":
        return (f": one in this process, {n_envs - 1} in worker process"
                + ("es" if n_envs > 2 else ""))
    return " in worker processes"


@dataclass(frozen=True)
class _Learned:
    """What :func:`_learn` gives back: the model, the wall time of ``learn`` [s], whether
    Ctrl-C stopped it, the training episodes finished, and the CPU time of ``learn``
    (user + system, the env workers included) [s]."""

    model: Any
    seconds: float
    interrupted: bool
    episodes: int
    cpu_seconds: float = float("nan")


def _learn(cls: type, vec: Any, params: dict[str, Any], *, seed: int, timesteps: int,
           verbose: int, log_dir: str | os.PathLike | None, curve_callback: Any,
           announce: Callable[[str], None] | None) -> _Learned:
    """Build the learner on ``vec`` (DQN's gradient steps overlapped with the workers'
    simulation where there are several envs), run SB3's ``learn`` for ``timesteps`` env
    steps with the callbacks, keep what was learned on Ctrl-C, and close the envs."""
    from stable_baselines3.common.logger import HumanOutputFormat, Logger, make_output_format
    from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

    from tap_bench.rl.callbacks import EpisodesCounted, StepsAnnounced

    counted = EpisodesCounted()  # first: it counts the step a Ctrl-C then interrupts
    callbacks = [counted, *([curve_callback] if curve_callback is not None else [])]
    if announce is not None:
        callbacks.append(StepsAnnounced(timesteps, announce))
    learner_env = vec
    try:
        if vec.num_envs > 1 and issubclass(cls, OffPolicyAlgorithm):
            # gradient steps while the workers simulate (overlap.py imports SB3)
            from tap_bench.rl.overlap import FlushPendingCallback, OverlapVecEnv, overlapping

            learner_env = OverlapVecEnv(vec)
            cls = overlapping(cls, learner_env)
            callbacks.insert(0, FlushPendingCallback(learner_env))
        # a copy: SB3's A2C adds its optimizer (a class) to policy_kwargs in place, which
        # would change the defaults and the definition's record
        model = cls("MlpPolicy", learner_env, seed=seed, verbose=verbose, device="cpu",
                    **copy.deepcopy(params))
        outputs = [HumanOutputFormat(sys.stdout)] if verbose else []
        if log_dir:
            Path(log_dir).mkdir(parents=True, exist_ok=True)
            outputs.append(make_output_format("csv", str(log_dir)))
        model.set_logger(Logger(str(log_dir) if log_dir else None, outputs))
        if log_dir:  # the weights at every tenth of the training: a learning curve on any
            # scenes afterwards (recorded scenes have no curve during training)
            from stable_baselines3.common.callbacks import CheckpointCallback

            callbacks.append(CheckpointCallback(
                save_freq=max(1, timesteps // (CHECKPOINTS * vec.num_envs)),
                save_path=str(log_dir), name_prefix="weights"))
        start = time.perf_counter()
        cpu_start = _cpu_seconds()
        interrupted = False
        try:
            model.learn(total_timesteps=timesteps, callback=callbacks, progress_bar=False)
        except KeyboardInterrupt:
            # Ctrl-C: keep what was learned. The workers may be half-way through a reply,
            # so they are stopped rather than asked to close.
            interrupted = True
            if learner_env is not vec:
                learner_env.flush()  # the gradient steps still pending (no env needed)
            print(f"training interrupted at {model.num_timesteps} steps: saving the model.",
                  file=sys.stderr, flush=True)
            for process in getattr(vec, "processes", ()):
                process.terminate()
            vec.closed = True
        seconds = time.perf_counter() - start
        # every training env is a Monitor; after Ctrl-C the workers are gone (the episodes
        # counted by their dones then)
        episodes = counted.episodes if interrupted else sum(
            len(r) for r in vec.env_method("get_episode_rewards"))
        cpu = _cpu_seconds(vec) - cpu_start  # the workers' too, while they run
    finally:
        vec.close()
    return _Learned(model, seconds, interrupted, int(episodes), cpu)


def _cpu_seconds(vec: Any = None) -> float:
    """CPU time [s] (user + system) of this process and of the env worker processes of
    ``vec`` still running (read from ``/proc/<pid>/stat``; NaN where it cannot be read)."""
    import resource

    own = resource.getrusage(resource.RUSAGE_SELF)
    total = own.ru_utime + own.ru_stime
    for process in getattr(vec, "processes", ()):
        try:
            fields = Path(f"/proc/{process.pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        except (OSError, ValueError, IndexError, AttributeError):
            return float("nan")
    return total


def _definition(output: Path, *, algo: str, scenario: Scenario | WomdScenes,
                observation: dict[str, Any], trained: int, asked: int, interrupted: bool,
                kept: dict[str, Any] | None, n_envs: int, fast: bool, seed: int,
                params: dict[str, Any], curve: CurveConfig | None, train_seconds: float,
                command: str | None, split: SceneSplit | None = None,
                cpu_seconds: float = float("nan"), egos: str = "sdc") -> dict[str, Any]:
    """The policy definition written beside the model (kind ``sb3``): what was trained,
    how, and the command; ``trained`` env steps of the ``asked`` ones, ``train_seconds``
    the wall time of the training without the curve's evaluations [s]."""
    return {
        "name": output.stem,
        "kind": "sb3",
        "description": f"{algo.upper()} trained on {scenario.env_id} for {trained} steps "
                       f"(seed {seed}) with tap-bench" + (
                           f"; the weights of its best evaluation, at {kept['timesteps']} "
                           "steps." if kept is not None else "."),
        "params": {
            "model": output.name,
            "algo": algo,
            "env": scenario.env_id,
            **({"womd": list(scenario.files), "traffic": scenario.traffic, "egos": egos}
               if isinstance(scenario, WomdScenes) else {}),
            **(split.record() if split is not None else {}),
            "observation": observation,
            # an action config of its own (a safety layer): rollouts drive it with that
            **({"action": dict(scenario.config["action"])} if isinstance(scenario, WomdScenes)
               and scenario.config.get("action") is not None else {}),
            **({"reward": _reward_config(scenario)} if isinstance(scenario, WomdScenes)
               else {}),
            "timesteps": trained,
            **({"interrupted_of": asked} if interrupted else {}),
            **({"kept": "best", "kept_timesteps": int(kept["timesteps"]),
                "kept_eval_return": round(float(kept["return_mean"]), 3),
                "kept_eval_crash_rate": float(kept["crash_rate"])}
               if kept is not None else {"kept": "last"}),
            "n_envs": n_envs,
            "fast": fast,
            "seed": seed,
            "hyperparameters": params,
            "curve": None if curve is None else {
                "points": curve.points, "seeds": curve.seeds,
                "reference": str(curve.reference), "level": curve.level},
            "train_seconds": round(train_seconds, 1),
            # the curve's evaluations included (CPU of the training alone is not separable)
            **({"cpu_seconds": round(cpu_seconds, 1)} if cpu_seconds == cpu_seconds else {}),
            "command": command or " ".join(shlex.quote(a) for a in sys.argv),
        },
    }


def _write_curve(result: TrainingResult, curve_callback: Any, *, algo: str,
                 scenario: Scenario, seeds: Any) -> TrainingResult:
    """Write the learning curve's table and plot beside the model; ``result`` with them."""
    table = curve_callback.curve
    output = result.model_path
    stem = output.with_suffix("")
    curve_path = write_table(table, f"{stem}.curve.csv")
    plot_path = plot_curve(table, f"{stem}.curve.png", kept=result.kept_timesteps,
                           title=f"{output.stem}: {algo.upper()} on {scenario.env_id}, "
                                 f"evaluated on seeds {seeds}; coverage of "
                                 f"{curve_callback.reference.description}")
    return dataclasses.replace(result, curve=table, curve_path=curve_path, plot_path=plot_path)


def _json_record(value: Any) -> Any:
    """How the definition records a hyperparameter JSON cannot hold (SB3 takes classes and
    functions, such as an activation or a learning-rate schedule): a numpy number by its
    value, a class or function by its module and qualified name, anything else by its
    ``repr``."""
    if hasattr(value, "item") and hasattr(value, "dtype") and getattr(value, "ndim", 1) == 0:
        return value.item()
    if isinstance(value, type) or (callable(value) and hasattr(value, "__qualname__")):
        return f"{value.__module__}.{value.__qualname__}"
    return repr(value)


def training_outputs(output: str | os.PathLike) -> list[Path]:
    """The files :func:`train` writes for model ``output``: the model, its definition and
    its learning curve (table and plot)."""
    output = Path(output)
    stem = output.with_suffix("")
    return [output, output.with_suffix(".json"), Path(f"{stem}.curve.csv"),
            Path(f"{stem}.curve.png")]


def _trained_here(output: Path) -> bool:
    """Whether the files of model ``output`` are those of an earlier ``tap-bench train``:
    the definition beside it is one train wrote for that model."""
    definition = output.with_suffix(".json")
    try:
        doc = json.loads(definition.read_text())
    except (OSError, ValueError):
        return False
    params = doc.get("params") if isinstance(doc, dict) else None
    return (isinstance(params, dict) and doc.get("kind") == "sb3"
        and params.get("model") == output.name and "command" in params
        and "with tap-bench" in str(doc.get("description", "")))


def _reward_config(scenario: WomdScenes) -> dict[str, float]:
    """The reward settings recorded scenes train with (the env's, over its defaults: the
    ``*_reward`` keys of :meth:`~tap_bench.sim.womd_env._WomdHighwayEnv.default_config`)."""
    from tap_bench.sim.womd_env import _WomdHighwayEnv

    config = {**_WomdHighwayEnv.default_config(), **scenario.config}
    return {key: float(value) for key, value in config.items() if key.endswith("_reward")}


def _observation_config(scenario: Scenario | WomdScenes) -> dict[str, Any]:
    """The observation config the agent reads: the scenario's, else the env's default (on
    recorded scenes the Kinematics observation with the route and the leader:
    :mod:`tap_bench.sim.womd_observation`)."""
    config = scenario.config.get("observation")
    if config is None and isinstance(scenario, WomdScenes):
        from tap_bench.sim.womd_env import _WomdHighwayEnv

        config = _WomdHighwayEnv.default_config()["observation"]
    if config is None:
        config = env_class(scenario.highway_env_id).default_config()["observation"]
    return dict(config)
