"""The README's examples run as written and in README order, in one folder, so what an
example writes is there for the next one and every file an example reads was made by an
earlier one (``tap-bench sample`` makes ``sample.parquet``; the simulation section's Python
block makes ``rollouts.parquet``, read by the benchmark's): every Python block (each in a
fresh process) and every command line that needs neither data the README does not make nor
a long run (those run in the slow test, again in README order, or are listed with the
reason they cannot run here). The folder starts empty but for ``data/training/``, which
links to the real WOMD sample files (``../shared/data/womd``, read there, never copied) so
the WOMD examples run as written when those files are present. ``tap-bench`` runs as
``python -m tap_bench``, the same entry point, so that the checkout under test is the one
that runs.
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
    "tap-bench fit sample.parquet -o thresholds.json",
    "tap-bench label sample.parquet -o labels.parquet --thresholds paper --level action "
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
    "tap-bench evaluate sample.parquet --labels labels.parquet -o results/eval/",
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
    "tap-bench coverage dqn.parquet --reference womd.parquet --level maneuver",
    "tap-bench gap results/inter/trajectories.parquet --reference womd.parquet --min-speed 5",
    # 36 episodes (the human, IDM, lane keeping, random and ppo-womd's 5 seeds on the 4
    # sample scenes), scored, with the report and viewer: about 2 CPU min
    "tap-bench agents results/womd-agents/ --womd 'data/training/*'",
}
NOT_RUN = {  # command -> why the tests cannot run it as written
    "pip install -e .": "installs the package",
    "pip install torch==2.13.0": "installs packages",
    'pip install -e ".[dev,sb3,ray]"': "installs packages",
    'python -m pytest -q -m "not slow" -n 2': "is the test suite itself",
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
    "tap-bench agents results/womd-dev/ --womd ../shared/data/womd "
    "../shared/data/womd-dev/dev.tfrecord --scenes 1,2,5,9,12-15":
        "reads the development scenes beside the project, not linked here (its files and "
        "scenes are ppo-womd's: tests/bench/test_agents.py)",
}


def blocks(language: str) -> list[str]:
    """The README's fenced blocks of ``language``, in order."""
    return [code for lang, code in steps_of_blocks() if lang == language]


def steps_of_blocks() -> list[tuple[str, str]]:
    """Every fenced block of the README as (language, code), in order."""
    return re.findall(r"```(\w+)\n(.*?)```", README.read_text(), flags=re.S)


def split_commands(block: str) -> list[str]:
    """The commands of a bash block: continuation lines joined, ``&&`` chains split,
    trailing comments dropped."""
    out = []
    for line in block.replace("\\\n", " ").splitlines():
        line = re.sub(r"\s+#.*$", "", line).strip()
        out += [re.sub(r"\s+", " ", part.strip()) for part in line.split("&&") if part]
    return out


def commands() -> list[str]:
    """Every command of the README's bash blocks, in order."""
    return [c for block in blocks("bash") for c in split_commands(block)]


def steps() -> list[tuple[str, str]]:
    """The README's examples in order: ("bash", one command) and ("python", one block)."""
    out = []
    for lang, code in steps_of_blocks():
        if lang == "bash":
            out += [("bash", c) for c in split_commands(code)]
        elif lang == "python":
            out.append(("python", code))
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
    """The folder the quick examples run in (see the module's docstring)."""
    return make_folder(tmp_path_factory.mktemp("readme"))


def make_folder(folder: Path) -> Path:
    """``folder`` with ``data/training/`` linking to the WOMD sample files, when present:
    nothing else; every other file an example reads, an earlier example makes."""
    if HAVE_WOMD:  # linked, never copied (Waymo's terms); README.md is left out by the glob
        (folder / "data" / "training").mkdir(parents=True)
        for path in WOMD_DATA.iterdir():
            (folder / "data" / "training" / path.name).symlink_to(path)
    return folder


def run(args: list[str], folder: Path, timeout: float) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "TAP_BENCH_CACHE": str(folder / ".cache")}
    return subprocess.run(args, cwd=folder, env=env, capture_output=True, text=True,
                           timeout=timeout)


def run_in_order(selected: set[str], folder: Path, timeout: float,
                 in_process: pytest.MonkeyPatch | None = None) -> list[str]:
    """Run the README's Python blocks and its ``selected`` commands in README order in
    ``folder``; return what ran (the commands, and ``python block N``). ``in_process``: the
    commands run as ``tap_bench.cli.main`` in this process (the same entry point as
    ``python -m tap_bench``, without a new interpreter's start-up for each), with ``folder``
    as the working folder and its own cache, set through this MonkeyPatch; the Python
    blocks always run in a fresh process."""
    from tap_bench.cli import main

    ran = []
    for n, (kind, code) in enumerate(steps()):
        if kind == "python":
            done = run([sys.executable, "-c", code], folder, timeout)
            assert done.returncode == 0, f"{code}\n{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
            assert "Traceback" not in done.stderr, done.stderr[-3000:]
            ran.append(f"python block {n}")
            continue
        if code not in selected:
            continue
        args = shlex.split(code)
        assert args[0] == "tap-bench"
        if in_process is not None:
            in_process.chdir(folder)
            in_process.setenv("TAP_BENCH_CACHE", str(folder / ".cache"))
            assert main(args[1:]) == 0, code
        else:
            done = run([sys.executable, "-m", "tap_bench", *args[1:]], folder, timeout)
            assert done.returncode == 0, (f"{code}\n{done.stdout[-2000:]}\n"
                                          f"{done.stderr[-3000:]}")
        ran.append(code)
    return ran


def test_every_file_an_example_reads_an_earlier_example_writes():
    """The inputs of the quick examples are outputs of earlier ones (or the WOMD files):
    no file is read before the README has made it."""
    made: set[str] = set()
    for kind, code in steps():
        if kind == "python":
            read = re.findall(r'read_table\("([^"]+)"\)', code)
            written = re.findall(r'to_parquet\("([^"]+)"\)', code)
        else:
            args = shlex.split(code)
            written = [args[args.index("-o") + 1]] if "-o" in args else []
            written += [args[args.index(flag) + 1] for flag in ("--segments",) if flag in args]
            read = [a for a in args[2:3] if a.endswith((".parquet", ".csv"))]
            if "--reference" in args:
                read.append(args[args.index("--reference") + 1])
        for path in read:
            assert path in made or path.startswith("results/"), (
                f"{code!r} reads {path}, which no earlier README example writes")
        made.update(written)


def test_the_quick_examples_run_as_written_in_order(folder, monkeypatch, capsys):
    ran = run_in_order(QUICK | (WOMD if HAVE_WOMD else set()), folder, timeout=600,
                       in_process=monkeypatch)
    assert "Traceback" not in capsys.readouterr().err
    assert sum(r.startswith("python block") for r in ran) == len(blocks("python"))
    assert (folder / "labels.csv").is_file() and (folder / "unique.parquet").is_file()
    assert (folder / "rollouts.parquet").is_file()  # made by the README, not by the test
    if HAVE_WOMD:  # label then export agree on the level, and nothing was overwritten
        assert any((folder / "openlabel").glob("*.json"))
        assert len(pd.read_parquet(folder / "labels.parquet")["level"].unique()) == 1


@pytest.mark.slow
def test_the_long_commands_run_as_written_in_order(tmp_path):
    folder = make_folder(tmp_path)  # fresh: every example writes its output once
    womd = WOMD | SLOW_WOMD if HAVE_WOMD else set()
    run_in_order(QUICK | SLOW | womd, folder, timeout=3600)
    assert (folder / "results" / "demo" / "report.html").is_file()
