"""The README's examples run as written, each in a fresh process: every Python block, and
every command line that needs neither data the README does not make nor a long run (those
run in the slow test, or are listed with the reason they cannot run here).

Commands run in README order in one folder, so a file one command writes is there for the
next; the folder starts with ``trajectories.parquet`` (the built-in sample, as ``tap-bench
sample`` writes it) and ``rollouts.parquet`` (short rollouts of two policies), the files
the README's examples read, and ``data/training/`` links to the real WOMD sample files
(``../shared/data/womd``, read there, never copied) so the WOMD examples run as written
when those files are present. ``tap-bench`` runs as ``python -m tap_bench``, the same entry
point, so that the checkout under test is the one that runs.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
WOMD_DATA = ROOT.parent / "shared" / "data" / "womd"
HAVE_WOMD = WOMD_DATA.is_dir() and any(WOMD_DATA.glob("*.tfrecord*"))

QUICK = {
    "tap-bench sample -o sample.parquet",
    "tap-bench label sample.parquet -o labels.csv --level all --segments segments.csv",
    "tap-bench fit trajectories.parquet -o thresholds.json",
    "tap-bench label trajectories.parquet -o labels.parquet --thresholds paper --level action "
    "--segments segments.parquet",
    "tap-bench envs",
    "tap-bench policies",
    "tap-bench search labels.parquet --like behaviours:left_lane_change --metric levenshtein "
    "--d-sim 1",
    'tap-bench search labels.parquet --sdl "Straight > Left Merge > Straight | Maintain '
    'Medium Speed"',
    "tap-bench unique labels.parquet --level action -o unique.parquet",
}
SLOW = {
    "tap-bench demo",  # about 2 min on 2 cores
    "tap-bench rollout --env highway --policy idm --seeds 0-49 -o highway-idm.parquet "
    "--workers 2",
    "tap-bench evaluate trajectories.parquet --labels labels.parquet -o results/eval/",
    # the shipped DQN agent against IDM on 30 highway seeds (the sb3 extra)
    "tap-bench rollout --env highway --policy dqn-highway --seeds 0-29 -o dqn.parquet",
    "tap-bench rollout --env highway --policy idm --seeds 0-29 -o idm.parquet",
    "tap-bench compare dqn.parquet idm.parquet -o results/dqn-vs-idm/",
    # the scripted interaction suite (160 episodes) and its contexts
    "tap-bench bench run --suite interactions -o results/inter/",
    "tap-bench contexts results/inter/trajectories.parquet --a dqn-highway --b idm",
}
WOMD = {  # quick, and run in README order when the WOMD sample files are present
    "tap-bench ingest womd 'data/training/*.tfrecord*' -o womd.parquet --object-types "
    "vehicle --workers 2",
    "tap-bench label womd.parquet -o womd_labels.parquet --level all",
    "tap-bench label womd.parquet -o womd_interactions.parquet --interactions all "
    "--segments womd_segments.parquet",
    "tap-bench export womd_segments.parquet --format openlabel -o openlabel/",
}
SLOW_WOMD = {  # long, and needing the WOMD files
    "tap-bench coverage dqn.parquet --reference womd_labels.parquet --level maneuver",
    "tap-bench gap results/inter/trajectories.parquet --reference womd.parquet --min-speed 5",
}
NOT_RUN = {  # command -> why the tests cannot run it as written
    "pip install -e .": "installs the package",
    "pip install torch==2.13.0": "installs packages",
    'pip install -e ".[dev,sb3,ray]"': "installs packages",
    'python -m pytest -q -m "not slow"': "is the test suite itself",
    "tap-bench train --algo dqn --env highway --timesteps 30000 --keep best -o "
    "my-dqn.zip": "trains for about 6 minutes (tests/sim trains small agents)",
    "tap-bench bench run --suite default -o results/run-001/":
        "takes 10-27 min (tests/bench/test_cache.py runs bench run on a small suite)",
    "tap-bench bench check results/run-001/ --baseline results/baselines/default.json":
        "needs the default suite's run",
    "tap-bench ingest womd 'data/training/*.tfrecord*' -o womd/ --backend ray --address auto":
        "needs a Ray cluster and WOMD files",
    "tap-bench label womd/ -o womd_labels/ --backend ray --address auto": "needs Ray and WOMD",
    "tap-bench fit womd/ -o womd_thresholds.json --backend ray --address auto":
        "needs Ray and WOMD",
    "tap-bench bench run --suite default --backend ray --address auto -o results/run-ray/":
        "needs a Ray cluster",
}


def blocks(language: str) -> list[str]:
    """The README's fenced blocks of ``language``, in order."""
    return re.findall(rf"```{language}\n(.*?)```", README.read_text(), flags=re.S)


