"""Derived outputs kept in the episode cache (issue 24 section 3): a re-run reads the scores,
the roads, the report's figures and the viewer's episode data of unchanged inputs, and
serves exactly what it would have made; a change of any input (a value of any table, a
setting, the code) makes them again; a damaged entry is never used."""

from __future__ import annotations

import functools
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench import cache as cache_module
from tap_bench.bench.cache import (
    EpisodeCache,
    derived_key,
    memoised,
    table_digest,
)
from tap_bench.bench.report.page import write_plots
from tap_bench.bench.run.runner import run_suite
from tap_bench.bench.scores.scoring import Scores, scores_from_files, scores_to_files
from tap_bench.bench.suite import Suite, suite_from_dict


def tiny():
    return suite_from_dict({"name": "tiny", "envs": ["merge", "highway"],
                            "policies": ["idm", "lane-keeping"], "seeds": "0-2",
                            "reference_policy": "idm",
                            "env_overrides": {"merge": {"duration": 4},
                                              "highway": {"duration": 4}},
                            "bootstrap": {"n_resamples": 200}}, check_names=False)


def run(folder, cache):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_suite(tiny(), folder, workers=1, progress=False, cache=cache)


def _files(folder, pattern):
    return {p.relative_to(folder).as_posix(): p.read_bytes()
            for p in sorted(folder.glob(pattern))}


def _index(folder):
    """The viewer's index without what names the run (its folder and time)."""
    text = (folder / "viewer" / "data" / "index.js").read_text()
    text = text.replace(folder.name, "RUN")
    return re.sub(r'"created":"[^"]*"', '"created":""', text)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("derived")
    cache = EpisodeCache(root / "cache")
    cold = run(root / "run-cold", None)
    first = run(root / "run-first", cache)
    return root, cold, first, cache


def test_a_rerun_serves_the_scores_figures_and_viewer_it_would_make(runs, monkeypatch):
    root, cold, first, cache = runs
    kinds = {p.name: len(list(p.glob("*/*.derived"))) for p in cache.derived_folder.iterdir()}
    assert kinds == {"scores": 1, "roads": 2, "plots": 1, "viewer": 1, "runs": 1}
    # without the whole run (tests/bench/test_run_cache.py), a re-run goes through the steps
    shutil.rmtree(cache.derived_folder / "runs")

    def fail(*args, **kwargs):
        raise AssertionError("made again")

    # a re-run makes none of them again: the roads (no highway-env), the scores, the figures
    # and the viewer's episode data all come from the cache
    monkeypatch.setattr(Suite, "road", fail)
    monkeypatch.setattr("tap_bench.bench.run.scoring.score", fail)
    monkeypatch.setattr("tap_bench.bench.report.page.draw_figures", fail)
    monkeypatch.setattr("tap_bench.bench.report.viewer.build.episode_chunks", fail)
    again = run(root / "run-again", cache)
    for result in (first, again):
        for name in ("plots/*.svg", "viewer/data/*-*.js", "*.parquet"):
            assert _files(result.folder, name) == _files(cold.folder, name), name
        assert _index(result.folder) == _index(cold.folder)
        for name, table in cold.scores.tables().items():
            pd.testing.assert_frame_equal(table, result.scores.tables()[name],
                                          check_exact=True, obj=name)
        assert result.summary["headline"] == cold.summary["headline"]
        assert result.summary["verdict"] == cold.summary["verdict"]
        assert list(result.scores.methods.items()) == list(cold.scores.methods.items())
        report = result.report.read_text().replace(result.folder.name, "RUN")
        expected = cold.report.read_text().replace(cold.folder.name, "RUN")
        strip = re.compile(r"<h3>Timings</h3>.*?</table>|\d{4}-\d\d-\d\d \d\d:\d\d:\d\d", re.S)
        assert strip.sub("", report) == strip.sub("", expected)


def test_a_damaged_entry_is_made_again(runs, tmp_path):
    _, cold, _, cache = runs

    damaged = EpisodeCache(tmp_path / "cache")
    shutil.copytree(cache.root, damaged.root)
    entries = sorted(damaged.derived_folder.glob("*/*/*.derived"))
    for k, path in enumerate(entries):  # each torn, flipped or emptied
        data = path.read_bytes()
        path.write_bytes([data[:-5], data[:-3] + bytes([data[-3] ^ 1]) + data[-2:], b""][k % 3])
    result = run(tmp_path / "run", damaged)
    for name in ("plots/*.svg", "viewer/data/*-*.js", "*.parquet"):
        assert _files(result.folder, name) == _files(cold.folder, name), name
    assert all(p.stat().st_size > 0 for p in damaged.derived_folder.glob("*/*/*.derived"))


