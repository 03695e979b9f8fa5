"""Scoring a benchmark run: every table of ``results/<run>/`` from the episode table.

:func:`score` is a pure function of tables: it does no rollout and no I/O, so it scores a
fresh run, an old run's ``episodes.parquet`` or a synthetic table alike (the scoring
benchmark times it on 10 policies x 5 envs x 100 seeds).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.bench.measures import MEASURES
from tap_bench.bench.scores.compare import ALL_ENVS, MIN_GROUP, compare_policies
from tap_bench.bench.scores.coverage import (
    UNITS,
    Reference,
    corpus_reference,
    coverage,
    pooled_coverage,
)
from tap_bench.bench.scores.diversity import MIN_COMPLETENESS, diversity_table
from tap_bench.bench.scores.novelty import novelty, pooled_novelty
from tap_bench.bench.scores.null import SPLITS, pooled_null, same_policy_null
from tap_bench.bench.scores.windows import CUT_FROM
from tap_bench.errors import LabelTableError
from tap_bench.stats.bootstrap import BootstrapConfig
from tap_bench.stats.intervals import measure_interval

__all__ = ["Scores", "policy_measures", "reference_scores", "score",
           "scores_from_files", "scores_to_files", "write_score_tables"]


@dataclass(frozen=True)
class Scores:
    """Every table of a scored run (each is written as ``<name>.parquet``).

    Attributes:
        label_counts: env, policy, sdl, count, share: each policy's ego label distribution.
        measures: env (and "all"), policy, measure, n, n_missing, mean, low, high:
            per-policy means of the safety and efficiency measures over the n episodes that
            have a value (t intervals inside the measure's bounds; Wilson for the crash
            rate); n_missing episodes have none (min headway and TTC without a leader).
        paired: env, policy_a, policy_b, n_pairs, n_dropped, agreement (+ interval).
        paired_measures: the paired measure differences and probabilities of improvement.
        paired_labels: the paired per-label frequency differences (per env).
        matched: measure differences inside groups of equal labels.
        coverage: env, policy, reference, and the coverage fields.
        novelty: env, policy, reference, novelty fields.
        novel_labels: env, policy, reference, label, count, share, example_scenario.
        diversity: env, policy, and the Hill numbers, completeness and asymptotes of
            :class:`tap_bench.bench.scores.diversity.DiversityResult`.
        gate_power: per env and measure, the gate's minimum detectable effect and the seeds
            a margin needs (:mod:`tap_bench.bench.gate.power`; empty when not asked).
        scenario_matches: highway-env scenarios beside their nearest WOMD scenarios (when
            a WOMD reference was given).
        gap: reference, and :meth:`tap_bench.bench.scores.gap.GapResult.row` per policy: the
            sim-to-real behaviour gap from each reference of real driving given as data
            files (empty otherwise).
        gap_labels: reference, policy and the per-label share differences of each gap.
        contexts: each policy against the reference inside each interaction context
            (:func:`tap_bench.bench.scores.contexts.context_scores`; ``bench run`` only).
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
    diversity: pd.DataFrame = field(default_factory=pd.DataFrame)
    gate_power: pd.DataFrame = field(default_factory=pd.DataFrame)
    scenario_matches: pd.DataFrame = field(default_factory=pd.DataFrame)
    gap: pd.DataFrame = field(default_factory=pd.DataFrame)
    gap_labels: pd.DataFrame = field(default_factory=pd.DataFrame)
    contexts: pd.DataFrame = field(default_factory=pd.DataFrame)
    references: dict[str, Reference] = field(default_factory=dict)
    methods: dict[str, str] = field(default_factory=dict)

    TABLES = ("label_counts", "measures", "paired", "paired_measures", "paired_labels",
              "matched", "coverage", "novelty", "novel_labels", "diversity", "gate_power",
              "scenario_matches", "gap", "gap_labels", "contexts")

    def tables(self) -> dict[str, pd.DataFrame]:
        """name -> table, in report order."""
        return {name: getattr(self, name) for name in self.TABLES}

    @property
    def envs(self) -> list[str]:
        """The envs the run was scored in, sorted: those of the measures' and label counts'
        rows, the pooled ``"all"`` left out (each env has a label heat map, a measures plot
        and its tables in the report)."""
        envs: set[str] = set()
        for table in (self.measures, self.label_counts):
            if len(table) and "env" in table.columns:
                envs |= set(map(str, table["env"].unique()))
        envs.discard(ALL_ENVS)
        return sorted(envs)