def commands() -> list[str]:
    """Every command of the README's bash blocks: continuation lines joined, ``&&`` chains
    split, trailing comments dropped."""
    out = []
    for block in blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            out += [re.sub(r"\s+", " ", part.strip()) for part in line.split("&&") if part]
    return out


def test_every_readme_command_is_run_or_says_why_not():
    known = QUICK | SLOW | WOMD | SLOW_WOMD | set(NOT_RUN)
    unknown = [c for c in commands() if c not in known]
    assert not unknown, f"README commands the tests do not know: {unknown}"
    stale = known - set(commands())
    assert not stale, f"listed here but no longer in the README: {stale}"


def output_of(command: str) -> str | None:
    """The file or folder a README command writes (its ``-o``), if any."""
    args = shlex.split(command)
    return args[args.index("-o") + 1] if "-o" in args else None


def test_no_readme_command_overwrites_an_earlier_output():
    seen: dict[str, str] = {}
    for command in commands():
        out = output_of(command)
        assert out is None or out not in seen, (
            f"{command!r} writes {out}, which {seen.get(out)!r} wrote before it")
        if out is not None:
            seen[out] = command


def test_readme_gives_the_real_sample_count():
    from tap_bench.synthetic import sample_table

    stated = re.search(r"\((\d+) of them:", README.read_text())
    assert stated, "the README no longer states the sample's size"
    real = sample_table().groupby(["scenario_id", "track_id"]).ngroups
    assert int(stated.group(1)) == real


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    """The folder the quick examples run in, with the files the README's examples read."""
    return make_folder(tmp_path_factory.mktemp("readme"))


def make_folder(folder: Path) -> Path:
    """``folder`` with the files the README's examples read (see the module's docstring)."""
    from tap_bench.sim.rollout import rollout
    from tap_bench.synthetic import sample_table

    sample_table().to_parquet(folder / "trajectories.parquet", index=False)
    tables = [rollout("merge", policy, "0-3", duration=5, progress=False).trajectories
              for policy in ("idm", "idm-aggressive")]
    pd.concat(tables, ignore_index=True).to_parquet(folder / "rollouts.parquet", index=False)
    if HAVE_WOMD:  # linked, never copied (Waymo's terms); README.md is left out by the glob
        (folder / "data" / "training").mkdir(parents=True)
        for path in WOMD_DATA.iterdir():
            (folder / "data" / "training" / path.name).symlink_to(path)
    return folder


def run(args: list[str], folder: Path, timeout: float) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "TAP_BENCH_CACHE": str(folder / ".cache")}
    return subprocess.run(args, cwd=folder, env=env, capture_output=True, text=True,
                           timeout=timeout)


def run_commands(selected: set[str], folder: Path, timeout: float) -> None:
    for command in commands():
        if command not in selected:
            continue
        args = shlex.split(command)
        assert args[0] == "tap-bench"
        done = run([sys.executable, "-m", "tap_bench", *args[1:]], folder, timeout)
        assert done.returncode == 0, f"{command}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"


@pytest.mark.parametrize("index", range(len(blocks("python"))))
def test_python_blocks_run_as_written_in_a_fresh_process(index, folder):
    code = blocks("python")[index]
    done = run([sys.executable, "-c", code], folder, timeout=600)
    assert done.returncode == 0, f"{code}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
    assert "Traceback" not in done.stderr, done.stderr[-3000:]


def test_the_quick_commands_run_as_written_in_order(folder):
    run_commands(QUICK | (WOMD if HAVE_WOMD else set()), folder, timeout=300)
    assert (folder / "labels.csv").is_file() and (folder / "unique.parquet").is_file()
    if HAVE_WOMD:  # label then export agree on the level, and nothing was overwritten
        assert any((folder / "openlabel").glob("*.json"))
        assert len(pd.read_parquet(folder / "labels.parquet")["level"].unique()) == 1


@pytest.mark.slow
def test_the_long_commands_run_as_written_in_order(tmp_path):
    folder = make_folder(tmp_path)  # fresh: every command writes its output once
    womd = WOMD | SLOW_WOMD if HAVE_WOMD else set()
    run_commands(QUICK | SLOW | womd, folder, timeout=3600)
    assert (folder / "results" / "demo" / "report.html").is_file()
