"""Agents over training seeds on real scenes, against the human: a hand-made run folder of
two scenes whose figures are worked out by hand."""

from __future__ import annotations

from types import SimpleNamespace

import pandas as pd
import pytest

from tap_bench.bench.report.agents import agents_report_section, write_agents_page
from tap_bench.bench.scores.agents import (
    SeedGroupError,
    agent_of,
    agents_figures,
    expand_seed_groups,
    seed_group,
    seed_groups,
)
from tap_bench.errors import FileFormatError

GROUPS = {"ppo": ("ppo-s0", "ppo-s1")}

# (policy, scene, route progress, at fault, lateral, longitudinal, interaction)
EPISODES = [
    ("log", "A", 1.0, 0, ["Left Turn"], ["Maintain Speed"], ["Following (5)"]),
    ("log", "B", 1.0, 0, ["Straight"], ["Decelerate"], []),
    ("ppo-s0", "A", 0.4, 1, ["Left Turn"], ["Accelerate"], []),  # adds Accelerate, crashes
    ("ppo-s0", "B", 1.0, 0, ["Straight"], ["Decelerate"], []),
    ("ppo-s1", "A", 0.9, 0, ["Left Turn"], ["Maintain Speed"], []),
    ("ppo-s1", "B", 0.8, 0, ["Straight"], ["Decelerate"], []),
    ("idm", "A", 1.0, 0, ["Left Turn"], ["Maintain Speed"], ["Following (7)"]),
    ("idm", "B", 0.5, 0, ["Straight"], ["Maintain Speed"], []),
]


@pytest.fixture
def run(tmp_path):
    """A run folder with the episodes and ego segments of :data:`EPISODES`."""
    episodes, segments = [], []
    for policy, scene, progress, fault, *axes in EPISODES:
        sid = f"{scene}/{policy}"
        episodes.append({"env": "womd", "policy": policy, "seed": "AB".index(scene),
                         "scenario_id": sid, "status": "ok", "route_progress": progress,
                         "crashed_at_fault": float(fault), "crashed": float(fault),
                         "off_road": 0.0})
        for axis, labels in zip(("lateral", "longitudinal", "interaction"), axes,
                                strict=True):
            for label in labels:
                segments.append({"scenario_id": sid, "is_ego": True, "level": "maneuver",
                                 "axis": axis, "label": label, "t_start": 0.0, "t_end": 9.0})
        segments.append({"scenario_id": sid, "is_ego": False, "level": "maneuver",
                         "axis": "lateral", "label": "U-Turn", "t_start": 0.0, "t_end": 9.0})
    pd.DataFrame(episodes).to_parquet(tmp_path / "episodes.parquet")
    pd.DataFrame(segments).to_parquet(tmp_path / "segments.parquet")
    return tmp_path


def row(table: pd.DataFrame, **where) -> dict:
    mask = pd.Series(True, index=table.index)
    for key, value in where.items():
        mask &= table[key] == value
    assert mask.sum() == 1, where
    return table[mask].iloc[0].to_dict()


def test_a_seed_group_names_its_seeds_and_refuses_to_drive():
    definitions = {"ppo": SimpleNamespace(kind="seeds", params={"seeds": ["a", "b"]},
                                          path=None),
                   "idm": SimpleNamespace(kind="idm", params={}, path=None)}
    assert seed_groups(definitions) == {"ppo": ("a", "b")}
    assert agent_of("b", {"ppo": ("a", "b")}) == "ppo" and agent_of("idm", {}) == "idm"
    with pytest.raises(SeedGroupError, match="stands for 2 trained seeds"):
        seed_group("ppo", ["a", "b"])
    bad = {"x": SimpleNamespace(kind="seeds", params={"seeds": []}, path=None)}
    with pytest.raises(FileFormatError, match="non-empty list"):
        seed_groups(bad)
    twice = {**definitions, "dqn": SimpleNamespace(kind="seeds", params={"seeds": ["a"]},
                                                   path=None)}
    with pytest.raises(FileFormatError, match="already a seed"):
        seed_groups(twice)