def scores_to_files(scores: Scores) -> dict[str, bytes]:
    """A :class:`Scores` as files (name -> bytes): each table as Parquet, the methods and
    references as JSON; :func:`scores_from_files` reads them back, equal value for value
    (the run keeps the scores of unchanged inputs this way: :func:`~tap_bench.bench.cache.
    memoised`). Raises what Parquet raises for a column it cannot hold."""
    import io
    import json

    files = {}
    for name, table in scores.tables().items():
        buffer = io.BytesIO()
        table.to_parquet(buffer, index=True)
        files[f"{name}.parquet"] = buffer.getvalue()
    refs = {name: {"items": [str(v) for v in ref.items],
                   "weights": [float(w) for w in ref.weights], "kind": ref.kind,
                   "level": ref.level, "description": ref.description,
                   "n_trajectories": int(ref.n_trajectories),
                   "units": [str(u) for u in ref.units], "axes": list(ref.axes),
                   "seeds": None if ref.seeds is None else [int(x) for x in ref.seeds]}
            for name, ref in scores.references.items()}
    # in order: the report lists the methods as scoring wrote them
    files["meta.json"] = json.dumps({"methods": scores.methods, "references": refs}).encode()
    return files


def write_score_tables(scores: Scores, folder: Path) -> None:
    """Each table of ``scores`` with rows as ``<folder>/<name>.parquet`` (a run folder's
    score tables); object columns holding mixed Python values are written as strings
    (Parquet needs one type a column)."""
    for name, table in scores.tables().items():
        if len(table):
            _parquet_safe(table).to_parquet(folder / f"{name}.parquet", index=False)


def _parquet_safe(table: pd.DataFrame) -> pd.DataFrame:
    """Object columns holding mixed Python values as strings (Parquet needs one type)."""
    out = table.copy()
    for col in out.columns:
        if out[col].dtype == object:
            kinds = {type(v) for v in out[col].dropna()}
            if len(kinds) > 1:
                out[col] = out[col].astype("string")
    return out


def scores_from_files(files: Mapping[str, bytes]) -> Scores:
    """The :class:`Scores` :func:`scores_to_files` wrote."""
    import io
    import json

    meta = json.loads(files["meta.json"])
    refs = {name: Reference(np.array(r["items"], dtype=object),
                            np.array(r["weights"], dtype=float), r["kind"], r["level"],
                            r["description"], int(r["n_trajectories"]),
                            units=np.array(r.get("units", []), dtype=object),
                            seeds=None if r.get("seeds") is None else np.array(r["seeds"]),
                            axes=tuple(r.get("axes", sdl.AXES)))
            for name, r in meta["references"].items()}
    tables = {name: pd.read_parquet(io.BytesIO(files[f"{name}.parquet"]))
              for name in Scores.TABLES}
    return Scores(**tables, references=refs, methods=dict(meta["methods"]))


