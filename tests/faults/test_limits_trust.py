"""Limits that hold before anything is allocated or run: a ScenarioNet pickle cannot make the
restricted unpickler allocate beyond its size (nor crash numpy); a CSV that is not text
(a sparse 2 GiB file of NUL bytes) is refused before it is parsed; ``--workers`` is capped
at the usable cores with a warning; zero, negative or NaN box sizes on valid steps are
refused naming the track; a ScenarioNet rollout keeps the times ``read_womd`` gives; a
damaged file's error does not advise ``on_error='skip'`` to a rollout, which has no such
option."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
import warnings

import numpy as np
import pandas as pd
import pytest
from fault_helpers import PROJECT_ROOT, womd_shard

from tap_bench.errors import FileFormatError, WomdRecordError

HOSTILE = {
    "ndarray(shape)": "(np.ndarray, ((300_000_000,), np.dtype('f8')))",
    "_reconstruct(shape)": "(_reconstruct, (np.ndarray, (300_000_000,), b'b'))",
    "bytes(n)": "(bytes, (3_000_000_000,))",
    "object array, short list": ("(_reconstruct, (np.ndarray, (0,), b'b'), (1, (30_000_000,),"
                                 " np.dtype('O'), False, [1, 2]))"),
    "object array, short list, small": ("(_reconstruct, (np.ndarray, (0,), b'b'), (1, (1000,),"
                                        " np.dtype('O'), False, [1, 2]))"),
}

_CHILD = """
import json, pickle, sys
import numpy as np
from numpy._core.multiarray import _reconstruct
from tap_bench.sources.scenarionet import load_scenarionet


def load(case, path, hostile):
    with open(path, "wb") as f:
        pickle.dump({"metadata": {"ts": [0.0]}, "tracks": {"a": hostile}}, f)
    try:  # the peak of this process's memory (VmHWM) from here on: this case's alone
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass  # the peak of every case so far: an upper bound of this one's
    try:
        load_scenarionet(path)
        outcome = "LOADED"
    except Exception as err:
        outcome = f"{type(err).__name__} {err}"
    with open("/proc/self/status") as f:
        hwm = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
    print(json.dumps({"case": case, "outcome": outcome, "peak_mb": hwm / 1024}), flush=True)

"""

_CASE = """
class Hostile:
    def __reduce__(self):
        return {reduce}


load({case!r}, {path!r}, Hostile())
"""


@pytest.fixture(scope="module")
def hostile_loads(tmp_path_factory) -> dict[str, dict]:
    """Each hostile pickle of HOSTILE written and loaded in one child process, one after
    the other, and last the pickle of one track state named by many tracks (:data:`_SHARED`,
    read under a 3 GiB address-space limit; each case's peak memory measured from its
    start): case -> its outcome, its peak memory [MB] and its file's size [B]. A child, so
    that what it allocates is measured, and a crash of numpy would not take the test run
    with it (one child for all, about 1 CPU s a child)."""
    folder = tmp_path_factory.mktemp("hostile")
    paths = {case: folder / f"{n}.pkl" for n, case in enumerate(sorted(HOSTILE))}
    paths[SHARED] = folder / "sd_shared.pkl"  # last: it limits the child's address space
    source = _CHILD + "".join(_CASE.format(reduce=HOSTILE[case], case=case, path=str(path))
                              for case, path in paths.items() if case != SHARED)
    source += _SHARED.format(case=SHARED, path=str(paths[SHARED]))
    result = subprocess.run([sys.executable, "-c", source], capture_output=True, text=True,
                            timeout=300,
                            env={"PYTHONPATH": str(PROJECT_ROOT), "PATH": "/usr/bin:/bin"})
    assert result.returncode == 0, (result.returncode, result.stderr[-2000:])
    loads = {line["case"]: line for line in map(json.loads, result.stdout.splitlines())}
    for case, path in paths.items():
        if case in loads:
            loads[case]["size"] = path.stat().st_size
    return loads


@pytest.mark.parametrize("case", sorted(HOSTILE))
def test_a_small_hostile_pickle_allocates_nothing_large(hostile_loads, case):
    """The pickle is small; it is refused as a bad record, and loading it peaks below
    400 MB (all cases in one child process: :func:`hostile_loads`)."""
    load = hostile_loads[case]
    assert load["size"] < 4000
    assert "WomdRecordError" in load["outcome"] and "LOADED" not in load["outcome"], load
    assert load["peak_mb"] < 400, f"{case}: {load['peak_mb']:.0f} MB before it was refused"


SHARED = "one state for many tracks"
"""The case of :data:`_SHARED` in :func:`hostile_loads`."""

_SHARED = """
import resource
from tap_bench.errors import WomdRecordError
from tap_bench.sources import read_womd

