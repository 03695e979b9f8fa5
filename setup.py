"""Build step: ship the benchmark's data (``envs/``, ``policies/``, the gate's
``results/baselines/``) inside the wheel.

The scenario, policy and suite files and the trained models stay at the top of the source
tree (the design's layout); building a wheel copies them to ``tap_bench/_catalogue/``, where
:mod:`tap_bench.catalogue` finds them after a normal (non-editable) ``pip install``. All other
metadata is in pyproject.toml.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
DATA = ("envs", "policies", "results/baselines")


class BuildWithCatalogue(build_py):
    """``build_py`` plus a copy of ``envs/`` and ``policies/`` into the built package."""

    def run(self) -> None:
        super().run()
        target = Path(self.build_lib) / "tap_bench" / "_catalogue"
        for name in DATA:
            source = HERE / name
            if not source.is_dir():
                raise SystemExit(f"cannot build tap-bench: {source} is missing")
            shutil.rmtree(target / name, ignore_errors=True)
            shutil.copytree(source, target / name,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))


setup(cmdclass={"build_py": BuildWithCatalogue})
