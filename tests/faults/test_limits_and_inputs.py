"""Limits (huge seed ranges), empty and odd inputs, and the command line's manners: each
case warns or errors by name, and none ends in a traceback."""

from __future__ import annotations

import json
import resource

import pandas as pd
import pytest
from fault_helpers import PROJECT_ROOT, label_table, run_process, womd_shard

from tap_bench.errors import ParameterError, UnknownNameError, did_you_mean
from tap_bench.sim.scenario_format import MAX_SEEDS, parse_seeds


# -- seed ranges ------------------------------------------------------------------------
@pytest.mark.parametrize("spec", ["0-999999999", "0-99999999", "5,0-100000",
                                  range(10**12), list(range(MAX_SEEDS + 1))])
def test_a_huge_seed_range_is_refused_by_count_before_any_seed_is_made(spec):
    """`--seeds 0-999999999` once grew to 21 GB before it was killed."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(ParameterError, match=r"more than the maximum of 100,000 .*MAX_SEEDS"):
        parse_seeds(spec, source="--seeds")
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak < 64 * 1024  # KiB


def test_the_largest_legitimate_range_is_parsed():
    seeds = parse_seeds(f"0-{MAX_SEEDS - 1}")
    assert len(seeds) == MAX_SEEDS and seeds[-1] == MAX_SEEDS - 1
    with pytest.raises(ParameterError, match="given twice"):
        parse_seeds("0-9,5")
    with pytest.raises(ParameterError, match="2\\^63"):
        parse_seeds(2**64)


def test_huge_seed_ranges_on_the_command_line_and_in_a_suite_are_exit_2(tmp_path, cli):
    code, _, err = cli("rollout", "--env", "highway", "--policy", "idm", "--seeds",
                       "0-999999999", "-o", tmp_path / "t.parquet")
    assert code == 2 and "MAX_SEEDS" in err and "Traceback" not in err
    suite = tmp_path / "big.json"
    suite.write_text(json.dumps({"name": "big", "envs": ["highway"], "policies": ["idm"],
                                 "seeds": "0-99999999"}))
    code, _, err = cli("bench", "run", "--suite", suite, "-o", tmp_path / "run")
    assert code == 2 and "100,000" in err and "big.json" in err
    assert not (tmp_path / "run").exists() and not (tmp_path / "t.parquet").exists()


# -- empty and odd inputs ------------------------------------------------------------------
def test_an_all_invalid_table_is_an_error_by_name(tmp_path, cli):
    traj = tmp_path / "t.parquet"
    assert cli("sample", "-o", traj)[0] == 0
    table = pd.read_parquet(traj)
    table.assign(valid=False).to_parquet(tmp_path / "invalid.parquet")
    code, _, err = cli("label", tmp_path / "invalid.parquet", "-o", tmp_path / "l.parquet")
    assert code == 2 and "nothing to label" in err and "'valid' is False on every row" in err
    assert not (tmp_path / "l.parquet").exists()
    table.iloc[:0].to_parquet(tmp_path / "empty.parquet")
    code, _, err = cli("label", tmp_path / "empty.parquet", "-o", tmp_path / "l.parquet")
    assert code == 2 and "empty.parquet: the table is empty" in err


def test_compare_without_a_shared_env_and_seed_warns_by_name(tmp_path, cli):
    a, c = tmp_path / "a.parquet", tmp_path / "c.parquet"
    label_table("a", range(6)).to_parquet(a)
    label_table("c", range(10, 16)).to_parquet(c)
    code, _, err = cli("compare", a, c, "-o", tmp_path / "cmp", "--resamples", "100")
    assert code == 0
    assert "share no (env, seed)" in err and "seeds 0-5" in err and "seeds 10-15" in err


def test_resume_makes_a_damaged_part_again_and_keeps_the_damaged_file(tmp_path, cli):
    from tap_bench.womd.writer import write_womd

    src = tmp_path / "src"
    src.mkdir()
    traj = tmp_path / "t.parquet"
    assert cli("sample", "-o", traj)[0] == 0
    table = pd.read_parquet(traj)
    first = table["scenario_id"].unique()[:2]
    write_womd(table[table["scenario_id"] == first[0]], src / "a.tfrecord")
    write_womd(table[table["scenario_id"] == first[1]], src / "b.tfrecord")
    out = tmp_path / "parts"
    assert cli("ingest", "womd", src, "-o", out)[0] == 0
    part = out / "a.tfrecord.parquet"
    whole = part.read_bytes()
    part.write_bytes(whole[:100])  # an interrupted copy
    code, _, err = cli("ingest", "womd", src, "-o", out, "--resume")
    assert code == 0 and "cannot be read as Parquet; it is made again" in err
    assert part.read_bytes() == whole
    assert (out / ".a.tfrecord.parquet.damaged").read_bytes() == whole[:100]
    report = json.loads((out / "_report.json").read_text())
    entry = next(s for s in report["shards"] if s["output"] == str(part))
    assert entry["redone"] and report["notes"]
    assert sorted(pd.read_parquet(out)["scenario_id"].unique()) == sorted(first)


def test_label_and_fit_name_a_damaged_part_in_the_report_and_the_provenance(tmp_path, cli):
    traj = tmp_path / "t.parquet"
    assert cli("sample", "-o", traj)[0] == 0
    table = pd.read_parquet(traj)
    shards = tmp_path / "shards"
    shards.mkdir()
    ids = table["scenario_id"].unique()
    half = len(ids) // 2
    table[table["scenario_id"].isin(ids[:half])].to_parquet(shards / "p0.parquet")
    table[table["scenario_id"].isin(ids[half:])].to_parquet(shards / "p1.parquet")
    (shards / "p2.parquet").write_bytes(b"PAR1 not really")
    code, _, err = cli("label", shards, "-o", tmp_path / "labels")
    assert code == 0 and "p2.parquet failed" in err
    report = json.loads((tmp_path / "labels" / "_report.json").read_text())
    assert [s["ok"] for s in report["shards"]] == [True, True, False]
    code, _, err = cli("fit", shards, "-o", tmp_path / "th.json", "--methods", "grid")
    assert code == 0 and "p2.parquet left out of the fit" in err
    dataset = json.loads((tmp_path / "th.json").read_text())["provenance"]["dataset"]
    assert "2 of 3 shards; failed:" in dataset and "p2.parquet" in dataset


# -- the command line's manners ---------------------------------------------------------
def test_did_you_mean_ignores_case(cli):
    assert "Did you mean 'highway'?" in str(did_you_mean("env", "HIGHWAY", ["highway", "merge"]))
    with pytest.raises(UnknownNameError, match="Did you mean 'idm'"):
        from tap_bench.sim.policies import get_definition

        get_definition("IDM")
    code, _, err = cli("rollout", "--env", "HIGHWAY", "--policy", "idm", "--seeds", "0",
                       "-o", "unused.parquet")
    assert code == 2 and "Did you mean 'highway'" in err


def test_a_closed_pipe_ends_quietly(tmp_path):
    """`tap-bench policies | head` once ended in BrokenPipeError."""
    result = run_process("policies", shell_pipe="head -c 1 >/dev/null", cwd=tmp_path)
    assert b"Traceback" not in result.stderr and b"BrokenPipe" not in result.stderr
    assert result.returncode in (0, 141)  # 141: the reader left first, as for any program


def test_progress_bars_go_only_to_a_terminal_unless_asked(tmp_path, cli, monkeypatch):
    """In this process, its stderr captured (not a terminal, as a child's piped stderr is
    not): the command decides from ``sys.stderr.isatty()`` alike."""
    path = womd_shard(tmp_path / "s.tfrecord")
    monkeypatch.chdir(tmp_path)
    code, _, err = cli("ingest", "womd", path, "-o", tmp_path / "a.parquet")
    assert code == 0 and "ingest:" not in err and "\r" not in err
    code, _, err = cli("ingest", "womd", path, "-o", tmp_path / "b.parquet", "--progress")
    assert code == 0 and "ingest:" in err


def test_a_model_zip_reads_the_observation_of_the_definition_beside_it(tmp_path):
    """`--policy policies/ppo-highway.zip` failed: the env was built without the
    model's observation config, which its definition .json records."""
    from tap_bench.sim.policies import get_definition, load_policy

    zipped = PROJECT_ROOT / "policies" / "ppo-highway.zip"
    by_zip, by_name = get_definition(zipped), get_definition("ppo-highway")
    assert by_zip.params["observation"] == by_name.params["observation"] == {
        "type": "Kinematics"}
    assert load_policy(zipped).observation == {"type": "Kinematics"}  # the model is not loaded
    alone = tmp_path / "ppo-copy.zip"
    alone.write_bytes(zipped.read_bytes())
    assert "observation" not in get_definition(alone).params  # no definition beside it


@pytest.mark.slow
def test_a_model_zip_rolls_out(tmp_path, cli):
    pytest.importorskip("stable_baselines3")
    code, _, err = cli("rollout", "--env", "highway", "--policy",
                         PROJECT_ROOT / "policies" / "ppo-highway.zip", "--seeds", "0",
                         "--duration", "2", "-o", tmp_path / "t.parquet")
    assert code == 0, err

