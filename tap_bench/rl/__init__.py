"""Training RL agents and watching their behaviour grow: Stable-Baselines3 training
(:mod:`~tap_bench.rl.training`), the behaviour-coverage learning curve it records
(:mod:`~tap_bench.rl.curve`, scored with the benchmark's coverage and diversity) and the
callback that records it (:mod:`~tap_bench.rl.callbacks`, which imports Stable-Baselines3).

This layer sits above :mod:`tap_bench.sim` (envs, policies, rollouts) and
:mod:`tap_bench.bench` (coverage, diversity); nothing below imports it.
"""