def _env_groups(table: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    groups = [(str(env), sub) for env, sub in table.groupby("env", sort=True)]
    if len(groups) > 1:
        groups.append((ALL_ENVS, table))
    return groups


def policy_measures(episodes: pd.DataFrame, config: BootstrapConfig) -> pd.DataFrame:
    """Mean of each measure per env (and pooled: every episode of the policy) and policy,
    with the interval each measure's entry calls for (Student's t over the episodes that
    have a value, inside the measure's bounds; Wilson's for a rate such as the crash rate);
    ``n_missing`` counts the episodes without a value (no leader after the burn-in: no
    minimum headway or TTC)."""
    ok = episodes[episodes["status"] == "ok"]
    rows = []
    for policy, pol in ok.groupby("policy", sort=True):
        for env, sub in _env_groups(pol):
            for m in MEASURES:
                x = sub[m.name].to_numpy(float, na_value=np.nan)
                missing = int((~np.isfinite(x)).sum())  # e.g. no leader: no min headway
                x = x[np.isfinite(x)]
                n = len(x)
                # a rate gets Wilson's interval (honest at 0 and 1), a mean Student's t
                low, high = measure_interval(m, x, config.level)
                rows.append({"env": env, "policy": policy, "measure": m.name, "n": n,
                             "n_missing": missing, "mean": float(x.mean()) if n else np.nan,
                             "low": low, "high": high})
    return pd.DataFrame(rows, columns=["env", "policy", "measure", "n", "n_missing", "mean",
                                       "low", "high"])


def _label_counts(episodes: pd.DataFrame) -> pd.DataFrame:
    ok = episodes[(episodes["status"] == "ok") & episodes["sdl"].notna()]
    counts = ok.groupby(["env", "policy", "sdl"], sort=True).size().rename("count").reset_index()
    total = counts.groupby(["env", "policy"])["count"].transform("sum")
    counts["share"] = counts["count"] / total
    return counts.sort_values(["env", "policy", "count"], ascending=[True, True, False],
                              kind="stable").reset_index(drop=True)


def _scored(episodes: pd.DataFrame) -> pd.DataFrame:
    return episodes[(episodes["status"] == "ok") & episodes["sdl"].notna()]


def reference_scores(episodes: pd.DataFrame, reference: Reference | Mapping[str, Reference],
                     name: str, *, config: BootstrapConfig,
                     policies: list[str] | None = None, paired: bool = False,
                     unit: str | None = None, windowed: bool = False
                     ) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """Coverage and unique manoeuvres of every policy against one reference, per env and
    pooled, each beside the same-policy figure of that reference and the difference from
    it (:mod:`tap_bench.bench.scores.null`): the one scoring path of ``bench run``, ``compare``
    and ``tap-bench coverage``.

    Args:
        episodes: the episode table (failed and unlabelled episodes are left out).
        reference: one :class:`Reference` for every env (a corpus without envs such as WOMD,
            or the vocabulary), or env -> Reference (rollouts of a policy, keyed by env: an
            env's episodes are held against that env's reference only).
        name: the reference's name in the tables (``"idm rollouts"``, ``"WOMD"``).
        config: interval level, resamples and seed; each coverage draws from the stream
            ``("coverage", env, policy, name)``.
        policies: the policies to score (default every policy of ``episodes``).
        paired: the reference is rollouts of the same seeds (its ``seeds``): the null takes
            the policy's episodes on the seeds of the reference's probe half.
        unit: what the rows say they were scored on (default the reference's own unit:
            ``episodes`` or ``segments``; e.g. ``"9.1 s windows"`` when ``episodes`` are
            windows of the policy's episodes).
        windowed: ``episodes`` are windows cut from episodes (:func:`tap_bench.bench.scores.windows.
            window_episodes`), each one's episode in the :data:`~tap_bench.bench.scores.
            windows.CUT_FROM` column: the coverage's and the
            null's intervals resample them by whole episodes (a cluster bootstrap) and
            the novelty's Wilson interval is taken at the episodes' worth of information
            (its design effect), as the windows of one episode are not independent.

    Returns:
        (coverage rows, novelty rows, novel labels), each with env, policy, reference,
        unit. Coverage rows carry the null's ``null_coverage``, ``half_coverage``,
        ``coverage_diff`` (+ interval), novelty rows ``null_novel_rate``,
        ``half_novel_rate``, ``novel_diff`` (+ interval), both ``null_m`` (trajectories of
        a half, the sizes these are taken at) and ``null_paired``.
        The novel labels are listed once, under the env whose episodes show them (a pooled
        label is an (env, label) pair: its rows are the envs' rows). Pooled coverage and
        novelty rows (``env == "all"``) aggregate the per-env ones for env-keyed references
        (:func:`tap_bench.bench.scores.coverage.pooled_coverage`,
        :func:`tap_bench.bench.scores.novelty.pooled_novelty`) and score all episodes together
        against a reference without envs.

    Raises:
        LabelTableError: ``windowed`` and ``episodes`` without the ``CUT_FROM`` column.
    """
    if windowed and CUT_FROM not in episodes.columns:
        raise LabelTableError(
            f"reference_scores(windowed=True) needs the {CUT_FROM!r} column of a table of "
            f"windows (the episode each window was cut from, resampled whole); "
            f"window_episodes adds it, or add it as window_episode(table['scenario_id']).")
    ok = _scored(episodes)
    keyed = not isinstance(reference, Reference)
    first = next(iter(reference.values()), None) if keyed else reference
    unit = unit or (first.unit if first is not None else "episodes")
    cov_rows, nov_rows, nov_labels = [], [], []
    for policy in policies if policies is not None else sorted(ok["policy"].unique()):
        pol = ok[ok["policy"] == policy]
        per_env_cov, per_env_nov, per_env_null, sizes = [], {}, [], []
        for env, sub in _env_groups(pol):
            key = {"env": env, "policy": policy, "reference": name, "unit": unit}
            if env == ALL_ENVS and keyed:
                if not per_env_cov:
                    continue
                cv = pooled_coverage(per_env_cov, sizes, config.level)
                nv = pooled_novelty(per_env_nov, config.level) if per_env_nov else None
                nl = (pooled_null([r for r, _, _ in per_env_null],
                                  [k for _, k, _ in per_env_null],
                                  [n for _, _, n in per_env_null], config.level)
                      if per_env_null else None)
            else:
                ref = reference.get(env) if keyed else reference
                if ref is None:
                    continue
                # windows are resampled by the episode each was cut from
                clusters = sub[CUT_FROM].to_numpy(object) if windowed else None
                cv = coverage(sub["sdl"], ref, config=config,
                              rng=config.rng("coverage", env, policy, name,
                                             *(() if unit == "episodes" else (unit,))),
                              clusters=clusters)
                nv = (novelty(sub, ref, config=config, windowed=windowed)
                      if ref.kind != "vocabulary" else None)
                nl = (same_policy_null(
                    sub["sdl"].to_numpy(object), ref, config=config,
                    seeds=sub["seed"].to_numpy() if paired and "seed" in sub else None,
                    clusters=clusters, rng=config.rng("null", env, policy, name, unit))
                    if ref.kind != "vocabulary" and len(ref.units) else None)
                if keyed:
                    per_env_cov.append(cv)
                    sizes.append(ref.n_trajectories)
                    if nv is not None:
                        per_env_nov[env] = nv
                    if nl is not None:  # with its env's pooling weights (K, episodes)
                        per_env_null.append((nl, cv.n_reference, cv.n))
            cov_rows.append({**key, **cv.row(), **(nl.coverage_row() if nl else {})})
            if nv is not None:
                size = (sum(r.n_trajectories for r in reference.values())
                        if keyed and env == ALL_ENVS
                        else (reference.get(env) if keyed else reference).n_trajectories)
                nov_rows.append({**key, **nv.row(), "reference_size": size,
                                 **(nl.novelty_row() if nl else {})})
                if env != ALL_ENVS:  # pooled: the envs' rows again; each (env, label) once
                    nov_labels.append(nv.labels.assign(env=env, policy=policy,
                                                       reference=name, unit=unit))
    cov = pd.DataFrame(cov_rows)
    nov = pd.DataFrame(nov_rows)
    frames = [f for f in nov_labels if len(f)]
    columns = ["env", "policy", "reference", "unit", "label", "count", "share",
               "example_scenario"]
    labels = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=columns)
    if len(labels):
        labels = labels[columns]
    return cov, nov, labels


