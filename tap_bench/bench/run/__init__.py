"""``bench run``: a suite rolled out, labelled, scored and written to a run folder.

- :mod:`~tap_bench.bench.run.runner`: :func:`~tap_bench.bench.run.runner.run_suite`, the
  steps in order;
- :mod:`~tap_bench.bench.run.plan`: the suite read once into a plan, the run's tasks;
- :mod:`~tap_bench.bench.run.estimate`: how long the run should take;
- :mod:`~tap_bench.bench.run.references`: the coverage references read once, before the
  episodes;
- :mod:`~tap_bench.bench.run.episodes`: the episodes step: each env's map drawn once, what
  the episode cache holds read, every task run, the run's tables gathered and checked;
- :mod:`~tap_bench.bench.run.tasks`: episodes as tasks of the execution layer and their
  results;
- :mod:`~tap_bench.bench.run.scoring`: every score of the run;
- :mod:`~tap_bench.bench.run.folder`: the run folder: ``summary.json``, write, read,
  provenance, and what a run returns (:class:`~tap_bench.bench.run.folder.RunResult`);
- :mod:`~tap_bench.bench.run.spill`: a run's trajectories on disk, a part per episode;
- :mod:`~tap_bench.bench.run.served`: a run served whole from the episode cache;
- :mod:`~tap_bench.bench.run.demo`: ``tap-bench demo``.
"""
