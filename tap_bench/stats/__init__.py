"""Statistics shared by the benchmark, the realism score, training curves and the WOMD
readers: how intervals are computed and their random streams.

- :mod:`~tap_bench.stats.bootstrap`: the level, the bootstrap's resamples, named random
  streams and scene clusters (:class:`~tap_bench.stats.bootstrap.BootstrapConfig`);
- :mod:`~tap_bench.stats.intervals`: one interval function per kind of statistic (Wilson,
  Newcombe, Tango, Student, Welch), and the interval a measure's entry calls for.
"""
