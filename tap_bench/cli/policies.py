"""``tap-bench policies``: the available driving policies."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "policies", help="list the available driving policies",
        description="List the policies of policies/ (and any registered in Python) with "
        "their kind and parameters. Trained agents' figures come from held-out seeds only "
        "(policies/heldout.csv: seeds the weights were never selected on); the "
        "evaluation figures recorded at training (kept_eval_*) are of the seeds the weights "
        "were chosen on and are not shown.")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=run)


SELECTION_KEYS = ("kept_eval_return", "kept_eval_crash_rate")
"""Figures of the seeds a trained agent's weights were selected on: optimistic, not shown."""


def heldout() -> dict[str, dict[str, str]]:
    """policy -> its held-out evaluation (``heldout.csv`` of every policies folder of the
    catalogue, the first that names it)."""
    import csv

    from tap_bench import catalogue

    out: dict[str, dict[str, str]] = {}
    for folder in catalogue.folders("policies"):
        path = Path(folder) / "heldout.csv"
        if path.is_file():
            with path.open(newline="") as f:
                for row in csv.DictReader(f):
                    out.setdefault(row.get("policy", ""), row)
    return out


def run(args: argparse.Namespace) -> int:
    from tap_bench.sim.policies import available_policies

    defs = available_policies()
    held = heldout()
    if args.json:
        print(json.dumps({n: {"kind": d.kind, "description": d.description,
                              "params": dict(d.params), "held_out": held.get(n)}
                          for n, d in defs.items()}, indent=2, default=str))
        return 0
    width = max(len(n) for n in defs) if defs else 4
    for name, d in defs.items():
        print(f"{name.ljust(width)}  {d.kind:<12}  {d.description}")
        shown = {k: v for k, v in d.params.items()
                 if k not in ("observation", "hyperparameters", "command", *SELECTION_KEYS)}
        if shown:
            print(f"{'':{width}}  {'':<12}  {json.dumps(shown, default=str)}")
        h = held.get(name)
        if h:
            print(f"{'':{width}}  {'':<12}  held-out seeds {h['seeds']} ({h['episodes']} "
                  f"episodes): crash rate {float(h['crash_rate']):.2f} "
                  f"[{float(h['crash_low']):.2f}, {float(h['crash_high']):.2f}], mean return "
                  f"{float(h['mean_return']):.2f} ({h['source']})")
        elif any(k in d.params for k in SELECTION_KEYS):
            print(f"{'':{width}}  {'':<12}  no held-out evaluation recorded: its training "
                  "figures are of the seeds its weights were selected on (not shown); "
                  "evaluate it on fresh seeds (benchmarks/bench_rollout_eval.py)")
    return 0
