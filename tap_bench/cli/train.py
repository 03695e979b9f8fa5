"""``tap-bench train``: train a Stable-Baselines3 agent on a scenario (CPU)."""

from __future__ import annotations

import argparse
import math
import shlex


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train", help="train a Stable-Baselines3 agent (DQN, PPO, A2C) on a scenario",
        description="Train a Stable-Baselines3 agent on a scenario and write the model (.zip) "
        "with a policy definition (.json) beside it, so that it loads by its file (--policy "
        "my-dqn.zip), or by name once in a policies/ folder on $TAP_BENCH_PATH, and its "
        "behaviour-coverage learning curve (.curve.csv, .curve.png). Training runs on the "
        "scenario's fast variant (5 Hz simulation, collisions checked for the ego only) in "
        "parallel envs; the curve evaluates the agent on the scenario itself. Needs the sb3 "
        "extra (pip install torch==2.13.0, then pip install 'tap-bench[sb3]').")
    p.add_argument("--algo", required=True, help="dqn, ppo or a2c")
    p.add_argument("--env", required=True,
                   help="scenario name (highway) or id; 'womd' trains on recorded scenes "
                   "(--womd FILES)")
    p.add_argument("--womd", nargs="+", metavar="FILE",
                   help="with --env womd: WOMD files (Scenario or tf.Example TFRecords, "
                   "ScenarioNet pickles); the agent drives the recorded ego of each scenario "
                   "in turn (tap_bench/womd-v0, 10 Hz, no learning curve)")
    p.add_argument("--traffic", choices=("log", "idm"), default="log",
                   help="with --env womd: the other agents replay the log (default) or are "
                   "driven by IDM/MOBIL")
    p.add_argument("--hold-out", metavar="SEEDS",
                   help="with --env womd: scenes never trained on, by index in the files' "
                   "scenes (the seeds a rollout or suite names, e.g. 6,9,12,15), to judge "
                   "the agent on scenes it did not see; the definition records both sets")
    p.add_argument("--egos", choices=("sdc", "all"), default="sdc",
                   help="with --env womd: drive each scene's ego (sdc, the default), or every "
                   "vehicle that drives in the training scenes in turn (all: as many "
                   "situations as the scenes hold drivers)")
    p.add_argument("--reward", nargs="+", metavar="KEY=VALUE", default=[],
                   help="with --env womd: reward settings over the env's defaults (e.g. "
                   "progress_gain_reward=2 ttc_reward=-0.05; the *_reward keys of "
                   "tap_bench/womd-v0, docs/closed_loop.md); the definition records them all")
    p.add_argument("--observation", nargs="+", metavar="KEY=VALUE", default=[],
                   help="with --env womd: settings of the agent's observation over the env's "
                   "default (KinematicsRoute with the leader), as JSON values (e.g. "
                   "crossing=true: the road users whose way crosses the ego's path; "
                   "docs/agents.md); the definition records the observation")
    p.add_argument("--action", nargs="+", metavar="KEY=VALUE", default=[],
                   help="with --env womd: settings of the agent's action over the env's "
                   "default (DiscreteMetaAction), as JSON values (e.g. safety_layer=true: "
                   "its acceleration capped by IDM's braking for the road user in its swept "
                   "box, docs/agents.md); the definition records the action")
    p.add_argument("--hyperparameters", nargs="+", metavar="KEY=VALUE", default=[],
                   help="the algorithm's settings over tap-bench's defaults, as JSON values "
                   "(e.g. gamma=0.95 n_steps=512: arguments of Stable-Baselines3's PPO, DQN "
                   "or A2C, each of its argument's type and range: gamma in [0, 1], n_steps "
                   "a whole number from 1, ...); the definition records them all")
    p.add_argument("--timesteps", type=int, required=True, help="decisions to train for")
    p.add_argument("--seed", type=_seed, default=0,
                   help="training seed, 0 to 4294967295 (default 0)")
    p.add_argument("-o", "--output", required=True,
                   help="model file, e.g. policies/dqn-highway.zip")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the model, definition and curve of an earlier 'tap-bench "
                   "train' at -o (files it did not write are never replaced)")
    p.add_argument("--n-envs", type=int, default=None,
                   help="training envs in parallel processes (default 2)")
    p.add_argument("--in-process", choices=("auto", "yes", "one", "no"), default="auto",
                   help="where the training envs are stepped; the same training (same "
                   "weights) at different speeds: one after the other in this process "
                   "(yes: the least CPU, the fastest when the cores are busy with other "
                   "work), the first in this process and the others in worker processes "
                   "(one: the fastest with about as many free cores as envs), or each in a "
                   "worker process (no: the fastest with a core more). auto (default): "
                   "chosen by the cores idle at the start")
    p.add_argument("--exact", action="store_true",
                   help="train on the scenario itself (10 Hz, every collision), not its fast "
                   "variant: about twice as slow")
    p.add_argument("--keep", choices=("last", "best"), default="last",
                   help="save the weights at the end of training (last, the default) or "
                   "those of the learning curve's evaluation with the highest mean return "
                   "(best: model selection on the curve's seeds)")
    p.add_argument("--no-curve", action="store_true",
                   help="do not evaluate the agent during training (no learning curve)")
    p.add_argument("--curve-points", type=int, default=10,
                   help="evaluations during training, besides the untrained one (default 10)")
    p.add_argument("--curve-seeds", default="500-519",
                   help="evaluation seeds of the curve (default 500-519)")
    p.add_argument("--reference", default="idm",
                   help="coverage reference: a policy whose rollouts on the curve seeds are "
                   "the reference (default idm), a label or trajectory table (.parquet/.csv, "
                   "e.g. WOMD), or 'vocabulary'")
    p.add_argument("--level", default="maneuver",
                   help="SDL level of the curve's labels (default maneuver)")
    p.add_argument("--log-dir", help="write SB3's training log as CSV there (return and "
                   "episode length per update: the learning curve on the training scenes), "
                   "and the weights at every tenth of the training (weights_<steps>_steps.zip)")
    p.add_argument("-v", "--verbose", action="count", default=0, help="SB3 verbosity")
    p.set_defaults(func=run)


