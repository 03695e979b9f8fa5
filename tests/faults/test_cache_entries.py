"""The episode cache never serves the wrong episode: a malformed or edited entry is refused,
deleted and simulated again with a note; an edited scripted event or env name re-simulates
and ``bench check`` names the env as changed."""

from __future__ import annotations

import hashlib
import json
import shutil
import warnings
from pathlib import Path

import pandas as pd
import pytest

from tap_bench.bench.cache import EpisodeCache, _canonical, episode_key
from tap_bench.bench.run.runner import run_suite
from tap_bench.bench.suite import suite_from_dict
from tap_bench.errors import CacheEntryWarning
from tap_bench.sim.rollout import rollout
from tap_bench.sim.scenario_env import get_scenario

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def entry(tmp_path_factory):
    """One whole entry: (cache, key, file bytes)."""
    cache = EpisodeCache(tmp_path_factory.mktemp("entry"))
    table, episodes = rollout("merge", "lane-keeping", [3], duration=2, progress=False)
    key, doc = episode_key({"env": "merge"}, {"policy": "lane-keeping"}, 3, {})
    path = cache.put(key, doc, table, episodes.iloc[0].to_dict(), 1.0)
    return cache, key, path.read_bytes()


def _header(data: bytes) -> tuple[dict, bytes]:
    line, _, payload = data.partition(b"\n")
    return json.loads(line), payload


def _resigned(header: dict, payload: bytes) -> bytes:
    """An entry whose header checksum was made again over the edited header."""
    body = {k: v for k, v in header.items() if k != "header_sha256"}
    body["header_sha256"] = hashlib.sha256(_canonical(body)).hexdigest()
    return _canonical(body) + b"\n" + payload


def _edit_row(data: bytes, **changes) -> bytes:
    header, payload = _header(data)
    header["row"].update(changes)
    return _canonical(header) + b"\n" + payload


def _empty_payload(data: bytes) -> bytes:
    header, _ = _header(data)
    header.update(payload_bytes=0, payload_sha256=hashlib.sha256(b"").hexdigest())
    return _resigned(header, b"")


def _replace_header(value) -> callable:
    return lambda data: json.dumps(value).encode() + b"\n" + data.partition(b"\n")[2]


BAD_ENTRIES = {
    "header null": _replace_header(None),
    "header a list": _replace_header([1, 2, 3]),
    "header a number": _replace_header(7),
    "header deeply nested": lambda d: b"[" * 100_000 + b"]" * 100_000 + b"\n" + d,
    "header not JSON": lambda d: b"{'format'\n" + d.partition(b"\n")[2],
    "no header line": lambda d: d.replace(b"\n", b" "),
    "empty payload with a matching hash": _empty_payload,
    "phantom crash in the episode row": lambda d: _edit_row(d, crashed=True),
    "episode row of another seed": lambda d: _edit_row(d, seed=4),
    "episode row of a failed episode, re-signed": lambda d: _resigned(
        {**_header(d)[0], "row": {**_header(d)[0]["row"], "status": "error"}}, _header(d)[1]),
    "row with a field removed, re-signed": lambda d: _resigned(
        {**_header(d)[0], "row": {k: v for k, v in _header(d)[0]["row"].items()
                                  if k != "crashed"}}, _header(d)[1]),
    "seconds as text, re-signed": lambda d: _resigned({**_header(d)[0], "seconds": "1"},
                                                      _header(d)[1]),
    "doc of another key, re-signed": lambda d: _resigned(
        {**_header(d)[0], "doc": {"env": "highway"}}, _header(d)[1]),
    "payload bit flipped": lambda d: d[:-100] + bytes([d[-100] ^ 1]) + d[-99:],
    "payload truncated": lambda d: d[:-10],
    "payload of a table of two episodes, re-signed": None,  # built in the test
    "binary garbage": lambda d: bytes(range(256)) * 10,
    "empty file": lambda d: b"",
}