N = 1_000_000  # steps, its arrays made by ndarray(shape) within the unpickler's budget


class Empty:
    def __init__(self, shape, dtype):
        self.shape, self.dtype = shape, dtype

    def __reduce__(self):
        return (np.ndarray, (self.shape, np.dtype(self.dtype)))


state = {{"position": Empty((N, 2), "f8"), "velocity": Empty((N, 2), "f8"),
          "heading": Empty((N,), "f8"), "valid": Empty((N,), "?")}}
track = {{"type": "VEHICLE", "state": state}}  # one object, pickled once, named 2,000 times
with open({path!r}, "wb") as f:
    pickle.dump({{"metadata": {{"ts": Empty((N,), "f8"), "scenario_id": "x"}},
                  "tracks": {{f"t{{i}}": track for i in range(2000)}}}}, f)
resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))  # a miss fails, never swaps
try:  # the peak of this case alone, as for the others
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")
except OSError:
    pass
try:
    read_womd([{path!r}])
    outcome = "LOADED"
except WomdRecordError as err:
    outcome = f"WomdRecordError {{err}}"
except Exception as err:
    outcome = f"{{type(err).__name__}} {{err}}"
with open("/proc/self/status") as f:
    hwm = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
print(json.dumps({{"case": {case!r}, "outcome": outcome, "peak_mb": hwm / 1024}}), flush=True)
"""


def test_a_pickle_naming_one_track_state_for_many_tracks_is_refused(hostile_loads):
    """A 19 kB pickle whose 2,000 tracks are one memoised object (each array charged once)
    would be decoded into 2,000 copies (about 160 GB): refused, naming the track, before
    any copy is made (read in :func:`hostile_loads`' child, last)."""
    load = hostile_loads[SHARED]
    assert load["size"] < 40_000
    assert load["outcome"].startswith("WomdRecordError") and "track t1" in load["outcome"], load
    assert load["peak_mb"] < 400, load


def test_a_real_scenarionet_pickle_still_loads(womd_dir):
    from tap_bench.sources.scenarionet import decode_scenarionet, load_scenarionet

    scenario = load_scenarionet(womd_dir / "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")
    table = decode_scenarionet(scenario).to_pandas()
    assert len(table) and np.isfinite(table.loc[table["valid"], "length"]).all()


def test_a_sparse_csv_of_nul_bytes_is_refused_before_it_is_parsed(tmp_path, monkeypatch):
    from tap_bench.tableio import read_table

    path = tmp_path / "big.csv"
    with path.open("wb") as f:
        f.write(b"scenario_id,track_id,t,x,y\n")
        f.truncate(2 << 30)  # 2 GiB, a hole after the header
    assert path.stat().st_blocks * 512 < 1 << 20  # sparse: nothing written to disk

    def parse(*args, **kwargs):
        raise AssertionError("pandas was asked to parse a 2 GiB file of NUL bytes")

    monkeypatch.setattr(pd, "read_csv", parse)
    with pytest.raises(FileFormatError, match=r"line 2, byte 1 is a NUL byte"):
        read_table(path)



def test_a_gzipped_csv_of_nul_bytes_is_refused_before_it_is_parsed(tmp_path, monkeypatch):
    """The same zeros behind gzip (64 MiB in a 65 kB file; 2 GiB fit in 2 MB): scanned as
    they are decompressed, a block at a time, never parsed."""
    import gzip

    from tap_bench.tableio import read_table

    path = tmp_path / "big.csv.gz"
    with gzip.open(path, "wb", compresslevel=1) as f:
        f.write(b"scenario_id,track_id,t,x,y\n")
        for _ in range(64):
            f.write(bytes(1 << 20))
    assert path.stat().st_size < 1 << 20

    def parse(*args, **kwargs):
        raise AssertionError("pandas was asked to parse 64 MiB of NUL bytes")

    monkeypatch.setattr(pd, "read_csv", parse)
    with pytest.raises(FileFormatError, match=r"line 2, byte 1 is a NUL byte"):
        read_table(path)



def test_a_gzipped_csv_cut_short_is_one_named_error(tmp_path):
    """A .csv.gz cut short (a download stopped): the file named, no EOFError traceback."""
    import gzip

    from tap_bench.tableio import read_table

    data = gzip.compress(b"scenario_id,track_id,t,x,y\n" + b"s,1,0.0,1.0,2.0\n" * 5000)
    (tmp_path / "cut.csv.gz").write_bytes(data[:len(data) // 2])
    with pytest.raises(FileFormatError, match=r"cut\.csv\.gz: cannot read it as csv"):
        read_table(tmp_path / "cut.csv.gz")


def test_a_csv_name_on_a_device_is_not_read(tmp_path):
    """A .csv name that is a link to /dev/zero: refused as no regular file, never read."""
    from tap_bench.tableio import read_table

    (tmp_path / "z.csv").symlink_to("/dev/zero")
    with pytest.raises(FileFormatError, match="not a regular file"):
        read_table(tmp_path / "z.csv")


def test_a_text_csv_and_a_gzipped_one_still_read(tmp_path):
    from tap_bench.tableio import read_table

    table = pd.DataFrame({"scenario_id": ["a", "b"], "x": [1.0, 2.0]})
    for name in ("t.csv", "t.csv.gz"):
        table.to_csv(tmp_path / name, index=False)
        pd.testing.assert_frame_equal(read_table(tmp_path / name), table,
                                      check_dtype=False)


def test_workers_are_capped_at_the_usable_cores_with_a_warning(monkeypatch, tmp_path):
    from tap_bench.bench.run import runner
    from tap_bench.bench.run import served as run_cache
    from tap_bench.cli import main
    from tap_bench.execution import usable_cores

    asked = {}

    def run_suite(*args, workers, **kwargs):
        asked["workers"] = workers
        raise KeyboardInterrupt

    monkeypatch.setattr(runner, "run_suite", run_suite)
    monkeypatch.setattr(run_cache, "serve_unchanged", lambda *a, **k: None)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        code = main(["bench", "run", "--no-cache", "-o", str(tmp_path / "run"),
                     "--workers", str(usable_cores() + 10), "--no-progress"])
    assert code == 130 and asked["workers"] == usable_cores()
    assert any("core" in str(w.message) and "--workers" in str(w.message) for w in said)



def test_workers_asked_of_the_demo_agents_or_run_suite_are_capped_too():
    """``tap-bench demo``, ``tap-bench agents`` and ``run_suite(workers=...)`` make their
    pool of local processes here, with the same cap and warning."""
    from tap_bench.execution import resolve_backend, usable_cores

    with pytest.warns(UserWarning, match=r"more than the \d+ core"):
        backend = resolve_backend(None, usable_cores() + 10)
    assert backend.workers == usable_cores()


def _sized_pickle(path, value) -> str:
    t = np.arange(20) * 0.1
    track = {"type": "VEHICLE", "state": {
        "position": np.c_[t * 10, np.zeros(20)], "velocity": np.c_[np.full(20, 10.0),
                                                                   np.zeros(20)],
        "heading": np.zeros(20), "valid": np.ones(20, bool),
        "length": np.r_[np.full(5, 4.5), value, np.full(14, 4.5)], "width": np.full(20, 2.0),
        "height": np.full(20, 1.5)}}
    with path.open("wb") as f:
        pickle.dump({"metadata": {"scenario_id": "s", "ts": t, "dataset": "waymo",
                                  "sdc_id": "7"}, "tracks": {"7": track}}, f)
    return str(path)


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_a_box_size_that_is_not_a_length_is_refused(tmp_path, value):
    from tap_bench.sources import read_womd

    path = _sized_pickle(tmp_path / "sd_s.pkl", value)
    with pytest.raises(WomdRecordError, match=r"track 7 step 5: length .* not a box size"):
        read_womd([path])
    assert len(read_womd([_sized_pickle(tmp_path / "sd_ok.pkl", 4.4)]))


def test_a_scenarionet_rollout_keeps_read_womds_times(womd_dir):
    from tap_bench.sim.policies import load_policy
    from tap_bench.sim.womd_env import make_womd_env
    from tap_bench.sources import read_womd

    path = str(womd_dir / "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")
    recorded = read_womd([path])
    env = make_womd_env(path)
    policy = load_policy("log")
    obs, _ = env.reset(seed=0)
    policy.reset(env, seed=0)
    for _ in range(6):
        obs, _, terminated, truncated, _ = env.step(policy.act(obs))
        if terminated or truncated:
            break
    rolled = env.trajectories(policy="log")
    times = np.sort(recorded["t"].unique())
    assert not np.allclose(times[1], round(times[1], 6), rtol=0, atol=0)  # 0.10001802
    assert set(rolled["t"].unique()) <= set(times - times[0])


def test_a_damaged_files_rollout_error_does_not_advise_an_option_rollout_lacks(tmp_path, cli):
    """The command line's message (in this process, as ``cli`` runs it: the same entry
    point and handler as ``python -m tap_bench``, without a child's start-up)."""
    path = womd_shard(tmp_path / "s.tfrecord")
    data = bytearray(path.read_bytes())
    data[14] ^= 0xFF  # a byte of the first record's data: its CRC fails
    path.write_bytes(bytes(data))
    code, _, err = cli("rollout", "--womd", path, "--policy", "log", "-o",
                       tmp_path / "out.parquet")
    assert code == 2, err
    assert "on_error='skip' to" not in err and "with on_error='skip'." not in err
    assert "a rollout reads whole files" in err, err