def score(episodes: pd.DataFrame, *, reference_policy: str, level: str,
          config: BootstrapConfig | None = None,
          references: dict[str, pd.DataFrame] | None = None,
          comparisons: list[tuple[str, str]] | None = None,
          scenario_matches: pd.DataFrame | None = None,
          gate_power: pd.DataFrame | None = None,
          windows: dict[str, tuple[pd.DataFrame, str]] | None = None,
          contexts: pd.DataFrame | None = None, gap: pd.DataFrame | None = None,
          gap_labels: pd.DataFrame | None = None,
          methods: Mapping[str, str] | None = None) -> Scores:
    """Score a run.

    Args:
        episodes: the episode table (:mod:`tap_bench.bench.episodes`) of every policy.
        reference_policy: the policy compared with every other one; its ego labels, per
            env, are the ``"<policy> rollouts"`` coverage reference of that env.
        level: the SDL level of the episode table's labels.
        config: interval settings.
        references: more reference corpora: name -> label table (e.g. ``{"WOMD": labels}``;
            vehicles' labels at ``level`` are used; one reference for every env).
        comparisons: (A, B) pairs to compare, B the reference; default every other policy
            against the reference policy, as (policy, reference).
        scenario_matches: a precomputed table of cross-data-set scenario matches to carry.
        gate_power: a precomputed power table of the gate to carry.
        windows: reference name -> (episode table, unit): the policies' episodes cut into
            windows of that reference's track length (:func:`tap_bench.bench.scores.windows.
            window_episodes`, e.g. 9.1 s for WOMD; each window's episode in its
            :data:`~tap_bench.bench.scores.windows.CUT_FROM` column), scored against it in
            place of whole episodes (``unit`` says so: ``"9.1 s windows"``).
        contexts: a precomputed table of the interaction contexts' scores to carry
            (:func:`tap_bench.bench.scores.contexts.context_scores`).
        gap, gap_labels: precomputed sim-to-real gap tables to carry
            (:mod:`tap_bench.bench.scores.gap`).
        methods: how the carried tables were made (table name -> text), listed after the
            methods of the tables scored here.

    Returns:
        :class:`Scores`.
    """
    config = config or BootstrapConfig()
    policies = sorted(episodes["policy"].unique())
    if comparisons is None:
        comparisons = [(p, reference_policy) for p in policies if p != reference_policy]
    # in steps: the methods, each policy's own tables, each policy against each reference
    # corpus, each policy's diversity, the policies against one another
    carried_methods, methods = dict(methods or {}), _methods(config)
    label_counts, measures = _label_counts(episodes), policy_measures(episodes, config)
    cov, nov, novel_labels, refs = _reference_scores(
        episodes, reference_policy=reference_policy, level=level, config=config,
        references=references, windows=windows)
    diversity = diversity_table(episodes, config)
    compared = compare_policies(episodes, comparisons, config)
    methods["paired"] = compared.method  # in the place _methods keeps for it
    if compared.skipped:
        methods["skipped comparisons"] = "; ".join(compared.skipped)
    methods.update(carried_methods)
    carried = {"gate_power": gate_power, "scenario_matches": scenario_matches, "gap": gap,
               "gap_labels": gap_labels, "contexts": contexts}
    return Scores(
        label_counts=label_counts, measures=measures, paired=compared.paired,
        paired_measures=compared.measures, paired_labels=compared.labels,
        matched=compared.matched, coverage=cov, novelty=nov, novel_labels=novel_labels,
        diversity=diversity, references=refs, methods=methods,
        **{name: table for name, table in carried.items() if table is not None})