def _two_episodes(data: bytes) -> bytes:
    header, payload = _header(data)
    table = pd.read_parquet(__import__("io").BytesIO(payload))
    other = table.assign(scenario_id=table["scenario_id"] + "-other")
    import io

    buffer = io.BytesIO()
    pd.concat([table, other]).to_parquet(buffer, index=False)
    payload = buffer.getvalue()
    header.update(payload_bytes=len(payload),
                  payload_sha256=hashlib.sha256(payload).hexdigest())
    return _resigned(header, payload)


@pytest.mark.parametrize("case", sorted(BAD_ENTRIES))
def test_a_malformed_entry_is_refused_deleted_and_named(entry, case):
    cache, key, data = entry
    damage = BAD_ENTRIES[case] or _two_episodes
    cache.path(key).write_bytes(damage(data))
    episode, note = cache.read(key)
    assert episode is None
    assert note is not None and cache.path(key).name in note and "refused" in note
    assert not cache.path(key).exists()
    cache.path(key).write_bytes(data)  # the whole entry reads again
    episode, note = cache.read(key)
    assert episode is not None and note is None and episode.row["seed"] == 3


def tiny(envs=("merge",), seeds="0-1", overrides=None):
    return suite_from_dict({"name": "tiny", "envs": list(envs), "policies": ["idm"],
                            "seeds": seeds, "reference_policy": "idm",
                            "env_overrides": overrides or {env: {"duration": 3}
                                                           for env in envs},
                            "bootstrap": {"n_resamples": 100}}, check_names=False)


def run(suite, folder, cache):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run_suite(suite, folder, workers=1, progress=False, report=False,
                           cache=cache)
    return result, [w for w in caught if issubclass(w.category, CacheEntryWarning)]


def test_a_refused_entry_is_simulated_again_with_a_note(tmp_path):
    cache = EpisodeCache(tmp_path / "cache")
    cold, _ = run(tiny(), tmp_path / "cold", cache)
    entries = sorted(cache.folder.glob("*/*.episode"))
    entries[0].write_bytes(b"null\n" + entries[0].read_bytes().partition(b"\n")[2])
    entries[1].write_bytes(_edit_row(entries[1].read_bytes(), crashed=True))
    # without the whole run (served from the cache: tests/bench/test_run_cache.py), the
    # re-run reads its episodes
    shutil.rmtree(cache.derived_folder / "runs")
    again, notes = run(tiny(), tmp_path / "again", cache)
    assert (again.summary["cache"]["cached"], again.summary["cache"]["simulated"]) == (0, 2)
    assert len(again.summary["cache"]["refused"]) == 2 and len(notes) == 2
    assert "simulated again" in str(notes[0].message)
    assert {w.filename for w in notes} == {__file__}  # the user's call of run_suite
    pd.testing.assert_frame_equal(cold.episodes, again.episodes)
    assert sorted(cache.folder.glob("*/*.episode")) == entries  # stored again, whole
    assert all(cache.read(p.stem)[0] is not None for p in entries)