def _seed(text: str) -> int:
    """``--seed``: a whole number numpy and Stable-Baselines3 take as a seed (0 to 2**32 - 1;
    a negative one failed with a traceback once the training envs had started)."""
    try:
        seed = int(text)
    except ValueError:
        seed = -1
    if not 0 <= seed < 2**32:
        raise argparse.ArgumentTypeError(f"{text!r} is not a seed: give a whole number from 0 "
                                         f"to {2**32 - 1}")
    return seed


def _curve_options(args: argparse.Namespace) -> list[str]:
    """The curve options given that differ from their defaults (they decide the curve and,
    with --keep best, the weights saved: the recorded command must repeat them)."""
    if args.no_curve:
        return ["--no-curve"]
    options = []
    for flag, value, default in (("--curve-points", str(args.curve_points), "10"),
                                 ("--curve-seeds", args.curve_seeds, "500-519"),
                                 ("--reference", args.reference, "idm"),
                                 ("--level", args.level, "maneuver")):
        if value != default:
            options += [flag, value]
    return options


def _rewards(items: list[str]) -> dict[str, float]:
    """``--reward KEY=VALUE ...`` as config: each key one of the env's ``*_reward`` settings,
    each value a number."""
    from tap_bench.sim.womd_env import _WomdHighwayEnv

    known = sorted(k for k in _WomdHighwayEnv.default_config() if k.endswith("_reward"))
    out = {}
    for item in items:
        key, _, value = item.partition("=")
        if key not in known:
            raise SystemExit(f"tap-bench train: --reward {item}: {key!r} is not a reward "
                             f"setting; use one of {', '.join(known)} (KEY=VALUE).")
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = math.nan
        if not math.isfinite(out[key]):
            raise SystemExit(f"tap-bench train: --reward {item}: {value!r} is not a finite "
                             "number; write KEY=VALUE, e.g. progress_gain_reward=2.")
    return out