def _reference_scores(episodes: pd.DataFrame, *, reference_policy: str, level: str,
                      config: BootstrapConfig,
                      references: dict[str, pd.DataFrame] | None,
                      windows: dict[str, tuple[pd.DataFrame, str]] | None,
                      ) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame,
                                 dict[str, Reference]]:
    """The coverage, novelty and novel-label tables of every policy against each reference
    (the reference policy's rollouts per env, then ``references``), per unit
    (:data:`UNITS`), each one under the other; and the references by name."""
    ok = _scored(episodes)
    ref_eps = ok[ok["policy"] == reference_policy]
    refs: dict[str, Reference] = {}
    rollouts = f"{reference_policy} rollouts"
    policies = sorted(episodes["policy"].unique())
    others = [p for p in policies if p != reference_policy]  # a corpus covers itself
    # every reference (the rollouts per env, then each corpus; both units), then every
    # policy scored against each in that order
    against: list[tuple[pd.DataFrame, Reference | dict[str, Reference], str, dict]] = []
    for unit in UNITS:  # whole labels, then the manoeuvres (segments) episodes contain
        per_env: dict[str, Reference] = {}
        for env, sub in ref_eps.groupby("env", sort=True):
            per_env[str(env)] = corpus_reference(sub.assign(level=level), level,
                                                 tracks="all", name=f"{rollouts} ({env})",
                                                 unit=unit)
            shown = f"{rollouts} ({env})" + ("" if unit == "episodes" else f", {unit}")
            refs[shown] = per_env[str(env)]
        against.append((episodes, per_env, rollouts, {"policies": others, "paired": True}))
    for name, table in (references or {}).items():
        scored, unit_name = (windows or {}).get(name, (episodes, None))
        for unit in UNITS:
            ref = corpus_reference(table, level, tracks="vehicles", name=name, unit=unit)
            refs[name + ("" if unit == "episodes" else f", {unit}")] = ref
            against.append((scored, ref, name, {
                "unit": unit if unit_name is None else f"{unit_name}, {unit}"
                if unit == "segments" else unit_name, "windowed": unit_name is not None}))
    parts = [reference_scores(scored, ref, name, config=config, **how)
             for scored, ref, name, how in against]
    # each kind (coverage, novelty, novel labels): its non-empty tables one under the other
    kinds = [[t for t in kind if len(t)] for kind in zip(*parts, strict=True)]
    cov, nov, labels = (pd.concat(k, ignore_index=True) if k else pd.DataFrame()
                        for k in kinds)
    return cov, nov, labels, refs


