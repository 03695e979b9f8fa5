"""The stages' code arithmetic against its literal reading (SPEC section 3-4): the trace
classes at and around the thresholds, NaN and infinities included, and the action codes of
every maneuver / trend code with every intensity / speed class."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tap_bench import sdl
from tap_bench.stages import (
    _ACTION_LATERAL_BASE,
    _ACTION_LONGITUDINAL_BASE,
    _trace_lateral,
    _trace_longitudinal,
)
from tap_bench.thresholds import resolve_thresholds

TH = resolve_thresholds("paper")


def _values(*thresholds: float) -> np.ndarray:
    near = [f(t) for t in thresholds for f in (lambda x: x, lambda x: -x,
                                               lambda x: np.nextafter(x, np.inf),
                                               lambda x: np.nextafter(x, -np.inf),
                                               lambda x: -np.nextafter(x, np.inf))]
    return np.array([*near, 0.0, -0.0, np.nan, np.inf, -np.inf, 1e-300, -1e300])


@settings(max_examples=50, deadline=None)
@given(extra=st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=30))
def test_trace_codes_are_the_thresholds_literal_reading(extra):
    w = np.concatenate([_values(TH.w_str), np.asarray(extra, float)])
    expected = np.where(w > TH.w_str, sdl.LEFT, np.where(w < -TH.w_str, sdl.RIGHT,
                                                          sdl.STRAIGHT))
    got = _trace_lateral(w, TH)
    assert got.dtype == np.int8 and np.array_equal(got, expected)
    a = np.concatenate([_values(TH.a_acc, TH.a_dec), np.asarray(extra, float)])
    expected = np.where(a > TH.a_acc, sdl.ACCELERATE,
                        np.where(a <= TH.a_dec, sdl.DECELERATE, sdl.MAINTAIN))
    got = _trace_longitudinal(a, TH)
    assert got.dtype == np.int8 and np.array_equal(got, expected)


def test_action_codes_of_every_code_and_class():
    for code in range(5):
        for extra in range(3):  # a turn's intensity, a moving run's speed class
            lateral = np.select([code == sdl.STRAIGHT, code == sdl.LEFT_MERGE,
                                 code == sdl.RIGHT_MERGE],
                                [sdl.ACTION_STRAIGHT, sdl.ACTION_LEFT_MERGE,
                                 sdl.ACTION_RIGHT_MERGE],
                                1 + 3 * (code == sdl.RIGHT) + extra)
            if code in (sdl.LEFT, sdl.RIGHT) or extra == 0:  # (0 off the turns)
                assert _ACTION_LATERAL_BASE[code] + extra == lateral
            longitudinal = np.select([code == sdl.STOPPED, code == sdl.REVERSING],
                                     [sdl.ACTION_STOPPED, sdl.ACTION_REVERSING],
                                     3 * code + extra)
            if code not in (sdl.STOPPED, sdl.REVERSING) or extra == 0:
                assert _ACTION_LONGITUDINAL_BASE[code] + extra == longitudinal
    names = sdl.ACTION_LATERAL_NAMES
    assert [names[c] for c in _ACTION_LATERAL_BASE] == [
        "Straight", "Gradual Left Turn", "Gradual Right Turn", "Left Merge", "Right Merge"]