def _key_values(option: str, items: list[str], example: str,
                known: list[str] | None = None, owner: str = "") -> dict[str, object]:
    """``--OPTION KEY=VALUE ...`` as a mapping, each VALUE read as JSON (true, 5, 0.95,
    "Kinematics", {"net_arch": [64]}); with ``known``, each KEY one of them (``owner`` names
    whose settings they are in the error)."""
    import json

    out: dict[str, object] = {}
    for item in items:
        key, eq, value = item.partition("=")
        if not key or not eq:
            raise SystemExit(f"tap-bench train: --{option} {item}: write KEY=VALUE, e.g. "
                             f"{example}.")
        if key in out:
            raise SystemExit(f"tap-bench train: --{option} {item}: {key!r} is given twice; "
                             "give each setting once.")
        if known is not None and key not in known:
            raise SystemExit(f"tap-bench train: --{option} {item}: {key!r} is not a setting "
                             f"of {owner}; use one of {', '.join(known)}.")
        try:
            out[key] = json.loads(value)
        except ValueError:
            raise SystemExit(f"tap-bench train: --{option} {item}: {value!r} is not a JSON "
                             "value (true, false, a number, a quoted text, a mapping).") from None
    return out


def _observation(items: list[str], part: str = "observation",
                 example: str = "crossing=true") -> dict[str, object]:
    """``--observation KEY=VALUE ...`` (or ``--action``, ``part``) as the observation (or
    action) config: the env's default with each KEY set to VALUE read as JSON (true, 5,
    "Kinematics")."""
    from tap_bench.sim.womd_env import _WomdHighwayEnv

    return {**_WomdHighwayEnv.default_config()[part], **_key_values(part, items, example)}


# arguments of an SB3 algorithm that tap-bench sets itself, not a training setting
_NOT_HYPERPARAMETERS = frozenset({"policy", "env", "seed", "verbose", "device",
                                  "tensorboard_log", "_init_setup_model"})


def _hyperparameters(algo: str, items: list[str]) -> dict[str, object]:
    """``--hyperparameters KEY=VALUE ...`` as overrides of
    :data:`tap_bench.rl.training.HYPERPARAMETERS`: each KEY an argument of the algorithm's
    Stable-Baselines3 class (not one tap-bench sets: policy, env, seed, ...), each VALUE read
    as JSON (0.95, 512, {"net_arch": [64, 64]}) of the argument's type (an int a whole
    number, a float a finite one, ...), within its range where the algorithm defines one
    (:data:`_BOUNDS`: gamma in [0, 1], n_steps at least 1, ...)."""
    import inspect

    from tap_bench.sim.sb3 import algorithm_class

    if not items:
        return {}
    parameters = inspect.signature(algorithm_class(algo)).parameters
    known = sorted(set(parameters) - _NOT_HYPERPARAMETERS)
    out = _key_values("hyperparameters", items, "gamma=0.95", known, algo.upper())
    given = {item.partition("=")[0]: item for item in items}
    for key, value in out.items():
        item = f"--hyperparameters {given[key]}"
        out[key] = _typed(item, key, value, parameters[key].annotation, algo.upper())
        if key == "policy_kwargs" and isinstance(value, dict):
            _policy_settings(algo, item, value)
        bounds = _BOUNDS.get(key)
        if bounds is not None and isinstance(out[key], int | float):
            low, low_open, high, high_open, meaning = bounds
            number = out[key]
            if (number < low or (low_open and number == low) or number > high
                    or (high_open and number == high)):
                raise SystemExit(f"tap-bench train: {item}: {key} is {meaning}; give a value "
                                 f"in {'(' if low_open else '['}{low:g}, {high:g}"
                                 f"{')' if high_open else ']'}.")
    return out