def test_the_shipped_seed_groups_name_policies_that_exist():
    from tap_bench.sim.policies import available_policies

    known = available_policies()
    for agent, seeds in seed_groups(known).items():
        assert all(seed in known and known[seed].kind == "sb3" for seed in seeds), agent


def test_figures_over_seeds_and_scenes(run):
    result = agents_figures(run, groups=GROUPS, n_resamples=200)
    # route progress IQM of ppo over its 2 runs x 2 scenes: the middle of 0.4 0.8 0.9 1.0
    ppo = row(result.aggregates, agent="ppo", measure="route_progress")
    assert ppo["estimate"] == pytest.approx(0.85) and ppo["runs"] == 2
    assert ppo["low"] <= 0.85 <= ppo["high"]
    fault = row(result.aggregates, agent="ppo", measure="crashed_at_fault")
    assert fault["estimate"] == pytest.approx(0.25) and fault["low"] <= fault["high"]
    # P(ppo > idm) on progress: scene A 0 (0.4, 0.9 < 1.0), scene B 1 (1.0, 0.8 > 0.5)
    poi = row(result.improvement, agent="ppo", over="idm", measure="route_progress")
    assert poi["probability"] == pytest.approx(0.5)
    # at-fault collisions, fewer better: A: one run worse, one tied (1/4); B tied (1/2)
    poi = row(result.improvement, agent="ppo", over="idm", measure="crashed_at_fault")
    assert poi["probability"] == pytest.approx(0.375)
    profile = result.profiles[(result.profiles["agent"] == "ppo")
                              & (result.profiles["tau"].round(2) == 0.5)]
    assert profile["share"].iloc[0] == pytest.approx(0.75)


def test_coverage_of_the_human_unique_manoeuvres_and_safety_by_own_label(run):
    result = agents_figures(run, groups=GROUPS, n_resamples=100)
    cover = result.coverage
    # the human's 5 manoeuvres: A Left Turn, Maintain Speed, Following; B Straight, Decelerate
    assert row(cover, agent="ppo", run="ppo-s0")["coverage"] == pytest.approx(3 / 5)
    assert row(cover, agent="ppo", run="ppo-s1")["coverage"] == pytest.approx(4 / 5)
    assert row(cover, agent="ppo", run="(mean over runs)")["coverage"] == pytest.approx(0.7)
    # IDM follows another car on A (the track id is not part of the manoeuvre)
    assert row(cover, agent="idm", run="idm")["coverage"] == pytest.approx(4 / 5)
    unique = row(result.unique, agent="ppo", manoeuvre="longitudinal: Accelerate")
    assert unique["runs"] == 1 and unique["scenes"] == "A"
    assert unique["episodes"] == "A/ppo-s0"
    assert set(result.unique["agent"]) == {"ppo", "idm"}  # IDM: Maintain Speed on B
    crash = row(result.safety, agent="ppo", kind="manoeuvre", label="Left Turn | Accelerate")
    assert crash["at_fault"] == 1 and crash["episodes"] == 1
    calm = row(result.safety, agent="ppo", kind="manoeuvre", label="Straight | Decelerate")
    assert calm["at_fault"] == 0 and calm["episodes"] == 2


def test_the_page_links_the_failures_to_the_viewer(run):
    result = agents_figures(run, groups=GROUPS, n_resamples=100)
    page = write_agents_page(result, run / "agents").read_text()
    assert 'href="../viewer/index.html#ep=A%2Fppo-s0&amp;b=log"' in page
    assert "Left Turn | Accelerate" in page and (run / "agents" / "profiles.png").is_file()
    assert (run / "agents" / "aggregates.csv").is_file()


def test_a_run_without_the_human_is_refused(run):
    episodes = pd.read_parquet(run / "episodes.parquet")
    episodes[episodes["policy"] != "log"].to_parquet(run / "episodes.parquet")
    with pytest.raises(FileFormatError, match="human"):
        agents_figures(run, groups=GROUPS)


