"""The gate's power on rates whose events are not nested: the exact figure against a
simulation study of the gate's own paired test."""

from __future__ import annotations

import math

import numpy as np
import pytest


@pytest.mark.parametrize("crashes", [0, 3, 6])
def test_paired_rate_power_when_crashes_are_drawn_afresh_matches_a_simulation(crashes):
    # a simulation study of the gate's own paired test: the run's outcome on each of 30
    # seeds drawn afresh (independent of the baseline's) at the baseline's rate + 25 points
    from tap_bench.bench.gate.power import _rate_power, afresh_rate_power
    from tap_bench.bench.gate.regression import _sign_flip_test
    from tap_bench.bench.suite import GateConfig

    config = GateConfig()
    n, margin, effect = 30, 0.1, 0.25
    level = config.alpha * config.share("crashed")
    base = np.zeros(n)
    base[:crashes] = 1.0
    exact = afresh_rate_power(base, effect, margin, level)
    rng = np.random.default_rng(crashes)
    draws = 4000
    fired = 0
    for _ in range(draws):
        run = (rng.random(n) < crashes / n + effect).astype(float)
        d = run - base
        test = _sign_flip_test(d, -1, config, ("power study",))
        fired += d.mean() > margin and test.p_worse <= level
    se = math.sqrt(exact * (1 - exact) / draws)
    assert abs(fired / draws - exact) <= 4 * se + 1e-9
    nested = _rate_power(base, -1, effect, margin, level, n, True)
    if crashes:  # seeds that stop crashing count against the change
        assert exact < nested - 0.2
    else:  # no crash to lose: both models are one
        assert exact == pytest.approx(nested)