# arguments of the policy network that the algorithm passes itself
_NOT_POLICY_SETTINGS = frozenset({"observation_space", "action_space", "lr_schedule",
                                  "use_sde"})


def _policy_settings(algo: str, item: str, settings: dict) -> None:
    """``policy_kwargs``' keys and values checked against the arguments of the algorithm's
    ``MlpPolicy`` (the policy tap-bench trains: net_arch, ortho_init, ...), as
    :func:`_typed` checks the algorithm's own. Exits naming the key and what it takes."""
    import inspect

    from tap_bench.sim.sb3 import algorithm_class

    policy = algorithm_class(algo).policy_aliases["MlpPolicy"]
    parameters = inspect.signature(policy).parameters
    known = sorted(set(parameters) - _NOT_POLICY_SETTINGS)
    owner = f"{algo.upper()}'s MlpPolicy"
    for key, value in settings.items():
        if key not in known:
            raise SystemExit(f"tap-bench train: {item}: {key!r} is not a setting of {owner}; "
                             f"use one of {', '.join(known)}.")
        settings[key] = _typed(item, key, value, parameters[key].annotation, owner)


# the ranges of the algorithms' settings (as their papers define them; outside, SB3 fails
# mid-training or trains on a meaningless objective, e.g. gamma > 1):
# key -> (low, low excluded, high, high excluded, what it is)
_BOUNDS: dict[str, tuple[float, bool, float, bool, str]] = {
    "gamma": (0, False, 1, False, "the discount factor of future rewards"),
    "gae_lambda": (0, False, 1, False, "the GAE trade-off of bias and variance"),
    "learning_rate": (0, True, math.inf, True, "the optimiser's step size"),
    "n_steps": (1, False, math.inf, True, "the steps per env between updates"),
    "batch_size": (1, False, math.inf, True, "the minibatch size"),
    "n_epochs": (1, False, math.inf, True, "the passes over each rollout"),
    "clip_range": (0, True, math.inf, True, "PPO's clipping of the policy ratio"),
    "clip_range_vf": (0, True, math.inf, True, "PPO's clipping of the value function"),
    "ent_coef": (0, False, math.inf, True, "the weight of the entropy bonus"),
    "vf_coef": (0, False, math.inf, True, "the weight of the value loss"),
    "max_grad_norm": (0, True, math.inf, True, "the gradient norm clipped to"),
    "target_kl": (0, True, math.inf, True, "the KL divergence that stops an update"),
    "rms_prop_eps": (0, True, math.inf, True, "RMSprop's epsilon"),
    "buffer_size": (1, False, math.inf, True, "the replay buffer's size"),
    "learning_starts": (0, False, math.inf, True, "the steps before learning starts"),
    "tau": (0, True, 1, False, "the soft update coefficient"),
    "target_update_interval": (1, False, math.inf, True,
                               "the steps between target network updates"),
    "exploration_fraction": (0, False, 1, False, "the share of training epsilon decays over"),
    "exploration_initial_eps": (0, False, 1, False, "a probability of a random action"),
    "exploration_final_eps": (0, False, 1, False, "a probability of a random action"),
    "stats_window_size": (1, False, math.inf, True, "the episodes of the logged means"),
    "sde_sample_freq": (-1, False, math.inf, True, "the steps between gSDE noise samples "
                        "(-1: at the start of each rollout only)"),
}


def _union(kind: object) -> tuple:
    """The members of a union annotation (``float | None``), else the annotation alone."""
    import types
    import typing

    return (typing.get_args(kind)
            if typing.get_origin(kind) in (typing.Union, types.UnionType) else (kind,))


