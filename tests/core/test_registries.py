"""One Registry class for measures, formats, policy kinds and scenario kinds; the public
checkers run over every built-in entry and refuse broken ones with the reason."""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
import pytest

from tap_bench.bench.measures import MEASURES, SCENE_MEASURES, Measure, check_measure
from tap_bench.errors import ParameterError, RegistrationError, UnknownNameError
from tap_bench.registry import Registry
from tap_bench.sim.policies import POLICY_KINDS, PolicyKind, register_policy_kind
from tap_bench.sim.schema import (
    SCENARIO_KINDS,
    ScenarioKind,
    check_scenario_kind,
    env_class,
    scenario_kinds,
)
from tap_bench.sources import READERS, Reader, check_reader


@dataclass(frozen=True)
class _Entry:
    name: str
    size: int = 0


def test_a_registry_keeps_order_refuses_duplicates_and_suggests_names():
    def check(entry: _Entry) -> None:
        if entry.size < 0:
            raise RegistrationError(f"{entry.name}: size must be >= 0")

    reg: Registry[_Entry] = Registry("widget", check=check)
    for name in ("alpha", "beta", "gamma"):
        reg.register(_Entry(name))
    assert reg.names() == ("alpha", "beta", "gamma") and len(reg) == 3 and "beta" in reg
    with pytest.raises(RegistrationError, match="widget named 'beta' is already registered"):
        reg.register(_Entry("beta", 1))
    with pytest.raises(RegistrationError, match="size must be"):
        reg.register(_Entry("delta", -1))
    assert "delta" not in reg  # a refused entry is not half-registered
    with pytest.raises(UnknownNameError, match="Did you mean 'gamma'"):
        reg["gama"]
    reg.unregister("alpha")
    assert reg.names() == ("beta", "gamma") and reg.get("alpha") is None


def test_the_registries_are_the_one_class():
    assert all(isinstance(r, Registry) for r in (MEASURES, SCENE_MEASURES, READERS,
                                                 POLICY_KINDS, SCENARIO_KINDS))


@pytest.mark.parametrize("measure", [*MEASURES, *SCENE_MEASURES], ids=lambda m: m.name)
def test_check_measure_passes_every_built_in(measure):
    check_measure(measure)
    doc = measure.to_dict()
    assert doc["label"] and doc["kind"] in ("mean", "rate") and doc["interval"]


def test_check_measure_refuses_a_wrong_shape_a_non_binary_rate_and_values_out_of_bounds():
    base = MEASURES["mean_speed"]
    with pytest.raises(RegistrationError, match="one value per episode"):
        check_measure(replace(base, name="x", function=lambda s: np.zeros(5)))
    with pytest.raises(RegistrationError, match="rate: each episode's value must be 0 or 1"):
        check_measure(replace(base, name="x", kind="rate",
                              function=lambda s: np.full(s.n_episodes, 0.5)))
    with pytest.raises(RegistrationError, match="outside its bounds"):
        check_measure(replace(base, name="x", bounds=(0.0, 5.0)))
    with pytest.raises(RegistrationError, match="failed on two hand-built episodes"):
        check_measure(replace(base, name="x", function=lambda s: 1 / 0))
    with pytest.raises(RegistrationError, match="kind 'median'"):
        check_measure(replace(base, name="x", kind="median"))
    with pytest.raises(RegistrationError, match="needs a gate margin"):
        check_measure(Measure("x", "m", True, "no margin", None, base.function))


def test_a_rate_entry_is_bounded_and_shown_in_percent():
    crash = MEASURES["crashed"]
    assert crash.is_rate and crash.bounds == (0.0, 1.0) and crash.display_unit == "%"
    assert crash.scale == 100.0 and "Wilson" in crash.interval_method
    jerk = MEASURES["rms_jerk"]
    assert not jerk.is_rate and jerk.bounds is None and jerk.display_unit == "m/s³"


SAMPLES = {"tf_example": "motion_data_one_example.tfrecord",
           "scenario": "womd_scenario_input.tfrecord",
           "scenarionet": "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl"}