def _methods(config: BootstrapConfig) -> dict[str, str]:
    """How each table of a run's scores was computed, as the report states it, in its
    order; the paired comparisons' text (``"paired"``) is theirs
    (:attr:`~tap_bench.bench.scores.compare.Comparisons.method`): "" here, set by
    :func:`score` once they are made."""
    return {
        "measures": f"{config.level:.0%} intervals over episodes, each measure's own: "
                    + "; ".join(f"{m.label}: {m.interval_method}" for m in MEASURES)
                    + "; 'all' pools every episode of the policy",
        "paired": "",
        "matched": (f"{config.level:.0%} Welch t intervals (Newcombe score intervals for "
                    "rates: " + ", ".join(m.label for m in MEASURES if m.is_rate)
                    + ") between the episodes of each policy in a label group of one "
                    f"env; groups with fewer than {MIN_GROUP} episodes of a policy are listed, "
                    "not tested"),
        "coverage": (f"{config.level:.0%} studentized bootstrap (bootstrap-t) intervals "
                     f"over {config.n_resamples} draws from the label distribution augmented "
                     "with Chao1-estimated undetected labels (Chao et al. 2014, iNEXT's "
                     "population), each draw against its population's own value; labels are "
                     "(env, label): 'all' is the share of every env's reference labels shown "
                     f"(K-weighted mean of the envs); seed {config.seed}, streams named "
                     "('coverage', env, policy, reference)"),
        "novelty": f"{config.level:.0%} Wilson score intervals; 'all' pools the per-env "
                   "counts (each env held against its own reference)",
        "same-policy null": (
            "beside each coverage and novelty: the same-policy figure (the reference split "
            "in random halves, one half held against the other) and the policy at the same "
            "sizes (its episodes on the probe half's seeds for rollouts of the same seeds, "
            f"else as many drawn at random), means over {SPLITS} splits; the difference's "
            f"{config.level:.0%} interval from {config.n_resamples} bootstrap draws (a "
            "split, each half resampled), re-centred and shrunk by the split-to-split "
            "spread (coverage measured by benchmarks/null_coverage.py); 'all' pools the "
            "envs as coverage and novelty are pooled"),
        "unit": ("episodes: each episode's whole label; segments: the labels of its "
                 "segments (the runs of one label on one axis: the manoeuvres it contains), "
                 "an episode novel when one of its segments carries a label the reference "
                 "never shows; windows: the episodes cut into windows of the reference's "
                 "median track length before labelling"),
        "diversity": (f"Hill numbers q = 0, 1, 2 at a common sample size per env (the "
                      "smallest episode count of its policies; iNEXT rarefaction/"
                      f"extrapolation), {config.level:.0%} studentized bootstrap "
                      f"(bootstrap-t) intervals over {config.n_resamples} draws from iNEXT's "
                      "bootstrap population (completeness: Esty's standard error); "
                      "asymptotes given as "
                      f"'at least' when the sample completeness is below {MIN_COMPLETENESS}; "
                      "'all' is the mean over envs"),
    }
