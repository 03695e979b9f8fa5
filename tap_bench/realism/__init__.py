"""How realistic simulated traffic is: WOSAC 2025's realism score on a CPU (SPEC section 9).

- :mod:`tap_bench.realism.features`: the per-step features (speeds, accelerations, distance
  to the nearest object, time to collision, signed distance to the road edge, collision,
  off-road, traffic-light violation) as pure numpy functions of states;
- :mod:`tap_bench.realism.score`: the histogram and Bernoulli likelihoods and the
  meta-metric (WOSAC 2025's bins and weights);
- :mod:`tap_bench.realism.rollouts`: K rollouts of recorded scenes in ``tap_bench/womd-v0``
  and the per-agent scores of a scene;
- :mod:`tap_bench.realism.summary`: means over scenes, per object type and manoeuvre, with
  bootstrap intervals over scenes.

``tap-bench realism`` (:mod:`tap_bench.cli.realism`) runs them.
"""