@functools.cache
def _scores(seed: int = 0) -> Scores:
    """Scores of 64 drawn episodes (made once per seed: the tests only read them)."""
    from tap_bench.bench.scores.scoring import score
    from tap_bench.stats.bootstrap import BootstrapConfig

    from .conftest import make_episodes

    rng = np.random.default_rng(seed)
    labels = ["Straight | Maintain Speed", "Left Merge > Straight | Accelerate",
              "Right Merge | Decelerate"]
    rows = [{"env": env, "policy": policy, "seed": s, "scenario_id": f"{env}/{policy}/s{s}",
             "sdl": labels[rng.integers(3)], "crashed": bool(rng.random() < 0.3),
             "mean_speed": rng.normal(20, 2), "min_headway_s": rng.normal(2, .3),
             "min_ttc_s": rng.uniform(2, 9), "rms_jerk": rng.normal(3, 1)}
            for env in ("highway", "merge") for policy in ("idm", "random")
            for s in range(8)]
    return score(make_episodes(rows), reference_policy="idm", level="maneuver",
                 config=BootstrapConfig(n_resamples=100))


def _changed(table: pd.DataFrame, rng: np.random.Generator) -> pd.DataFrame:
    """``table`` with one value changed: a float nudged by one ulp, an int by one, a
    string by one character, a bool flipped."""
    out = table.copy()
    row = int(rng.integers(len(out)))
    col = out.columns[int(rng.integers(len(out.columns)))]
    value = out[col].iloc[row]
    if isinstance(value, bool | np.bool_):
        new = not value
    elif isinstance(value, float | np.floating):
        new = np.nextafter(value, np.inf) if np.isfinite(value) else 0.0
    elif isinstance(value, int | np.integer):
        new = value + 1
    else:
        new = f"{value}x"
    out[col] = out[col].astype(object)
    out.iloc[row, out.columns.get_loc(col)] = new
    return out.astype(table.dtypes.to_dict()) if not isinstance(new, str) else out


@pytest.fixture(scope="module")
def _drawn(tmp_path_factory) -> Path:
    """A cache holding the figures of ``_scores()`` (reference idm), drawn once: each test
    below starts from a copy (``_cache_of_drawn``) and draws changed inputs into it."""
    root = tmp_path_factory.mktemp("drawn")
    write_plots(_scores(), root / "a", reference="idm", cache=EpisodeCache(root / "cache"))
    return root / "cache"


def _cache_of_drawn(drawn: Path, tmp_path: Path) -> EpisodeCache:
    shutil.copytree(drawn, tmp_path / "cache")
    return EpisodeCache(tmp_path / "cache")


@pytest.mark.parametrize("seed", range(12))
def test_a_change_of_any_value_of_any_scores_table_redraws_the_figures(_drawn, tmp_path, seed):
    scores = _scores()
    cache = _cache_of_drawn(_drawn, tmp_path)
    rng = np.random.default_rng(seed)
    names = [n for n, t in scores.tables().items() if len(t)]
    name = names[seed % len(names)]
    changed = Scores(**{**scores.tables(), name: _changed(getattr(scores, name), rng)},
                     methods=scores.methods)
    assert table_digest(getattr(changed, name)) != table_digest(getattr(scores, name))
    cold = {p.name: p.read_bytes() for p in write_plots(changed, tmp_path / "cold",
                                                         reference="idm")}
    warm = {p.name: p.read_bytes() for p in write_plots(changed, tmp_path / "warm",
                                                         reference="idm", cache=cache)}
    assert warm == cold


def test_another_reference_or_level_redraws_the_figures(_drawn, tmp_path):
    scores = _scores()
    cache = _cache_of_drawn(_drawn, tmp_path)
    for kwargs in ({"reference": "random"}, {"reference": "idm", "level": 0.9}):
        cold = {p.name: p.read_bytes() for p in write_plots(scores, tmp_path / "c2", **kwargs)}
        warm = {p.name: p.read_bytes() for p in write_plots(scores, tmp_path / "w2",
                                                             cache=cache, **kwargs)}
        assert warm == cold


