"""Pruned ADE and DTW nearest neighbours are exactly the brute-force ones."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tap_bench.similarity import Shapes, ade_nearest, brute_force_nearest, dtw_nearest


def random_shapes(seed: int, n: int, lengths: tuple[int, int] = (12, 12),
                  duplicates: bool = True) -> Shapes:
    """Random walks from the origin, with exact copies, stuttered copies and parked ones."""
    rng = np.random.default_rng(seed)
    trajectories = []
    for _ in range(n):
        length = int(rng.integers(lengths[0], lengths[1] + 1))
        steps = rng.normal([1.0, 0.0], rng.uniform(0.05, 1.0), size=(length - 1, 2))
        trajectories.append(np.vstack([[0.0, 0.0], np.cumsum(steps, axis=0)]))
    if duplicates:
        parked = np.zeros((lengths[0], 2))
        for _ in range(3):
            trajectories.insert(int(rng.integers(0, len(trajectories))), parked.copy())
        twin = trajectories[int(rng.integers(0, n))]
        trajectories.insert(int(rng.integers(0, len(trajectories))), twin.copy())
        # a stuttered copy: DTW 0 from its source, another length
        src = trajectories[int(rng.integers(0, len(trajectories)))]
        trajectories.append(np.vstack([src[:1], src]))
        # rounding to a coarse grid makes equal distances (ties) likely
        trajectories = [np.round(t * 2) / 2 for t in trajectories]
    offsets = np.concatenate([[0], np.cumsum([len(t) for t in trajectories])])
    points = np.concatenate(trajectories)
    return Shapes(points=points, offsets=offsets, speed=np.zeros(len(points)),
                  t=np.zeros(len(points)), keys=pd.DataFrame(index=range(len(trajectories))))


def assert_same(pruned, brute):
    np.testing.assert_array_equal(pruned.query, brute.query)
    np.testing.assert_array_equal(pruned.neighbour, brute.neighbour)
    np.testing.assert_array_equal(pruned.distance, brute.distance)  # bit for bit


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 40))
def test_ade_pruned_equals_brute_force(seed, n):
    shapes = random_shapes(seed, n)
    assert_same(ade_nearest(shapes, workers=1, progress=False),
                brute_force_nearest(shapes, metric="ade"))


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(2, 30))
def test_dtw_pruned_equals_brute_force_on_ragged_sets(seed, n):
    shapes = random_shapes(seed, n, lengths=(3, 20))
    assert_same(dtw_nearest(shapes, workers=1, progress=False),
                brute_force_nearest(shapes, metric="dtw"))


@pytest.mark.parametrize("seed", [0, 1])
def test_ade_groups_unequal_lengths_or_cuts_a_prefix(seed):
    shapes = random_shapes(seed, 40, lengths=(8, 11), duplicates=False)
    equal = ade_nearest(shapes, workers=1, progress=False)
    assert_same(equal, brute_force_nearest(shapes, metric="ade"))
    lengths = shapes.lengths
    found = equal.neighbour >= 0
    assert (lengths[equal.neighbour[found]] == lengths[found]).all()
    alone = np.flatnonzero(np.bincount(lengths)[lengths] == 1)
    assert (equal.neighbour[alone] == -1).all() and np.isnan(equal.distance[alone]).all()
    prefix = ade_nearest(shapes, length=9, workers=1, progress=False)
    assert_same(prefix, brute_force_nearest(shapes, metric="ade", length=9))
    assert (prefix.neighbour[lengths < 9] == -1).all()
    assert (prefix.neighbour[lengths >= 9] >= 0).all()


def test_queries_threads_and_hints_do_not_change_answers():
    shapes = random_shapes(7, 300, lengths=(10, 30))
    queries = np.array([5, 0, 299, 17, 5])
    brute = brute_force_nearest(shapes, queries, metric="dtw")
    for workers in (1, 2):
        assert_same(dtw_nearest(shapes, queries, workers=workers, chunk=2, progress=False),
                    brute)
    bad_hints = np.array([6, 1, 3, 3, -1])
    assert_same(dtw_nearest(shapes, queries, hints=bad_hints, workers=1, progress=False), brute)
    assert_same(ade_nearest(shapes, queries, workers=2, chunk=1, progress=False),
                brute_force_nearest(shapes, queries, metric="ade"))


def test_exact_copies_are_neighbours_at_distance_zero():
    shapes = random_shapes(3, 20)
    res = dtw_nearest(shapes, workers=1, progress=False)
    zero = res.distance == 0
    assert zero.sum() >= 5  # three parked, a twin pair, a stuttered pair
    for q, nb in zip(res.query[zero], res.neighbour[zero], strict=True):
        assert nb != q
    assert (res.evaluated[zero] == 0).all()  # answered without a search


def test_bad_arguments():
    shapes = random_shapes(0, 5)
    with pytest.raises(IndexError, match="query rows"):
        ade_nearest(shapes, [99], progress=False)
    with pytest.raises(KeyError, match="Did you mean 'equal'"):
        ade_nearest(shapes, length="equall", progress=False)
    with pytest.raises(ValueError, match="hints must have one row per query"):
        dtw_nearest(shapes, [0, 1], hints=[0], progress=False)
