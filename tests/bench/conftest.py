"""Fixtures of the benchmark tests: episode tables small enough to check by hand."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.episodes import EPISODE_COLUMNS


def make_episodes(rows: list[dict]) -> pd.DataFrame:
    """An episode table from partial rows (missing measures NaN, status ok)."""
    table = pd.DataFrame(rows)
    missing = {col: {"status": "ok", "error": "", "env": "e"}.get(col, np.nan)
               for col in EPISODE_COLUMNS if col not in table.columns}
    if missing:  # added at once (half the CPU of a column at a time)
        table = pd.concat([table, pd.DataFrame(missing, index=table.index)], axis=1)
    table["sdl"] = table["sdl"].astype("string")
    return table


@pytest.fixture
def hand_pairs() -> pd.DataFrame:
    """Policies A and B on four seeds of one env.

    seed  A label  B label  A speed  B speed  A crashed  B crashed
    0     x        x        10       8        no         no
    1     x        y        12       12       no         yes
    2     y        y        9        11       no         no
    3     z        z        14       10       yes        no
    """
    rows = []
    for seed, (la, lb, va, vb, ca, cb) in enumerate([
            ("x", "x", 10, 8, False, False), ("x", "y", 12, 12, False, True),
            ("y", "y", 9, 11, False, False), ("z", "z", 14, 10, True, False)]):
        rows.append({"policy": "A", "seed": seed, "sdl": f"{la} | s", "mean_speed": va,
                     "crashed": ca})
        rows.append({"policy": "B", "seed": seed, "sdl": f"{lb} | s", "mean_speed": vb,
                     "crashed": cb})
    return make_episodes(rows)


@pytest.fixture(autouse=True)
def _quiet_gymnasium():
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*observation space.*")
        yield


def without_runs(cache):
    """``cache`` (an :class:`~tap_bench.bench.cache.EpisodeCache`) without its whole runs
    (``tests/bench/test_run_cache.py`` tests those), so that a re-run with unchanged inputs
    goes through the episode, label and derived entries these tests are about."""
    import shutil

    shutil.rmtree(cache.derived_folder / "runs", ignore_errors=True)
    return cache
