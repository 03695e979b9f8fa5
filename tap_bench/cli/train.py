"""``tap-bench train``: train a Stable-Baselines3 agent on a scenario (CPU)."""

from __future__ import annotations

import argparse
import shlex


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train", help="train a Stable-Baselines3 agent (DQN, PPO, A2C) on a scenario",
        description="Train a Stable-Baselines3 agent on a scenario and write the model (.zip) "
        "with a policy definition (.json) beside it, so that it loads by name. Needs the sb3 "
        "extra (pip install torch==2.13.0, then pip install 'tap-bench[sb3]').")
    p.add_argument("--algo", required=True, help="dqn, ppo or a2c")
    p.add_argument("--env", required=True, help="scenario name (highway) or id")
    p.add_argument("--timesteps", type=int, required=True, help="decisions to train for")
    p.add_argument("--seed", type=int, default=0, help="training seed (default 0)")
    p.add_argument("-o", "--output", required=True,
                   help="model file, e.g. policies/dqn-highway.zip")
    p.add_argument("--no-coverage", action="store_true",
                   help="do not label episodes or log behaviour coverage (faster)")
    p.add_argument("--log-dir", help="write SB3's training log as CSV there")
    p.add_argument("-v", "--verbose", action="count", default=0, help="SB3 verbosity")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tap_bench.sim.training import train

    command = "tap-bench train " + " ".join(
        shlex.quote(a) for a in ("--algo", args.algo, "--env", args.env, "--timesteps",
                                 str(args.timesteps), "--seed", str(args.seed), "-o",
                                 args.output))
    result = train(args.algo, args.env, timesteps=args.timesteps, seed=args.seed,
                   output=args.output, coverage=not args.no_coverage, log_dir=args.log_dir,
                   verbose=args.verbose, command=command)
    cov = "" if result.coverage is None else f", last coverage {result.coverage:.2f}"
    print(f"trained {args.algo} on {args.env} for {args.timesteps} steps in "
          f"{result.seconds:.0f} s ({result.episodes} episodes{cov})")
    print(f"wrote {result.model_path} and {result.definition_path}")
    return 0
