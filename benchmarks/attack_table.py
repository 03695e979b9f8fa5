"""The attack tables of issues 23 and 36: every attack class tried by running its tests,
with the number of tries (test cases; a property test counts its generated edits) and how
many held.

Each class maps to the tests that attack it (tests/faults/ and tests/bench/); the script
runs them with pytest, reads the JUnit report and prints one row per class. A try "held"
when its test passed: the attack was refused by name, handled, or changed nothing it must
not change.

A known hole is a strict ``xfail`` test: it counts as a try that did not hold (and fails the
suite the day it holds, so the table is corrected then).

Usage: ``python benchmarks/attack_table.py [--markdown] [--issue 23|36]``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

from machine import report

ROOT = Path(__file__).resolve().parents[1]

CLASSES = {
    "stale episode: an input left out of the key (byte edits of every input file, env name, "
    "script, version, versions)": ["tests/bench/test_cache_keys.py",
                                   "tests/faults/test_cache_entries.py::"
                                   "test_two_envs_of_one_config_under_two_names_do_not_share_"
                                   "episodes",
                                   "tests/faults/test_cache_entries.py::"
                                   "test_an_edited_script_or_version_is_simulated_again_and_"
                                   "named_by_check"],
    "tampered or malformed cache entries (null/list/deep headers, empty payload, phantom "
    "rows, torn and foreign entries)": [
        "tests/faults/test_cache_entries.py::test_a_malformed_entry_is_refused_deleted_and_named",
        "tests/faults/test_cache_entries.py::test_a_refused_entry_is_simulated_again_with_a_note",
        "tests/bench/test_cache.py"],
    "definitions are code (factories, vehicle types, untrusted models)": [
        "tests/faults/test_definitions_are_code.py"],
    "sizes without limits (resamples, permutations, n_envs, vehicles, lanes, duration, "
    "WOMD viewer)": ["tests/faults/test_size_limits.py",
                     "tests/faults/test_limits_and_inputs.py"],
    "replacing what tap-bench did not write (train, export, --overwrite)": [
        "tests/faults/test_never_replace.py", "tests/faults/test_outputs.py"],
    "bad records at ingest (NaN/duplicate/reversed times, inf/NaN coordinates)": [
        "tests/faults/test_ingest_validation.py"],
    "tampered baselines and run folders": ["tests/faults/test_baselines.py"],
    "tracebacks (math in names, long or reserved ids, full disk, no ego, empty gap, % in "
    "URL, -o X --cache X)": ["tests/faults/test_named_errors.py"],
    "re-runs: results identical whatever the cache holds and the workers": [
        "tests/bench/test_rerun.py"],
}
F = "tests/faults/"
CLASSES_36 = {
    "cache: user code an episode is made with (plugin policy kind and scenario kind, "
    "modules loaded by name or run from their path)": [F + "test_cache_user_code.py"],
    "cache: every kind of input a run reads edited one byte (property test, 17 kinds)": [
        F + "test_cache_inputs.py"],
    "cache: entries (WOMD rows served, damaged derived entries said, malformed refused)": [
        F + "test_cache_entries.py"],
    "files from others run no code (summary.json plugins in check and view, bench suites)": [
        F + "test_files_are_data.py"],
    "gate: settings from the suite, impossible values, checker crashes, exit codes and "
    "JSON, --update-baseline": [F + "test_gate_trust.py", F + "test_baselines.py"],
    "limits: hostile pickles, NUL CSV (plain, gzipped), workers, box sizes, times, help, "
    "advice": [F + "test_limits_trust.py"],
    "a fresh machine: tolerances against other libraries, cache times, signals": [
        "tests/sim/test_sim_womd.py::"
        "test_lane_lookup_and_projection_equal_highway_envs_on_generated_lanes",
        "tests/bench/test_run_cache.py::"
        "test_tap_bench_or_its_data_edited_while_the_run_goes_on_keeps_nothing_of_the_run",
        F + "test_signals.py"],
    "threshold fitting keeps the best evaluated": ["tests/core/test_fitting.py"],
    "quiet and loud: progress, one MapWarning, shipped models trusted, the shipped "
    "baseline named": [
        "tests/execution/test_progress.py", "tests/sim/test_womd_map_summary.py",
        F + "test_definitions_are_code.py::"
        "test_loading_a_shipped_model_does_not_warn_and_an_edited_one_does",
        F + "test_baselines.py::"
        "test_no_baseline_file_outside_the_project_points_to_the_shipped_one"],
    "the label: a lane change and its return on a straight road are merges": [
        F + "test_labels_on_straight_roads.py",
        "tests/core/test_behaviours.py::test_a_lane_change_and_its_partial_return_are_two_"
        "merges",
        "tests/core/test_behaviours.py::test_a_lane_change_with_its_partial_return_at_once_"
        "is_two_merges"],
}
"""Issue 36's classes (run with ``--issue 36``)."""
PROPERTY_EXAMPLES = {"test_any_byte_changed_in_any_input_changes_the_key": 120,
                     "test_every_input_edited_makes_the_rerun_fresh": 4}
"""Generated tries of a property test (its max_examples), counted as tries."""


def run_class(targets: list[str], xml: Path) -> tuple[int, int, list[str]]:
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
           "OMP_WAIT_POLICY": "PASSIVE"}
    subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                    "-m", "not slow", f"--junitxml={xml}", *targets], cwd=ROOT, env=env,
                   capture_output=True, text=True)
    tries = held = 0
    failed = []
    for case in ET.parse(xml).getroot().iter("testcase"):
        skipped = case.find("skipped")
        if skipped is not None and skipped.get("type") != "pytest.xfail":
            continue  # not tried here (data absent)
        weight = next((n for name, n in PROPERTY_EXAMPLES.items()
                       if case.get("name", "").startswith(name)), 1)
        tries += weight
        if skipped is None and case.find("failure") is None and case.find("error") is None:
            held += weight
        else:
            failed.append(case.get("name", ""))
    return tries, held, failed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--markdown", action="store_true", help="print a Markdown table")
    parser.add_argument("--issue", choices=("23", "36", "all"), default="all",
                        help="the classes of one issue's attack (default: all)")
    args = parser.parse_args()
    classes = {"23": CLASSES, "36": CLASSES_36, "all": {**CLASSES, **CLASSES_36}}[args.issue]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i, (name, targets) in enumerate(classes.items()):
            tries, held, failed = run_class(targets, Path(tmp) / f"{i}.xml")
            rows.append({"class": name, "tries": tries, "held": held, "failed": failed})
            print(f"{held:4d}/{tries:<4d} {name}" + (f"  FAILED: {failed}" if failed else ""),
                  flush=True)
    if args.markdown:
        print("\n| attack class | tries | held |\n|---|---:|---:|")
        for r in rows:
            print(f"| {r['class']} | {r['tries']} | {r['held']} |")
        total = sum(r["tries"] for r in rows), sum(r["held"] for r in rows)
        print(f"| **all** | {total[0]} | {total[1]} |")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    print(f"\ncommit {commit}, issue {args.issue}, {when}")
    report("attack_table", {"rows": rows}, commit=commit, issue=args.issue)


if __name__ == "__main__":
    main()
