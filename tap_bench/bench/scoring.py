"""Scoring a benchmark run: every table of ``results/<run>/`` from the episode table.

:func:`score` is a pure function of tables: it does no rollout and no I/O, so it scores a
fresh run, an old run's ``episodes.parquet`` or a synthetic table alike (the scoring
benchmark times it on 10 policies x 5 envs x 100 seeds).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from tap_bench.bench.bootstrap import (
    BootstrapConfig,
    percentile_interval,
    resample_weights,
    weighted_means,
    wilson_interval,
)
from tap_bench.bench.compare import ALL_ENVS, matched_by_label, paired_comparison
from tap_bench.bench.coverage import Reference, corpus_reference, coverage
from tap_bench.bench.measures import MEASURES
from tap_bench.bench.novelty import novelty
from tap_bench.errors import LabelTableError

__all__ = ["Scores", "policy_measures", "score"]


@dataclass(frozen=True)
class Scores:
    """Every table of a scored run (each is written as ``<name>.parquet``).

    Attributes:
        label_counts: env, policy, sdl, count, share: each policy's ego label distribution.
        measures: env (and "all"), policy, measure, n, mean, low, high: per-policy means of
            the safety and efficiency measures (bootstrap over episodes).
        paired: env, policy_a, policy_b, n_pairs, n_dropped, agreement (+ interval).
        paired_measures: the paired measure differences and probabilities of improvement.
        paired_labels: the paired per-label frequency differences.
        matched: measure differences inside groups of equal labels.
        coverage: env, policy, reference, and the coverage fields.
        novelty: env, policy, reference, novelty fields.
        novel_labels: env, policy, label, count, share, example_scenario.
        scenario_matches: highway-env scenarios beside their nearest WOMD scenarios (when
            a WOMD reference was given).
        references: name -> the :class:`Reference` used.
        methods: table name -> how its intervals were computed.
    """

    label_counts: pd.DataFrame
    measures: pd.DataFrame
    paired: pd.DataFrame
    paired_measures: pd.DataFrame
    paired_labels: pd.DataFrame
    matched: pd.DataFrame
    coverage: pd.DataFrame
    novelty: pd.DataFrame
    novel_labels: pd.DataFrame
    scenario_matches: pd.DataFrame = field(default_factory=pd.DataFrame)
    references: dict[str, Reference] = field(default_factory=dict)
    methods: dict[str, str] = field(default_factory=dict)

    TABLES = ("label_counts", "measures", "paired", "paired_measures", "paired_labels",
              "matched", "coverage", "novelty", "novel_labels", "scenario_matches")

    def tables(self) -> dict[str, pd.DataFrame]:
        """name -> table, in report order."""
        return {name: getattr(self, name) for name in self.TABLES}


def _env_groups(table: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    groups = [(str(env), sub) for env, sub in table.groupby("env", sort=True)]
    if len(groups) > 1:
        groups.append((ALL_ENVS, table))
    return groups


def policy_measures(episodes: pd.DataFrame, config: BootstrapConfig) -> pd.DataFrame:
    """Mean of each measure per env (and pooled) and policy, with percentile intervals over
    episodes (stratified by env when pooled)."""
    ok = episodes[episodes["status"] == "ok"].sort_values(["policy", "env"], kind="stable")
    rows = []
    stream = 30_000
    for policy, pol in ok.groupby("policy", sort=True):
        env_of = pol["env"].to_numpy()
        envs = sorted(set(env_of))
        weights = {}
        for env in envs:
            weights[env] = resample_weights(int((env_of == env).sum()), config, stream=stream)
            stream += 1
        groups = [(env, env_of == env, weights[env]) for env in envs]
        if len(envs) > 1:  # pooled: the per-env resamplings side by side (rows sorted by env)
            groups.append((ALL_ENVS, np.ones(len(pol), bool),
                           np.hstack([weights[env] for env in envs])))
        values = np.column_stack([pol[m.name].to_numpy(float, na_value=np.nan)
                                  for m in MEASURES])
        for env, mask, W in groups:
            sub = values[mask]
            present = ~np.isnan(sub)
            boot = weighted_means(W, sub)
            with np.errstate(invalid="ignore", divide="ignore"):
                est = np.where(present, sub, 0.0).sum(0) / present.sum(0)
            lo, hi = percentile_interval(boot, config.level)
            for j, m in enumerate(MEASURES):
                n_j = int(present[:, j].sum())
                low, high = lo[j], hi[j]
                if m.name == "crashed":  # a rate: Wilson, which stays honest at 0 and 1
                    low, high = wilson_interval(int(np.nansum(sub[:, j])), n_j, config.level)
                rows.append({"env": env, "policy": policy, "measure": m.name, "n": n_j,
                             "mean": est[j], "low": low, "high": high})
    return pd.DataFrame(rows, columns=["env", "policy", "measure", "n", "mean", "low", "high"])


def _label_counts(episodes: pd.DataFrame) -> pd.DataFrame:
    ok = episodes[(episodes["status"] == "ok") & episodes["sdl"].notna()]
    counts = ok.groupby(["env", "policy", "sdl"], sort=True).size().rename("count").reset_index()
    total = counts.groupby(["env", "policy"])["count"].transform("sum")
    counts["share"] = counts["count"] / total
    return counts.sort_values(["env", "policy", "count"], ascending=[True, True, False],
                              kind="stable").reset_index(drop=True)


def score(episodes: pd.DataFrame, *, reference_policy: str, level: str,
          config: BootstrapConfig | None = None,
          references: dict[str, pd.DataFrame] | None = None,
          comparisons: list[tuple[str, str]] | None = None,
          scenario_matches: pd.DataFrame | None = None) -> Scores:
    """Score a run.

    Args:
        episodes: the episode table (:mod:`tap_bench.bench.episodes`) of every policy.
        reference_policy: the policy compared with every other one; its ego labels (per env,
            and pooled) are the ``"<policy> rollouts"`` coverage reference.
        level: the SDL level of the episode table's labels.
        config: bootstrap settings.
        references: more reference corpora: name -> label table (e.g. ``{"WOMD": labels}``;
            vehicles' labels at ``level`` are used; one reference for every env).
        comparisons: (A, B) pairs to compare; default every other policy against the
            reference policy, as (policy, reference).
        scenario_matches: a precomputed table of cross-data-set scenario matches to carry.

    Returns:
        :class:`Scores`.
    """
    config = config or BootstrapConfig()
    policies = sorted(episodes["policy"].unique())
    if comparisons is None:
        comparisons = [(p, reference_policy) for p in policies if p != reference_policy]
    paired, paired_m, paired_l, matched = [], [], [], []
    method_paired = ""
    skipped = []
    for a, b in comparisons:
        try:
            pc = paired_comparison(episodes, a, b, config=config)
        except LabelTableError as err:  # nothing to pair (every episode of one failed)
            skipped.append(f"{a} vs {b}: {err}")
            continue
        method_paired = pc.method
        paired.append(pc.summary)
        paired_m.append(pc.measures.assign(policy_a=a, policy_b=b))
        paired_l.append(pc.labels.assign(policy_a=a, policy_b=b))
        matched.append(matched_by_label(episodes, a, b, config=config).assign(policy_a=a,
                                                                             policy_b=b))

    ok = episodes[(episodes["status"] == "ok") & episodes["sdl"].notna()]
    ref_eps = ok[ok["policy"] == reference_policy]
    cov_rows, nov_rows, nov_labels = [], [], []
    refs: dict[str, Reference] = {}
    corpora: list[tuple[str, pd.DataFrame | None]] = [(f"{reference_policy} rollouts", None)]
    corpora += list((references or {}).items())
    stream = 0
    for ref_name, ref_table in corpora:
        fixed = None
        if ref_table is not None:
            fixed = corpus_reference(ref_table, level, tracks="vehicles", name=ref_name)
            refs[ref_name] = fixed
        for policy in policies:
            if ref_table is None and policy == reference_policy:
                continue  # a corpus covers itself
            pol = ok[ok["policy"] == policy]
            for env, sub in _env_groups(pol):
                if fixed is not None:
                    ref = fixed
                else:
                    r_sub = ref_eps if env == ALL_ENVS else ref_eps[ref_eps["env"] == env]
                    if r_sub.empty:
                        continue
                    ref = corpus_reference(r_sub.assign(level=level), level, tracks="all",
                                           name=ref_name)
                    refs.setdefault(f"{ref_name} ({env})", ref)
                stream += 1
                cv = coverage(sub["sdl"], ref, config=config, stream=stream)
                nv = novelty(sub, ref, config=config, stream=stream)
                key = {"env": env, "policy": policy, "reference": ref_name}
                cov_rows.append({**key, **cv.row()})
                nov_rows.append({**key, **nv.row(), "reference_size": ref.n_trajectories})
                nov_labels.append(nv.labels.assign(**key))
    methods = {
        "measures": config.describe("episodes, stratified by env when pooled")
        + f"; crash rates: {config.level:.0%} Wilson score intervals",
        "paired": method_paired,
        "matched": config.describe("episodes of each policy within a label group, "
                                   "independently"),
        "coverage": (f"estimate +- z sd, z for {config.level:.0%}, sd over "
                     f"{config.n_resamples} draws from the label distribution augmented with "
                     "Chao1-estimated undetected labels (Chao et al. 2014, iNEXT); "
                     f"seed {config.seed}"),
        "novelty": config.describe("episodes, stratified by env when pooled"),
    }
    if skipped:
        methods["skipped comparisons"] = "; ".join(skipped)

    def cat(frames: list[pd.DataFrame]) -> pd.DataFrame:
        frames = [f for f in frames if len(f)]
        return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()

    return Scores(
        label_counts=_label_counts(episodes), measures=policy_measures(episodes, config),
        paired=cat(paired), paired_measures=cat(paired_m), paired_labels=cat(paired_l),
        matched=cat(matched), coverage=pd.DataFrame(cov_rows), novelty=pd.DataFrame(nov_rows),
        novel_labels=cat(nov_labels),
        scenario_matches=scenario_matches if scenario_matches is not None else pd.DataFrame(),
        references=refs, methods=methods)