def _matches(value: object, kind: object) -> bool:
    """Whether a JSON value is of the annotated type ``kind`` (see :func:`_typed`)."""
    import typing

    if len(_union(kind)) > 1:
        return any(_matches(value, k) for k in _union(kind))
    origin, args = typing.get_origin(kind) or kind, typing.get_args(kind)
    if kind is typing.Any:
        return True
    if kind is type(None):
        return value is None
    if kind in (bool, str):
        return isinstance(value, kind)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if kind is float:
        return (isinstance(value, int | float) and not isinstance(value, bool)
                and math.isfinite(value))
    if origin is dict:
        return isinstance(value, dict) and (not args or all(
            _matches(v, args[1]) for v in value.values()))
    if origin is list:
        return isinstance(value, list) and (not args or all(_matches(v, args[0])
                                                            for v in value))
    if origin is tuple:
        return (isinstance(value, list) and len(value) == len(args)
                and all(_matches(v, a) for v, a in zip(value, args, strict=True)))
    return False  # a class, a function: nothing JSON gives


def _describe(kind: object) -> str:
    """What JSON value ``kind`` takes, in words ("" where none does: a class, a function)."""
    import typing

    if len(_union(kind)) > 1:
        return " or ".join(filter(None, (_describe(k) for k in _union(kind))))
    origin, args = typing.get_origin(kind) or kind, typing.get_args(kind)
    words = {typing.Any: "any JSON value", type(None): "null", bool: "true or false",
             str: "a quoted text", int: "a whole number", float: "a finite number"}
    if kind in words:
        return words[kind]
    if origin is dict:
        inner = _describe(args[1]) if args else ""
        return "a mapping" + (f" (each value {inner})" if args and args[1] is not typing.Any
                              and inner else "")
    if origin is list:
        inner = _describe(args[0]) if args else ""
        return "a list" + (f" (each item {inner})" if inner else "")
    if origin is tuple:
        return f"a list of {len(args)} ({', '.join(getattr(a, '__name__', str(a)) for a in args)})"
    return ""


def _typed(item: str, key: str, value: object, annotation: object, owner: str) -> object:
    """``value`` (read as JSON) as the type of the algorithm's argument (its annotation in
    the class's signature): a whole number for an int, a finite number for a float (not
    true/false), true or false for a bool, a mapping for a dict, a list for a list, each
    item of its type, null where None is taken, a list of the tuple's items for a tuple
    (as the tuple). Exits naming what it takes (``item``: the option's item, ``key`` the
    setting, ``owner`` whose setting it is)."""
    import inspect
    import typing

    if annotation is inspect.Parameter.empty or isinstance(annotation, str | typing.ForwardRef):
        return value  # a signature that does not say its type (annotations as text)
    for kind in _union(annotation):
        if _matches(value, kind):
            return (float(value) if kind is float else
                    tuple(value) if (typing.get_origin(kind) or kind) is tuple else value)
    names = [d for d in (_describe(k) for k in _union(annotation)) if d]
    if set(names) <= {"null"}:  # a class or a function: nothing JSON can give but None
        raise SystemExit(f"tap-bench train: {item}: {key} of {owner} is a class or a "
                         "function, which a JSON value cannot give"
                         + (" (null: the default)" if names else "") + "; set it in Python: "
                         "tap_bench.rl.training.train(..., hyperparameters=).")
    raise SystemExit(f"tap-bench train: {item}: {key} of {owner} takes {' or '.join(names)}.")


