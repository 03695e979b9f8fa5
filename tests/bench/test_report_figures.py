"""The report's trade-off view and forest panels (SVG): every point and interval of the
scored tables is drawn where its value says, the reference is marked, each env has its
panel, and user text is drawn as text."""

from __future__ import annotations

import re
from xml.etree import ElementTree

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.report.figures import TOP_LABELS, _forest_plots, _tradeoff_plot
from tap_bench.bench.scores.scoring import score
from tap_bench.stats.bootstrap import BootstrapConfig

from .conftest import make_episodes

SVG = "{http://www.w3.org/2000/svg}"
LABELS = ["Straight | Maintain Speed", "Left Merge > Straight | Accelerate > Maintain Speed",
          "Right Merge | Decelerate", "Straight | Decelerate > Stopped",
          "Straight | Accelerate", "Right Merge > Straight | Maintain Speed",
          "Left Merge | Decelerate > Maintain Speed"]


@pytest.fixture(scope="module", params=[(("highway",), 0), (("highway", "merge", "exit",
                                                               "roundabout"), 1)])
def scores(request):
    """Scores of three policies (one named like matplotlib math) in one or four envs."""
    envs, seed = request.param
    rng = np.random.default_rng(seed)
    rows = []
    for env in envs:
        for policy, speed in (("idm", 20.0), ("fast $x^{", 24.0), ("slow & <b>", 15.0)):
            p = rng.dirichlet(np.ones(len(LABELS)))
            for s in range(12):
                rows.append({"env": env, "policy": policy, "seed": s,
                             "scenario_id": f"{env}/{policy}/s{s}",
                             "sdl": LABELS[rng.choice(len(LABELS), p=p)],
                             "crashed": bool(rng.random() < (0.5 if speed > 22 else 0.1)),
                             "mean_speed": rng.normal(speed, 1.0),
                             "min_headway_s": rng.normal(2, .3), "min_ttc_s": rng.uniform(2, 9),
                             "rms_jerk": rng.normal(3, 1)})
    return score(make_episodes(rows), reference_policy="idm", level="maneuver",
                 config=BootstrapConfig(n_resamples=200))


def _root(figure):
    return ElementTree.fromstring(figure[1])


def _texts(root) -> list[str]:
    return ["".join(t.itertext()) for t in root.iter(f"{SVG}text")]


def test_the_tradeoff_view_draws_each_policy_per_env_where_its_values_are(scores):
    figure = _tradeoff_plot(scores, "idm")
    assert figure[0] == "tradeoff.svg"
    root = _root(figure)
    m = scores.measures
    envs = sorted(e for e in m["env"].unique() if e != "all")
    panels = envs + (["all"] if len(envs) > 1 else [])
    texts = _texts(root)
    for env in panels:  # a titled panel per env, the pooled one last
        assert ("pooled" if env == "all" else env) in texts
    assert "slow & <b>" in texts and "fast $x^{" in texts  # user text, escaped, as text
    squares = [r for r in root.iter(f"{SVG}rect") if r.get("width") == "9.0"]
    circles = list(root.iter(f"{SVG}circle"))
    assert len(squares) == len(panels)  # the reference, once per panel
    assert len(circles) == 2 * len(panels) + 3  # the others, and the legend's three marks
    # each panel: fast's circle, then slow's (names sorted), the reference's square between
    # them on the speed axis, the fast one's crash rate drawn higher (less safe) than slow's
    xs = [float(c.get("cx")) for c in circles[:-3]]
    sq = [float(s.get("x")) + 4.5 for s in squares]
    ys = [float(c.get("cy")) for c in circles[:-3]]
    for k, env in enumerate(panels):
        assert xs[2 * k + 1] < sq[k] < xs[2 * k]
        sub = m[(m["env"] == env) & (m["measure"] == "crashed")].set_index("policy")["mean"]
        if sub["fast $x^{"] > sub["slow & <b>"]:
            assert ys[2 * k] < ys[2 * k + 1]  # up is a higher crash rate


def test_the_forest_panels_show_the_labels_that_differ_most_per_env(scores):
    paths = _forest_plots(scores, level=0.9)
    pl = scores.paired_labels
    pairs = pl[["policy_a", "policy_b"]].drop_duplicates()
    assert len(paths) == len(pairs)
    per_env = max(4, TOP_LABELS // 2)
    for path in paths:
        root = _root(path)
        texts = _texts(root)
        title = next(t for t in texts if " vs " in t)
        a, b = re.match(r"(.*) vs (.*), paired by seed", title).groups()
        pair = pl[(pl["policy_a"] == a) & (pl["policy_b"] == b)]
        assert "90 % interval" in texts and "simultaneous band" in texts
        envs = sorted(pair["env"].unique())
        shown = 0
        for env in envs:
            sub = pair[pair["env"] == env]
            top = sub.reindex(sub["diff"].abs().sort_values(ascending=False).index)[:per_env]
            shown += len(top)
            assert env in texts
            names = [t for t in texts if t in set(top["label"])]
            assert set(top["label"]) <= set(names)
        circles = list(root.iter(f"{SVG}circle"))
        assert len(circles) == shown + 1  # a dot per label shown, and the legend's
        bands = [r for r in root.iter(f"{SVG}rect") if r.get("fill") == "#d9d9d9"]
        assert len(bands) == shown + 1  # the band of each label, and the legend's
        # the dots sit in order of their differences within the first panel
        sub = pair[pair["env"] == envs[0]]
        top = sub.reindex(sub["diff"].abs().sort_values(ascending=False).index)[:per_env]
        xs = np.array([float(c.get("cx")) for c in circles[1:len(top) + 1]])
        assert (np.argsort(xs, kind="stable") == np.argsort(top["diff"].to_numpy(),
                                                            kind="stable")).all() or \
            len(set(top["diff"])) < len(top)


def test_no_figure_without_its_measures():
    from tap_bench.bench.scores.scoring import Scores

    empty = Scores(**{name: pd.DataFrame() for name in Scores.TABLES})
    assert _tradeoff_plot(empty, "idm") is None
    assert _forest_plots(empty, 0.95) == []


def test_the_envs_of_a_scored_run_are_its_per_env_rows_without_the_pooled_one(scores):
    """Scores.envs: the envs each get a heat map and a measures plot (the pooled "all" rows
    of a run of several envs are no env of their own); none in scores without rows."""
    from tap_bench.bench.scores.scoring import Scores

    envs = sorted(set(scores.measures["env"]) - {"all"})
    assert scores.envs == envs and "all" not in scores.envs
    assert Scores(**{name: pd.DataFrame() for name in Scores.TABLES}).envs == []


def test_the_figures_are_drawn_from_the_scores_alone_and_the_page_writes_them(scores, tmp_path):
    """draw_figures is a pure function of the scores (name -> SVG bytes, a heat map and a
    measures plot per env): the same bytes twice, and the files write_plots writes."""
    from tap_bench.bench.report.figures import draw_figures
    from tap_bench.bench.report.page import write_plots

    drawn = draw_figures(scores, scores.envs, "idm", 0.95)
    assert drawn == draw_figures(scores, scores.envs, "idm", 0.95)
    assert {f"labels_{env}.svg" for env in scores.envs} <= set(drawn)
    written = write_plots(scores, tmp_path, reference="idm", level=0.95)
    assert {p.name: p.read_bytes() for p in written} == drawn