@pytest.mark.parametrize("change", [{"label": "fastest speed"}, {"unit": "km/h"},
                                    {"higher_is_better": False}, {"bounds": (0.0, 60.0)}])
def test_a_measure_entry_changed_with_the_same_scores_redraws_the_figures(_drawn, tmp_path,
                                                                          monkeypatch, change):
    # a plug-in's measure can change its label, unit, direction or bounds with the same
    # values: the figures draw them, so they must not come from the cache unchanged
    import dataclasses

    from tap_bench.bench.measures import MEASURES

    scores = _scores()
    cache = _cache_of_drawn(_drawn, tmp_path)
    entries = dict(MEASURES._entries)
    entries["mean_speed"] = dataclasses.replace(entries["mean_speed"], **change)
    monkeypatch.setattr(MEASURES, "_entries", entries)
    cold = {p.name: p.read_bytes() for p in write_plots(scores, tmp_path / "cold",
                                                         reference="idm")}
    warm = {p.name: p.read_bytes() for p in write_plots(scores, tmp_path / "warm",
                                                         reference="idm", cache=cache)}
    assert warm == cold


def test_a_scene_measure_entry_is_in_the_figures_key(tmp_path, monkeypatch):
    # the trade-off view picks its measures by role from the measures and the scene
    # measures (measures_with_role): a scene measure's entry is part of what is drawn
    import dataclasses

    from tap_bench.bench.measures import SCENE_MEASURES
    from tap_bench.bench.report import page as report_page

    scores = _scores()
    seen = []
    monkeypatch.setattr(report_page, "draw_figures", lambda *a: seen.append(1) or {})
    cache = EpisodeCache(tmp_path / "cache")
    write_plots(scores, tmp_path / "a", reference="idm", cache=cache)
    entries = dict(SCENE_MEASURES._entries)
    name = next(iter(entries))
    entries[name] = dataclasses.replace(entries[name], label="another label")
    monkeypatch.setattr(SCENE_MEASURES, "_entries", entries)
    write_plots(scores, tmp_path / "b", reference="idm", cache=cache)
    assert len(seen) == 2


def test_memoised_builds_on_a_new_key_and_reads_on_the_same(tmp_path, monkeypatch):
    cache = EpisodeCache(tmp_path / "cache")
    calls = []

    def build(value):
        def made():
            calls.append(value)
            return {"v.txt": value.encode()}
        return made

    def get(inputs, value):
        return memoised(cache, "plots", inputs, build(value), dict, dict)["v.txt"].decode()

    assert get({"a": 1}, "one") == "one"
    assert get({"a": 1}, "two") == "one" and calls == ["one"]  # read back
    assert get({"a": 2}, "two") == "two"  # another input
    assert get(None, "three") == "three" and calls == ["one", "two", "three"]  # not keyed
    assert memoised(None, "plots", {"a": 1}, build("four"), dict, dict)["v.txt"] == b"four"
    monkeypatch.setattr(cache_module, "_PACKAGE_CODE", ["other code"])
    monkeypatch.setattr(cache_module, "_package_digest", lambda: "other code")
    assert get({"a": 1}, "five") == "five"  # the code changed
    key, _ = derived_key("plots", {"a": 1})
    path = cache.derived_path("plots", key)
    # an entry copied under another key, or of another kind, is refused and made again
    other, _ = derived_key("plots", {"a": 3})
    cache.derived_path("plots", other).parent.mkdir(parents=True, exist_ok=True)
    cache.derived_path("plots", other).write_bytes(path.read_bytes())
    assert get({"a": 3}, "six") == "six"
    files, note = cache.read_derived("viewer", key)
    assert files is None and note is None


def test_a_value_the_files_cannot_hold_is_built_and_not_kept(tmp_path):
    cache = EpisodeCache(tmp_path / "cache")

    def encode(value):
        raise TypeError("cannot hold")

    assert memoised(cache, "plots", {"a": 1}, lambda: 5, encode, dict) == 5
    assert not cache.derived_folder.exists()
    # a file name the cache does not keep: built, the run goes on
    out = memoised(cache, "plots", {"a": 1}, lambda: {"é.svg": b"x"}, dict, dict)
    assert out == {"é.svg": b"x"}