def test_the_figures_on_some_scenes_only(run):
    result = agents_figures(run, groups=GROUPS, n_resamples=100, scenes=[1])
    ppo = row(result.aggregates, agent="ppo", measure="route_progress")
    assert ppo["scenes"] == 1 and ppo["estimate"] == pytest.approx(0.9)  # 1.0 and 0.8
    with pytest.raises(FileFormatError, match="no finished episode on scene"):
        agents_figures(run, groups=GROUPS, scenes=[7])


def test_scenes_the_run_does_not_have_are_refused_not_dropped(run):
    """``--scenes 1,7`` on a run of scenes 0 and 1 (the held-out scenes of other files, say)
    is refused naming the scene missing and those the run has: judged on scene 1 alone, the
    figures would pass for those of both."""
    with pytest.raises(FileFormatError, match=r"scene\(s\) 7 of the 1,7 asked; the run has "
                       r"scenes 0,1\."):
        agents_figures(run, groups=GROUPS, scenes=[1, 7])
    with pytest.raises(FileFormatError, match=r"scene\(s\) 5-9 of the 0,5-9 asked"):
        agents_figures(run, groups=GROUPS, scenes=[0, *range(5, 10)])


def test_the_shipped_womd_agents_suite_names_the_human_and_ppo_womd(womd_dir):
    """The shipped suite (its scenes are the sample files beside the project: skipped where
    they are absent, as on a user's clone, where loading it says which pattern matched no
    file) names the human, the baselines and ppo-womd's seeds."""
    from tap_bench.bench.suite import load_suite

    suite = load_suite("womd-agents")
    assert suite.reference == "log" and suite.all_seeds
    assert {"log", "idm", "lane-keeping", "random", "ppo-womd"} <= set(suite.policies)
    seeds = seed_groups()["ppo-womd"]
    assert expand_seed_groups(suite.policies)[-len(seeds):] == seeds


def test_the_lines_that_quote_the_shipped_agents_seeds_name_the_shipped_ones():
    """Docstrings and usage lines that spell out ``ppo-womd``'s seeds name those its
    definition names (policies/ppo-womd.json), not an earlier group's."""
    from pathlib import Path

    from tap_bench.bench.scores import agents as agents_module
    from tap_bench.sim.policies import expand_seed_groups as expand

    seeds = seed_groups()["ppo-womd"]
    quoted = ", ".join(f'"{seed}"' for seed in seeds)
    assert f'{{"seeds": [{quoted}]}}' in " ".join(agents_module.__doc__.split())
    assert f'("idm", "{seeds[0]}", ...)' in expand.__doc__
    script = Path(__file__).resolve().parents[2] / "benchmarks" / "agents_validation.py"
    assert f"--pool ppo-womd={','.join(seeds)}" in script.read_text()


def test_bench_run_plans_every_seed_of_an_agent_the_suite_names(tmp_path):
    import json

    from tap_bench.bench.run.plan import plan_suite

    group = tmp_path / "two-drivers.json"  # an "agent" whose seeds are two baselines
    group.write_text(json.dumps({"name": "two-drivers", "kind": "seeds",
                                 "params": {"seeds": ["idm", "lane-keeping"]}}))
    suite = tmp_path / "s.json"
    suite.write_text(json.dumps({"name": "s", "envs": ["highway"], "seeds": "0-1",
                                 "policies": ["random", str(group), "idm"],
                                 "reference_policy": "random"}))
    plan = plan_suite(suite)
    assert plan.document["policies"] == ["random", "idm", "lane-keeping"]
    assert [d.name for d in plan.definitions] == ["random", "idm", "lane-keeping"]


def test_the_bench_report_gathers_the_seeds_of_an_agent(run):
    episodes = pd.read_parquet(run / "episodes.parquet")
    parts = agents_report_section(run, episodes, reference="log", level=0.95,
                                  viewer="viewer/index.html", groups=GROUPS)
    text = "\n".join(parts)
    assert "Agents over training seeds" in text and "ppo (2 seeds)" in text
    # ppo's route progress over 2 seeds x 2 scenes: 0.4, 0.8, 0.9, 1.0 -> IQM 0.85
    assert "0.85 [" in text
    assert (run / "agents" / "agents.html").is_file()
    assert "../viewer/index.html" in (run / "agents" / "agents.html").read_text()
    # no seed of an agent in the run, or another reference: no section
    assert agents_report_section(run, episodes[episodes["policy"] != "ppo-s0"].iloc[:0],
                                 reference="log", level=0.95, viewer=None,
                                 groups=GROUPS) == []
    assert agents_report_section(run, episodes, reference="idm", level=0.95, viewer=None,
                                 groups=GROUPS) == []