def test_a_refused_entry_is_said_at_the_users_line_however_deep_the_check():
    from tap_bench.bench.run.tasks import check_results

    results = [{"ok": True, "cache_note": f"entry {i} refused"} for i in range(6)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_results(results, pd.DataFrame(), "tiny")  # called here: said here
    assert len(caught) == 6
    assert {w.filename for w in caught} == {__file__}


def test_two_envs_of_one_config_under_two_names_do_not_share_episodes(tmp_path):
    folder = tmp_path / "envs"
    folder.mkdir()
    doc = json.loads(get_scenario("merge").path.read_text())
    for name in ("merge_a", "merge_b"):
        (folder / f"{name}.json").write_text(json.dumps({**doc, "name": name}))
    envs = [str(folder / "merge_a.json"), str(folder / "merge_b.json")]
    cache = EpisodeCache(tmp_path / "cache")
    result, _ = run(tiny(envs=envs), tmp_path / "both", cache)
    assert result.summary["cache"]["simulated"] == 4
    assert set(result.episodes["env"]) == {"merge_a", "merge_b"}
    alone, _ = run(tiny(envs=envs[1:]), tmp_path / "b", cache)
    assert set(alone.episodes["env"]) == {"merge_b"}


def test_an_edited_script_or_version_is_simulated_again_and_named_by_check(tmp_path, cli):
    folder = tmp_path / "envs"
    folder.mkdir()
    path = folder / "cut_in.json"
    doc = json.loads(get_scenario("cut_in").path.read_text())
    path.write_text(json.dumps(doc))
    suite = tiny(envs=[str(path)], seeds="0-7", overrides={str(path): {"duration": 5}})
    cache = EpisodeCache(tmp_path / "cache")
    run(suite, tmp_path / "first", cache)
    code, _, err = cli("bench", "check", tmp_path / "first", "--baseline",
                       tmp_path / "base.json", "--update-baseline")
    assert code == 0, err
    doc["script"]["speed_offset"] = -8.0  # a more violent cut-in
    path.write_text(json.dumps(doc))
    second, _ = run(suite, tmp_path / "second", cache)
    assert second.summary["cache"] == {**second.summary["cache"], "cached": 0,
                                       "simulated": 8}
    assert second.summary["provenance"]["envs"][str(path)]["script"]["speed_offset"] == -8.0
    code, out, err = cli("bench", "check", tmp_path / "second", "--baseline",
                         tmp_path / "base.json")
    assert "script.speed_offset: 0.0 -> -8.0" in out + err
    doc["version"] = 1
    path.write_text(json.dumps(doc))
    third, _ = run(suite, tmp_path / "third", cache)
    assert third.summary["cache"]["simulated"] == 8


def test_docs_say_a_shared_cache_needs_trusted_writers():
    text = (ROOT / "docs" / "benchmark.md").read_text()
    assert "trusted writers" in text


def test_an_episode_row_of_a_recorded_scene_comes_back(entry, tmp_path):
    """A recorded scene's row holds more columns than EPISODE_COLUMNS (its own measures):
    it is the row of a successful episode, and its entry is read, not refused."""
    _, key, data = entry
    header, payload = _header(data)
    row = {**header["row"], "scenario_id": "abc", "off_road": False, "log_ade": 1.25,
           "map": "as recorded"}
    other = EpisodeCache(tmp_path / "womd")
    other.put(key, header["doc"], pd.read_parquet(__import__("io").BytesIO(payload)), row,
              1.0)
    episode, note = other.read(key)
    assert note is None and episode is not None and episode.row == row


def test_a_recorded_scene_suite_is_read_from_the_cache_on_a_rerun(womd_dir, tmp_path):
    suite = suite_from_dict({"name": "scene", "policies": ["log"], "seeds": "0",
                             "reference_policy": "log",
                             "envs": [{"womd": [str(womd_dir / "womd_scenario_input.tfrecord")],
                                       "name": "womd"}],
                             "bootstrap": {"n_resamples": 100}}, check_names=False)
    cache = EpisodeCache(tmp_path / "cache")
    first, _ = run(suite, tmp_path / "first", cache)
    shutil.rmtree(cache.labels_folder)  # the episode itself must come back
    again, notes = run(suite, tmp_path / "again", cache)
    assert first.summary["cache"]["simulated"] == 1
    assert (again.summary["cache"]["cached"], again.summary["cache"]["simulated"]) == (1, 0)
    assert not notes and not again.summary["cache"]["refused"]
    pd.testing.assert_frame_equal(first.episodes, again.episodes)


def test_a_damaged_derived_entry_is_said_and_listed(tmp_path):
    cache = EpisodeCache(tmp_path / "cache")
    run(tiny(seeds="0"), tmp_path / "first", cache)
    shutil.rmtree(cache.derived_folder / "runs")
    roads = sorted((cache.derived_folder / "roads").glob("*/*.derived"))
    assert roads
    roads[0].write_bytes(roads[0].read_bytes()[:-5])  # torn
    again, notes = run(tiny(seeds="0"), tmp_path / "again", cache)
    refused = again.summary["cache"]["refused"]
    assert any(roads[0].name in note for note in refused), refused
    assert any(roads[0].name in str(w.message) for w in notes)
    on_disk = json.loads((tmp_path / "again" / "summary.json").read_text())
    assert on_disk["cache"]["refused"] == refused