def test_scores_read_back_equal_value_for_value():
    scores = _scores(3)
    back = scores_from_files(scores_to_files(scores))
    for name, table in scores.tables().items():
        pd.testing.assert_frame_equal(table, getattr(back, name), check_exact=True, obj=name)
    assert list(back.methods.items()) == list(scores.methods.items())  # in order
    assert back.references.keys() == scores.references.keys()
    for name, ref in scores.references.items():
        other = back.references[name]
        assert list(ref.items) == list(other.items) and (ref.weights == other.weights).all()
        assert (ref.kind, ref.level, ref.description, ref.n_trajectories) == \
            (other.kind, other.level, other.description, other.n_trajectories)


def test_table_digest_sees_every_value_bit_and_type():
    table = pd.DataFrame({"x": [0.0, 1.5, np.nan], "s": ["a", "b", "c"], "b": [True, False,
                                                                            True]})
    base = table_digest(table)
    assert table_digest(table.copy()) == base
    variants = [table.assign(x=[-0.0, 1.5, np.nan]),
                table.assign(x=[0.0, np.nextafter(1.5, 2), np.nan]),
                table.assign(s=["a", "b", "d"]), table.assign(b=[True, True, True]),
                table.rename(columns={"x": "y"}), table.astype({"x": "float32"}),
                table.iloc[:2], table.iloc[::-1], table.assign(s=pd.Categorical(table["s"])),
                table.assign(extra=[[1], [2], [3]])]
    digests = {table_digest(v) for v in variants}
    assert base not in digests and len(digests) == len(variants)
    assert table_digest(None) != table_digest(pd.DataFrame())


def test_table_digest_is_the_same_for_equal_content_as_labelled_and_cached():
    """What a freshly labelled and a cached episode give alike: strings in an object or a
    str column, NaN with any payload (a cached row's NaN is JSON's)."""
    payload = np.array([0x7FF8000000000001, 0xFFF8000000000000], dtype="u8").view("f8")
    fresh = pd.DataFrame({"s": pd.Series(["a", None, "c"], dtype="str"),
                          "x": [1.0, payload[0], payload[1]]})
    cached = pd.DataFrame({"s": pd.Series(["a", None, "c"], dtype=object),
                           "x": [1.0, np.nan, np.nan]})
    assert table_digest(fresh) == table_digest(cached)
    assert table_digest(fresh) != table_digest(cached.assign(s=["a", None, "d"]))


def test_an_output_built_while_the_package_was_edited_is_not_kept(tmp_path, monkeypatch):
    """The key's code is hashed when the run starts; the report and the viewer are imported
    later. A module edited in between made the output with the new code under the old
    code's key, and a checkout back to the old files was served it (review5)."""
    cache = EpisodeCache(tmp_path / "cache")
    monkeypatch.setattr(cache_module, "_PACKAGE_CODE", ["code at the start"])
    now = {"code": "code at the start"}
    monkeypatch.setattr(cache_module, "_package_digest", lambda: now["code"])

    def edited_while_built():
        now["code"] = "edited"
        return {"v.txt": b"new code's output"}

    out = memoised(cache, "plots", {"a": 1}, edited_while_built, dict, dict)
    assert out == {"v.txt": b"new code's output"}  # returned, written by the run
    key, _ = derived_key("plots", {"a": 1})
    assert not cache.derived_path("plots", key).exists()  # not kept under the old key
    now["code"] = "code at the start"  # back on the files the key names: kept
    memoised(cache, "plots", {"a": 1}, lambda: {"v.txt": b"old"}, dict, dict)
    assert cache.derived_path("plots", key).exists()


def test_the_package_digest_sees_every_edit_and_only_edits(tmp_path):
    package = tmp_path / "tap_bench"
    shutil.copytree(Path(cache_module.__file__).resolve().parents[1], package,
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    first = cache_module._package_digest(package)
    assert cache_module._package_digest(package) == first
    assert first == cache_module._package_digest()  # the package itself, unchanged
    module = package / "bench" / "report" / "page.py"
    text = module.read_text()
    module.write_text(text + "\n")
    assert cache_module._package_digest(package) != first
    module.write_text(text)
    assert cache_module._package_digest(package) == first
    (package / "bench" / "extra.py").write_text("")
    assert cache_module._package_digest(package) != first
