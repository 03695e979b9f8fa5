"""``tap-bench policies``: the available driving policies."""

from __future__ import annotations

import argparse
import json


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "policies", help="list the available driving policies",
        description="List the policies of policies/ (and any registered in Python) with "
        "their kind and parameters.")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tap_bench.sim.policies import available_policies

    defs = available_policies()
    if args.json:
        print(json.dumps({n: {"kind": d.kind, "description": d.description,
                              "params": dict(d.params)} for n, d in defs.items()},
                         indent=2, default=str))
        return 0
    width = max(len(n) for n in defs) if defs else 4
    for name, d in defs.items():
        print(f"{name.ljust(width)}  {d.kind:<12}  {d.description}")
        shown = {k: v for k, v in d.params.items()
                 if k not in ("observation", "hyperparameters", "command")}
        if shown:
            print(f"{'':{width}}  {'':<12}  {json.dumps(shown, default=str)}")
    return 0