def test_agents_on_a_folder_names_its_womd_files_so_the_viewer_finds_them(
        womd_dir, monkeypatch, tmp_path):
    """``tap-bench agents RUN --womd FOLDER``: the suite names the folder's WOMD files (its
    README left out), in the order a run reads the folder (the same scene indices), so the
    replay viewer reads them again for the signals; named as the folder, it warned that the
    files were gone and showed no signals."""
    import argparse
    import os
    import warnings

    import tap_bench.bench.run.runner as runner
    from tap_bench.bench.report.viewer.build import _present_files
    from tap_bench.cli.agents import _run_suite
    from tap_bench.sources.ingest import record_files

    seen = {}
    monkeypatch.setattr(runner, "run_suite", lambda suite, *a, **k: seen.update(suite=suite))
    args = argparse.Namespace(suite="womd-agents", womd=[str(womd_dir)], traffic="log",
                              run=str(tmp_path / "run"), workers=1, overwrite=False,
                              no_cache=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the folder's README is left out with a note
        _run_suite(args)
    envs = seen["suite"].to_dict()["envs"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        present = _present_files({"suite": {"envs": envs}})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert present == [os.path.abspath(p) for p in record_files([womd_dir])]


def test_the_command_says_what_its_figures_are_of_and_which_bootstrap(run, capsys):
    """``tap-bench agents`` prints the scenes, the env with its traffic and the bootstrap its
    intervals come from; its help says the default interval resamples whole training seeds
    (it said 'stratified', the one --resample task gives)."""
    import json

    from tap_bench.cli import build_parser, main

    episodes = pd.read_parquet(run / "episodes.parquet")  # the human stood still on B
    episodes.loc[episodes["seed"] == 1, "route_progress"] = float("nan")
    episodes.to_parquet(run / "episodes.parquet")
    (run / "summary.json").write_text(json.dumps(
        {"suite": {"envs": [{"womd": ["x.tfrecord"], "traffic": "idm", "name": "womd"}]}}))
    assert main(["agents", str(run), "--resamples", "100"]) == 0
    out = capsys.readouterr().out
    assert ("on 2 scene(s) (0,1) of env womd (idm traffic); route progress on the 1 where "
            "the human moved; intervals: 95% bootstrap over whole training seeds, 100 "
            "resamples") in out
    parser = build_parser(["agents", str(run)])
    agents = parser._subparsers._group_actions[0].choices["agents"]
    text = " ".join(agents.description.split())
    assert "bootstrap interval over training seeds (whole seeds resampled; --resample " \
        "task: rliable's stratified bootstrap)" in text


def test_the_readme_judges_ppo_womd_on_the_scenes_it_never_saw():
    """The README's agents section shows the command that judges ``ppo-womd`` on the sample
    and development scenes it did not train on: its --womd files are those every seed
    trained on, in their order (a scene is an index in them), its --scenes every seed's
    held-out scenes; and the scenes it names as trained on are the seeds' train_scenes."""
    import re
    import shlex
    from pathlib import Path

    from tap_bench.cli import build_parser
    from tap_bench.sim.policies import available_policies
    from tap_bench.sim.scenario_format import parse_seeds

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    section = readme[readme.index("**Agents on real scenes, over training seeds.**"):]
    section = section[:section.index("\n## ")]
    known = available_policies()
    params = [known[seed].params for seed in seed_groups(known)["ppo-womd"]]
    lines = [ln for ln in re.findall(r"^tap-bench agents .*$", section, flags=re.M)
             if "--scenes" in ln]
    assert lines, "no README line judges ppo-womd on its held-out scenes"
    for line in lines:
        argv = shlex.split(line.split("#")[0])[1:]
        args = build_parser(argv).parse_args(argv)
        for p in params:
            assert [str(Path(f)) for f in args.womd] == [str(Path(f)) for f in p["womd"]]
            assert list(parse_seeds(args.scenes)) == p["held_out_scenes"]
    train = params[0]["train_scenes"]
    assert all(p["train_scenes"] == train for p in params)
    assert f"scenes {', '.join(map(str, train[:-1]))} and {train[-1]}" in " ".join(section.split())


def test_a_suite_without_the_human_is_refused_before_its_episodes_run(monkeypatch, tmp_path):
    """``--womd FILES --suite S`` with a suite that lacks the human: refused naming the suite
    and its policies before any episode runs (it ran them all, then refused)."""
    import argparse

    import tap_bench.bench.run.runner as runner
    from tap_bench.cli.agents import _run_suite
    from tap_bench.errors import ParameterError

    monkeypatch.setattr(runner, "run_suite", lambda *a, **k: pytest.fail("the suite ran"))
    args = argparse.Namespace(suite="rl-highway", womd=[str(tmp_path / "x.tfrecord")],
                              traffic="log", run=str(tmp_path / "run"), workers=1,
                              overwrite=False, no_cache=True)
    with pytest.raises(ParameterError, match=r"--suite must be a suite with the human \('log'"
                       r".*'rl-highway' has idm, .*: add 'log' to them, or use womd-agents"):
        _run_suite(args)


def test_a_run_without_a_viewer_says_how_to_make_the_links_open(run, capsys):
    """The page links scenes to RUN/viewer/; a run without one (bench run --no-report) gets
    a line saying which command writes it."""
    from tap_bench.cli import main

    assert main(["agents", str(run), "--resamples", "100"]) == 0
    assert (f"the run has no replay viewer (bench run --no-report): the page's scene links "
            f"open once 'tap-bench view {run}' writes it") in capsys.readouterr().out
    (run / "viewer").mkdir()
    (run / "viewer" / "index.html").write_text("<!doctype html>")
    assert main(["agents", str(run), "--resamples", "100"]) == 0
    assert "no replay viewer" not in capsys.readouterr().out


@pytest.mark.parametrize(("options", "message"), [
    (["--traffic", "idm"], "--traffic goes with --womd"),
    (["--suite", "womd-sample", "--no-cache", "--overwrite"],
     "--suite, --no-cache and --overwrite go with --womd"),
])
def test_the_suite_s_options_without_womd_are_refused_not_ignored(run, options, message,
                                                                  capsys):
    """``tap-bench agents RUN --traffic idm`` (no --womd) read RUN as it was run, in log
    traffic, and judged it without a word: the options that say how the suite runs are
    refused without --womd."""
    from tap_bench.cli import main

    assert main(["agents", str(run), "--resamples", "100", *options]) == 2
    assert f"{message} (how the suite runs): {run} is read as it was run" in \
        capsys.readouterr().err
    assert not (run / "agents").exists()


def test_the_command_names_the_scenes_each_agent_trained_on(run):
    """Nothing in a run's outputs said which scenes an agent saw in training: the command
    prints, per agent whose definitions record them, the scenes it trained on by index in
    its training files and the --scenes that judges it on those held out."""
    from tap_bench.cli.agents import _trained_on

    trained = {"womd": ["a.tfrecord", "b.pkl"], "train_scenes": [0, 2, 3, 4],
               "held_out_scenes": [1, 5]}
    definitions = {"ppo-s0": SimpleNamespace(params=trained),
                   "ppo-s1": SimpleNamespace(params=trained),
                   "idm": SimpleNamespace(params={})}
    result = agents_figures(run, groups=GROUPS, n_resamples=100)
    assert _trained_on(result, definitions) == [
        "ppo (2 seed(s)) trained on scenes 0,2-4 of a.tfrecord b.pkl; a scene is its index "
        "in those files, in that order: on a run of them, --scenes 1,5 judges it on the "
        "scenes it never saw"]
    assert _trained_on(result, {}) == []


def test_the_figures_on_some_scenes_do_not_replace_the_page_the_report_links(run, capsys):
    """``--scenes`` without -o writes RUN/agents/scenes-<SEEDS>/: RUN/agents/ is the page of
    every scene that the run's report links to (it was overwritten by the page of fewer
    scenes, which does not say so), and the scene links still reach RUN/viewer/."""
    from tap_bench.cli import main

    assert main(["agents", str(run), "--resamples", "100"]) == 0
    every = (run / "agents" / "aggregates.csv").read_text()
    assert main(["agents", str(run), "--resamples", "100", "--scenes", "1"]) == 0
    assert (run / "agents" / "aggregates.csv").read_text() == every
    page = run / "agents" / "scenes-1" / "agents.html"
    assert f"wrote {page} and its tables" in capsys.readouterr().out
    assert 'href="../../viewer/index.html#ep=' in page.read_text()


def test_a_scenes_typo_is_refused_before_the_suite_runs(monkeypatch, tmp_path, capsys):
    """``--womd FILES --scenes 1,x``: the typo was read after every episode had run."""
    import tap_bench.bench.run.runner as runner
    from tap_bench.cli import main

    monkeypatch.setattr(runner, "run_suite", lambda *a, **k: pytest.fail("the suite ran"))
    assert main(["agents", str(tmp_path / "run"), "--womd", str(tmp_path),
                 "--scenes", "1,x"]) == 2
    assert "--scenes: 'x' in '1,x' is not a seed or a range" in capsys.readouterr().err


def test_an_existing_run_folder_says_how_to_judge_it_as_it_is(womd_dir, run, capsys):
    """``--womd FILES`` into a run folder that exists: besides --overwrite, the error names
    the command that judges the run it holds (the user re-running to re-judge)."""
    import warnings

    from tap_bench.cli import main
    from tap_bench.tableio import FOLDER_MARKER

    (run / FOLDER_MARKER).write_text("")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the folder's README is left out with a note
        assert main(["agents", str(run), "--womd", str(womd_dir)]) == 2
    assert (f"pass --overwrite to replace it. To judge the run it holds as it was run, leave "
            f"out --womd: tap-bench agents {run}") in capsys.readouterr().err


@pytest.mark.parametrize(("unit", "said"), [("run", "bootstrap over whole seeds"),
                                            ("task", "stratified bootstrap")])
def test_the_profiles_plot_says_what_its_bands_resampled(tmp_path, monkeypatch, unit, said):
    """The default bootstrap resamples whole training seeds; the title said "stratified"
    whatever was resampled."""
    import matplotlib.axes

    from tap_bench.bench.report.agents import plot_profiles

    titles = []
    original = matplotlib.axes.Axes.set_title
    monkeypatch.setattr(matplotlib.axes.Axes, "set_title",
                        lambda self, text, *a, **k: titles.append(text) or
                        original(self, text, *a, **k))
    profiles = pd.DataFrame({"agent": ["a", "a"], "tau": [0.0, 1.0], "share": [1.0, 0.5],
                             "low": [1.0, 0.4], "high": [1.0, 0.6]})
    plot_profiles(profiles, tmp_path / "p.png", level=0.95, unit=unit)
    assert titles == [f"Performance profiles (95% bands, {said})"]


def test_the_viewer_reads_a_suite_s_folder_of_womd_files_again(womd_dir):
    """A suite may name a folder of WOMD files (any suite file, not only the one `tap-bench
    agents` writes): the viewer reads its records again for the traffic signals, without
    a warning that the files are gone."""
    import warnings

    from tap_bench.bench.report.viewer.build import _add_run_signals, _present_files
    from tap_bench.sources.ingest import record_files
    from tap_bench.sources.maps import iter_road_maps

    summary = {"suite": {"envs": [{"name": "womd", "womd": [str(womd_dir)]}]}}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the folder's README is left out with a note
        records = [str(p) for p in record_files([womd_dir])]
        lit = next(road.scenario_id for road in iter_road_maps(records)
                   if road.signals is not None and road.signals.lane.size)
    chunks = {"c": [{"id": f"{lit}/log"}]}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _present_files(summary) == records
        _add_run_signals(summary, chunks)
    assert "signals" in chunks["c"][0]