@pytest.mark.parametrize("reader", list(READERS), ids=lambda r: r.name)
def test_check_reader_passes_every_built_in_on_a_real_file(reader, womd_dir):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        table = check_reader(reader, womd_dir / SAMPLES[reader.name])
    assert len(table) and table["scenario_id"].nunique() >= 1


def test_check_reader_refuses_functions_workers_cannot_import(tmp_path):
    with pytest.raises(RegistrationError, match="module-level function"):
        check_reader(Reader("lam", "file", lambda path, types: None, suffixes=(".x",)))
    bad = tmp_path / "a.pkl"
    bad.write_bytes(b"not a pickle")
    with pytest.raises(Exception, match=r"a\.pkl"):
        check_reader(READERS["scenarionet"], bad)


def test_policy_kinds_refuse_a_builder_workers_cannot_import_and_duplicates():
    assert {"idm", "random", "lane_keeping", "sb3", "import"} <= set(POLICY_KINDS.names())
    with pytest.raises(RegistrationError, match="module:attribute"):
        register_policy_kind("mine", "not a name")
    with pytest.raises(RegistrationError, match="already registered"):
        POLICY_KINDS.register(PolicyKind("idm", "x:y"))
    assert "mine" not in POLICY_KINDS


@pytest.mark.parametrize("policy", ["idm", "idm-aggressive", "idm-defensive", "random",
                                    "lane-keeping"])
def test_check_policy_passes_the_built_in_policies(policy):
    from tap_bench.sim import check_policy

    table = check_policy(policy, "highway", seed=1, duration=1.0)
    assert table["is_ego"].any()


def test_check_policy_refuses_a_policy_that_ignores_its_seed():
    from tap_bench.sim import check_policy

    class Unseeded:
        name = "unseeded"
        observation = None

        def reset(self, env, *, seed):
            self.n = env.action_space.n
            self.rng = np.random.default_rng()  # fresh entropy, not the seed: episodes differ

        def act(self, observation):
            return int(self.rng.integers(self.n))

    # 10 decisions of 5 actions: two equal episodes by chance are about 1e-5 likely (3 s made
    # this test fail about one run in a hundred)
    with pytest.raises(RegistrationError, match="two different ways"):
        check_policy(Unseeded(), "highway", seed=0, duration=10.0)
    with pytest.raises(RegistrationError, match="not a Policy"):
        check_policy(object(), "highway")


def test_scenario_kinds_hold_highway_env_ids_and_womd_and_suggest_names():
    import gymnasium

    kinds = scenario_kinds()
    assert kinds is SCENARIO_KINDS
    highway = {k for k, spec in gymnasium.registry.items()
               if str(spec.entry_point).startswith("highway_env")}
    assert highway and highway <= set(kinds.names()) and "highway-v0" in kinds
    for kind in kinds:
        check_scenario_kind(kind)
        if kind.configurable:
            assert isinstance(env_class(kind.name), type), kind.name
    assert env_class("highway-v0").__name__ == "HighwayEnv"
    with pytest.raises(UnknownNameError, match="Did you mean 'highway-v0'"):
        env_class("higway-v0")
    if "tap_bench/womd-v0" in gymnasium.registry:
        assert not kinds["tap_bench/womd-v0"].configurable
        with pytest.raises(ParameterError, match="rollout --womd"):
            env_class("tap_bench/womd-v0")


def test_scenario_kinds_refuse_duplicates_and_entry_points_workers_cannot_import():
    scenario_kinds()
    with pytest.raises(RegistrationError, match="module:attribute"):
        SCENARIO_KINDS.register(ScenarioKind("mine-v0", "not a name"))
    with pytest.raises(RegistrationError, match="already registered"):
        SCENARIO_KINDS.register(ScenarioKind("highway-v0", "highway_env.envs:HighwayEnv"))
    assert "mine-v0" not in SCENARIO_KINDS
    SCENARIO_KINDS.register(ScenarioKind("mine-v0", "highway_env.envs:HighwayEnv", "a plugin"))
    try:
        assert env_class("mine-v0").__name__ == "HighwayEnv"
    finally:
        SCENARIO_KINDS.unregister("mine-v0")
