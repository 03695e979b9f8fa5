"""``rollout --womd --backend ray``: scenes sharded by file over a local cluster of 2 workers
stream back to the driver's parts and give the local run's tables; a worker that dies in
the middle of a scene loses no scene (it runs again on another attempt)."""

from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scale"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "sim"))

from scale_scenes import scene_files

from tap_bench.sim.rollout_stream import stream_rollout
from tap_bench.sim.womd_scene import WomdScenes


class DiesOnce:
    """IDM that kills its worker process (``os._exit``) the first time it meets ``seed``,
    leaving ``marker`` behind: a worker lost in the middle of a scene."""

    def __init__(self, marker: str, seed: int):
        from tap_bench.sim.policies import load_policy

        self.inner = load_policy("idm")
        self.name, self.observation = self.inner.name, self.inner.observation
        self.marker, self.seed = marker, seed

    def reset(self, env, *, seed: int) -> None:
        if seed == self.seed and not os.path.exists(self.marker):
            open(self.marker, "w").close()
            os._exit(1)
        self.inner.reset(env, seed=seed)

    def act(self, observation):
        return self.inner.act(observation)


def test_a_ray_run_gives_the_local_tables_and_a_dead_worker_loses_no_scene(ray_backend,
                                                                           tmp_path):
    import ray.cloudpickle

    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers lack tests/
    files = tuple(scene_files(tmp_path / "scenes", 6, per_file=2))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        local = stream_rollout(WomdScenes(files), "idm", "all", tmp_path / "local.parquet",
                               progress=False)
        marker = tmp_path / "died"
        on_ray = stream_rollout(WomdScenes(files), DiesOnce(str(marker), 3), "all",
                                tmp_path / "ray.parquet", backend=ray_backend,
                                progress=False)
    assert marker.exists()  # a worker died in scene 3
    assert list(on_ray.episodes["status"]) == ["ok"] * 6
    assert on_ray.rows == local.rows > 0
    for name in ("{}.parquet", "{}.episodes.parquet"):
        ray_file, local_file = (tmp_path / name.format(k) for k in ("ray", "local"))
        pd.testing.assert_frame_equal(pd.read_parquet(ray_file), pd.read_parquet(local_file))
        assert ray_file.read_bytes() == local_file.read_bytes()
