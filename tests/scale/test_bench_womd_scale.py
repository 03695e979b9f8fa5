"""benchmarks/bench_womd_scale.py: the measuring child's command lines are ones tap-bench
takes, and a child whose command fails stops the script with its exit code and message
(not a missing output file read afterwards)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from scale_scenes import scene_files

PROJECT_ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(PROJECT_ROOT / "benchmarks"))

import bench_womd_scale  # noqa: E402


def _tap_bench_args(cmd: list[str]) -> list[str]:
    """The arguments the child hands to ``tap_bench.cli.main``."""
    at = cmd.index(bench_womd_scale._CHILD)
    return cmd[at + 2:]


@pytest.mark.parametrize("command", bench_womd_scale.COMMANDS)
def test_each_command_line_is_one_tap_bench_parses(command, tmp_path):
    from tap_bench.bench.suite import load_suite
    from tap_bench.cli import build_parser

    files = scene_files(tmp_path / "scenes", 2, per_file=1)
    out = tmp_path / {"rollout": "out.parquet", "realism": "out.json",
                      "bench-run": "run"}[command]
    cmd = bench_womd_scale.child_command(command, files, out, tmp_path / "m.json",
                                         policy="idm", traffic="log",
                                         extra=["--no-progress"], tree=str(tmp_path))
    assert cmd[:2] == [sys.executable, "-P"]  # the tree given, not the current folder
    argv = _tap_bench_args(cmd)
    args = build_parser(argv).parse_args(argv)
    assert args.output == str(out)
    if command == "bench-run":
        assert args.no_cache and args.progress is False
        suite = load_suite(args.suite)
        assert list(suite.policies) == ["log", "idm"] and suite.reference_policy == "log"
        doc = json.loads(Path(args.suite).read_text())
        assert doc["envs"][0]["womd"] == files and doc["envs"][0]["traffic"] == "log"
    else:
        assert args.womd == files and args.policy == "idm" and args.traffic == "log"
    shown = bench_womd_scale._shown(tmp_path, cmd, files)
    assert shown.startswith("tap-bench ") and files[0] not in shown


def test_a_failing_child_stops_the_script_with_its_message(tmp_path):
    folder = tmp_path / "scenes"
    folder.mkdir()
    (folder / "a.tfrecord").write_bytes(b"")
    # a refused option: the command returns exit code 2 and writes no output
    with pytest.raises(SystemExit, match=r"(?s)exit code 2.*--resamples"):
        bench_womd_scale.run_realism(folder, tmp_path / "out.json", "idm", "log",
                                     ["--resamples", "20"], tree=str(PROJECT_ROOT))
