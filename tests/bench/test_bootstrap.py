"""Resampling by cluster (tap_bench.stats.bootstrap): the windows of one episode are drawn
together, as whole episodes."""

from __future__ import annotations

import numpy as np
import pytest

from tap_bench.stats.bootstrap import cluster_indices, cluster_weights


def test_cluster_resamples_draw_whole_clusters():
    rng = np.random.default_rng(0)
    for sizes in ([3] * 7, [1, 2, 5, 3, 4]):  # equal clusters, and unequal
        clusters = np.repeat(np.arange(len(sizes)), sizes)
        w = cluster_weights(rng, clusters, 400)
        assert w.shape == (400, len(clusters))
        for c in range(len(sizes)):  # a cluster's units are drawn together
            assert (w[:, clusters == c] == w[:, clusters == c][:, :1]).all()
        assert (w.reshape(400, -1).sum(1) > 0).all()
        # as many clusters as there are, each with replacement: mean weight 1
        assert w.mean() == pytest.approx(1.0, abs=0.05)
        idx = cluster_indices(rng, clusters, 400, 9)
        assert idx.shape == (400, 9)
        for row in idx:  # runs of a cluster's units in order, only the last cut short
            runs = np.split(row, np.flatnonzero(np.diff(clusters[row]) != 0) + 1)
            for run in runs[:-1]:
                c = clusters[run[0]]
                members = np.flatnonzero(clusters == c)
                assert len(run) % len(members) == 0
    # every unit its own cluster: the ordinary bootstrap (n draws, mean count 1)
    w = cluster_weights(rng, np.arange(50), 1000)
    assert (w.sum(1) == 50).all()
