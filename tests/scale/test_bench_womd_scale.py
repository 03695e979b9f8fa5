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


def _row(tree: str, digest: str, cpu: float) -> dict:
    return {"tree": tree, "commit": tree, "scenes": 3, "steps_per_cpu_s": 100.0 / cpu,
            "cpu_s": cpu, "cpu_s_per_scene": cpu / 3, "peak_mb": 1.0, "load_before": 0.5,
            "load_after": 0.5, "tables_sha256": digest}


def test_the_summary_says_whether_every_run_wrote_the_same_tables(tmp_path, capsys):
    a, b = tmp_path / "a.parquet", tmp_path / "b.parquet"
    a.write_bytes(b"one")
    b.write_bytes(b"two")
    same = bench_womd_scale.tables_digest(a, b)
    assert same == bench_womd_scale.tables_digest(a, b) != bench_womd_scale.tables_digest(b, a)
    rows = [_row("A", same, 1.0), _row("B", same, 0.9), _row("B", same, 0.8),
            _row("A", same, 1.1)]
    equal = [x for x in bench_womd_scale.summary(rows) if "tables_equal" in x]
    assert equal == [{"scenes": 3, "tables_equal": True, "tables_sha256": [same]}]
    rows[2]["tables_sha256"] = "0" * 16
    lines = bench_womd_scale.summary(rows)
    assert [x["tables_equal"] for x in lines if "tables_equal" in x] == [False]
    bench_womd_scale.print_summary(lines)
    assert "DIFFER" in capsys.readouterr().out
