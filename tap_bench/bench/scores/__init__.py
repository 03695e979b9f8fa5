"""A run's scores, each computed from the episode table (:mod:`tap_bench.bench.episodes`).

- :mod:`~tap_bench.bench.scores.scoring`: every table of ``results/<run>/``, from the others;
- :mod:`~tap_bench.bench.scores.compare`: matched comparison, paired by seed and matched by
  label;
- :mod:`~tap_bench.bench.scores.coverage`, :mod:`~tap_bench.bench.scores.novelty`,
  :mod:`~tap_bench.bench.scores.diversity`: behaviour coverage of a reference, unique
  manoeuvres, Hill numbers; :mod:`~tap_bench.bench.scores.null`: their same-policy null;
- :mod:`~tap_bench.bench.scores.gap`: the sim-to-real behaviour gap;
  :mod:`~tap_bench.bench.scores.windows`: episodes cut in windows of a reference's track
  length, scored against real driving in place of whole episodes;
- :mod:`~tap_bench.bench.scores.contexts`: measures by interaction context;
- :mod:`~tap_bench.bench.scores.agreement`: agreement with a reference policy on recorded
  scenes; :mod:`~tap_bench.bench.scores.scenarios`: scenarios matched across data sets;
- :mod:`~tap_bench.bench.scores.verdict`: the answer per policy, in words.
"""