def run(args: argparse.Namespace) -> int:
    from tap_bench.rl.curve import CurveConfig
    from tap_bench.rl.training import DEFAULT_N_ENVS, train
    from tap_bench.sim.sb3 import algorithm_class

    algorithm_class(args.algo)  # an unknown one refused before anything is said or started

    n_envs = DEFAULT_N_ENVS if args.n_envs is None else args.n_envs
    hyperparameters = _hyperparameters(args.algo, args.hyperparameters)
    env = args.env
    recorded = []
    if args.env == "womd":
        from tap_bench.sim.womd_scene import WomdScenes

        if not args.womd:
            raise SystemExit("tap-bench train: --env womd trains on recorded scenes; name "
                             "their files with --womd FILES.")
        env = WomdScenes(tuple(args.womd), traffic=args.traffic)
        if args.reward:
            env = env.with_overrides(_rewards(args.reward))
        if args.observation:
            env = env.with_overrides({"observation": _observation(args.observation)})
        if args.action:
            from tap_bench.sim.womd_safety import safety_layer

            action = _observation(args.action, "action", "safety_layer=true")
            try:
                safety_layer(action.get("safety_layer"))
            except ValueError as err:
                raise SystemExit(f"tap-bench train: --action: {err}") from None
            env = env.with_overrides({"action": action})
        recorded = ["--womd", *args.womd, "--traffic", args.traffic,
                    *(["--hold-out", args.hold_out] if args.hold_out else []),
                    *(["--egos", args.egos] if args.egos != "sdc" else []),
                    *(["--reward", *args.reward] if args.reward else []),
                    *(["--observation", *args.observation] if args.observation else []),
                    *(["--action", *args.action] if args.action else [])]
        if not args.no_curve:
            print("recorded scenes: no learning curve (it evaluates on synthetic seeds); "
                  "compare the agent with the human afterwards: tap-bench rollout --womd ... "
                  f"--policy {args.output}")
            args.no_curve = True
    elif (args.womd or args.hold_out or args.egos != "sdc" or args.reward or args.observation
          or args.action):
        raise SystemExit("tap-bench train: --womd, --hold-out, --egos, --reward, "
                         "--observation and --action go with --env womd.")
    command = "tap-bench train " + " ".join(shlex.quote(a) for a in (
        "--algo", args.algo, "--env", args.env, *recorded,
        *(["--hyperparameters", *args.hyperparameters] if args.hyperparameters else []),
        "--timesteps", str(args.timesteps),
        "--seed",
        str(args.seed), "--n-envs", str(n_envs), *(["--exact"] if args.exact else []),
        *(["--keep", "best"] if args.keep == "best" else []), *_curve_options(args),
        "-o", args.output))
    curve = None if args.no_curve else CurveConfig(
        points=args.curve_points, seeds=args.curve_seeds, reference=args.reference,
        level=args.level)
    result = train(args.algo, env, timesteps=args.timesteps, seed=args.seed,
                   hyperparameters=hyperparameters,
                   output=args.output, n_envs=n_envs, fast=not args.exact, curve=curve,
                   log_dir=args.log_dir, verbose=args.verbose, command=command,
                   keep=args.keep, overwrite=args.overwrite,
                   announce=lambda line: print(line, flush=True),
                   in_process={"auto": None, "yes": True, "one": "one",
                               "no": False}[args.in_process],
                   hold_out=args.hold_out or None, egos=args.egos)
    print(f"trained {args.algo} on {args.env} for {result.timesteps} steps in "
          f"{result.train_seconds:.0f} s ({result.steps_per_second:.1f} steps/s, "
          f"{result.episodes} episodes)")
    kept = ("" if result.kept_timesteps is None
            else f" (the weights of its best evaluation, at {result.kept_timesteps} steps)")
    print(f"wrote {result.model_path} and {result.definition_path}{kept}")
    if result.curve is not None:
        last = result.curve.iloc[-1]
        print(f"learning curve: {len(result.curve)} evaluations on seeds {curve.seeds} "
              f"({result.seconds - result.train_seconds:.0f} s); last: return "
              f"{last['return_mean']:.2f}, crash rate {last['crash_rate']:.2f}, coverage "
              f"{last['coverage']:.2f}, diversity {last['diversity']:.2f} labels")
        print(f"wrote {result.curve_path} and {result.plot_path}")
    return 0
