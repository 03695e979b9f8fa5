"""Normalised shapes, and ADE and DTW worked by hand and against a plain reference."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from similarity_helpers import CRUISE, label_rows, table_from_points

from tap_bench.errors import LabelTableError, TapBenchError
from tap_bench.similarity import ade, dtw, normalised_shapes


def test_normalisation_removes_position_and_initial_heading():
    t = np.arange(30) * 0.1
    local = np.stack([8 * t, 0.5 * t**2], axis=1)  # a left curve in its own frame
    rows = []
    for k, (x0, y0, h0) in enumerate([(0, 0, 0.0), (120, -40, np.pi / 2), (-7, 3, -2.5)]):
        c, s = np.cos(h0), np.sin(h0)
        pts = local @ np.array([[c, s], [-s, c]]) + [x0, y0]
        frame = table_from_points({("s", str(k)): pts}, heading=h0)
        rows.append(frame)
    shapes = normalised_shapes(pd.concat(rows, ignore_index=True))
    assert len(shapes) == 3
    for k in range(3):
        np.testing.assert_allclose(shapes[k], local, atol=1e-9)
    assert shapes.keys["track_id"].tolist() == ["0", "1", "2"]
    np.testing.assert_allclose(shapes.time_of(1), t, atol=1e-12)


def test_shapes_follow_the_label_rows_and_check_them():
    pts = np.stack([np.arange(20.0), np.zeros(20)], axis=1)
    table = table_from_points({("s", "a"): pts, ("s", "b"): pts * 2})
    labels = label_rows([("s", "b", CRUISE), ("s", "a", CRUISE)])
    labels["t_end"] = 2.0
    shapes = normalised_shapes(table, labels)
    assert shapes.keys["track_id"].tolist() == ["b", "a"]
    np.testing.assert_allclose(shapes[0][-1], [38.0, 0.0])
    with pytest.raises(LabelTableError, match=r"row 1 \(s:zz segment 0\) has no valid segment"):
        normalised_shapes(table, label_rows([("s", "a", CRUISE), ("s", "zz", CRUISE)]))
    late = labels.copy()
    late["t_start"] = 0.5
    with pytest.raises(LabelTableError, match="made from another file"):
        normalised_shapes(table, late)
    with pytest.raises(LabelTableError, match="select a single level"):
        normalised_shapes(table, pd.concat([labels, labels], ignore_index=True))


def test_ade_by_hand():
    a = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    b = a + np.array([0.0, 1.0])
    b[0] = [0.0, 0.0]
    assert ade(a, a) == 0.0
    assert ade(a, b) == pytest.approx(0.75)  # 0, 1, 1, 1 over 4 points
    assert ade(a, a * 2) == pytest.approx((0 + 1 + 2 + 3) / 4)
    with pytest.raises(TapBenchError, match="equal length, got 4 and 3 points"):
        ade(a, a[:3])


def test_dtw_by_hand():
    a = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    stutter = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 0.0]])
    assert dtw(a, stutter) == 0.0  # repeats warp away at no cost
    assert dtw(a, a + np.array([0.0, 1.0])) == pytest.approx(3.0)  # 1 m per point
    # the paths agree until b jumps to 4: the best path pays only |2 - 4| at the end
    b = np.array([[0.0, 0.0], [1.0, 0.0], [4.0, 0.0]])
    assert dtw(a, b) == pytest.approx(2.0)
    assert dtw(a, b) == dtw(b, a)


def _dtw_reference(a: np.ndarray, b: np.ndarray) -> float:
    cost = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=2)
    d = np.full((len(a) + 1, len(b) + 1), np.inf)
    d[0, 0] = 0.0
    for i in range(1, len(a) + 1):
        for j in range(1, len(b) + 1):
            d[i, j] = cost[i - 1, j - 1] + min(d[i - 1, j - 1], d[i - 1, j], d[i, j - 1])
    return float(d[-1, -1])


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 12), st.integers(1, 12), st.integers(0, 2**32 - 1))
def test_dtw_equals_the_textbook_programme(n, m, seed):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(n, 2)), rng.normal(size=(m, 2))
    assert dtw(a, b) == pytest.approx(_dtw_reference(a, b), rel=1e-12, abs=1e-12)
