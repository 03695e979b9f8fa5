"""The HTML report renders in headless Chromium (Debian's chromium and chromium-driver) with
its tables and images; it needs no server."""

from __future__ import annotations

import re
from decimal import Decimal
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.run.runner import write_results
from tap_bench.bench.scores.scoring import score
from tap_bench.stats.bootstrap import BootstrapConfig

from .conftest import make_episodes

LABELS = ["Straight | Maintain Speed", "Left Merge > Straight | Accelerate > Maintain Speed",
          "Right Merge | Decelerate", "Straight | Decelerate > Stopped"]


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> Path:
    """A scored run of three policies in two envs (synthetic episodes, one failed)."""
    tmp_path = tmp_path_factory.mktemp("report")
    rng = np.random.default_rng(0)
    rows = []
    for env in ("highway", "merge"):
        for policy, p in (("idm", [0.6, 0.2, 0.1, 0.1]), ("random", [0.1, 0.3, 0.4, 0.2]),
                          ("idm-aggressive", [0.4, 0.4, 0.2, 0.0])):
            for seed in range(15):
                rows.append({"env": env, "policy": policy, "seed": seed,
                             "scenario_id": f"{env}/{policy}/s{seed}",
                             "sdl": LABELS[rng.choice(4, p=p)],
                             "crashed": bool(rng.random() < 0.2),
                             "mean_speed": rng.normal(20, 2), "min_headway_s": rng.normal(2, .3),
                             "min_ttc_s": rng.uniform(2, 10), "rms_jerk": rng.normal(3, 1)})
    episodes = make_episodes(rows)
    episodes.loc[3, ["status", "error"]] = ["error", "RuntimeError: boom"]
    scores = score(episodes, reference_policy="idm", level="maneuver",
                   config=BootstrapConfig(n_resamples=200))
    summary = {"run": "html-test", "suite": {"name": "synthetic", "envs": ["highway", "merge"],
                                             "policies": ["idm", "random", "idm-aggressive"]},
               "level": "maneuver", "seeds": list(range(15)), "methods": scores.methods,
               "n_episodes": len(episodes), "n_failed": 1,
               "realism": [{"traffic": "idm", "policy": "log", "rollouts": 8, "scenes": 16,
                            "agents": 458, "weights": {"collision_indication": 0.25},
                            "overall": {"meta_metric": {"value": 0.791, "low": 0.726,
                                                        "high": 0.85},
                                        "collision_indication": {"value": 0.9}},
                            "by_manoeuvre": {"Left Turn": {"meta_metric": {"value": 0.7},
                                                           "agents": 12}}}]}
    return write_results(tmp_path / "run", False, summary, episodes, pd.DataFrame(), None,
                         scores)


def test_report_is_written_with_embedded_images(run_folder):
    folder = run_folder
    page = (folder / "report.html").read_text()
    figures = sorted((folder / "plots").glob("*.svg"))
    names = {p.stem for p in figures}
    assert {"tradeoff", "improvement", "coverage", "novelty", "measures_all"} <= names
    assert {"forest_idm-aggressive_vs_idm", "forest_random_vs_idm"} <= names
    assert not list((folder / "plots").glob("*.png"))  # every figure is SVG
    assert page.count('<svg role="img"') == len(figures)  # every figure inline
    for path in figures:  # each well-formed, sized, with text and marks
        root = ElementTree.fromstring(path.read_text())
        assert root.tag.endswith("svg") and int(root.get("width")) > 100
        assert int(root.get("height")) > 50
        assert root.findall(".//{http://www.w3.org/2000/svg}text")
        assert root.findall(".//{http://www.w3.org/2000/svg}circle") or \
            root.findall(".//{http://www.w3.org/2000/svg}rect")
    assert "RuntimeError: boom" in page  # the failed episode is listed
    assert "<script src" not in page and 'src="http' not in page  # nothing from the network
    assert page.index('id="summary"') < page.index('id="paired"')  # the summary comes first


def test_report_renders_in_headless_chromium(run_folder, tmp_path, browser):
    """In the suite's Chromium (``browser``, shared with the viewer's tests), at a window of
    1280 x 2000 for this page, its own size put back afterwards."""
    folder = run_folder
    driver = browser
    size = driver.get_window_size()
    driver.set_window_size(1280, 2000)
    try:
        driver.get((folder / "report.html").resolve().as_uri())
        assert driver.title == "tap-bench html-test"
        ids = set(driver.execute_script(
            "return Array.from(document.querySelectorAll('table')).map(t => t.id)"))
        assert {"summary", "facts", "measures", "paired", "paired_measures", "paired_labels",
                "matched", "coverage", "novelty", "failed"} <= ids
        rows = driver.execute_script(
            "return document.querySelector('#coverage tbody').rows.length")
        assert rows == len(pd.read_parquet(folder / "coverage.parquet"))
        figures = driver.execute_script(
            "return Array.from(document.querySelectorAll('figure svg')).map(s => "
            "s.getBoundingClientRect().width)")
        assert len(figures) == len(list((folder / "plots").glob("*.svg")))
        assert all(shown > 100 for shown in figures)
        shot = tmp_path / "report.png"
        driver.save_screenshot(str(shot))
        assert shot.stat().st_size > 10_000
    finally:
        driver.set_window_size(size["width"], size["height"])
        driver.get_log("browser")  # this page's console lines are not the next test's


def test_coverage_and_novelty_stand_beside_the_same_policy_figure(run_folder):
    """Issue 25: every coverage and novelty with the same-policy figure and the difference
    from it, on whole labels and on segments; the summary gives the difference too; each
    novel (env, label) listed once."""
    page = (run_folder / "report.html").read_text()
    for table in ("coverage", "novelty"):
        start = page.index(f'id="{table}"')
        head = page[start:page.index("</thead>", start)]
        assert "scored on" in head and "same policy (halves)" in head
        assert "difference at halves" in head
        body = page[start:page.index("</table>", start)]
        assert ">segments<" in body and ">episodes<" in body and " pts [" in body
    start = page.index('id="summary"')
    summary = page[start:page.index("</table>", start)]
    assert "same policy" in summary
    # the summary shows the policy's own figure at the halves the difference is taken at,
    # and the figures shown subtract to the difference shown
    shown = re.findall(r"halves: policy ([\d.]+) % vs same policy ([\d.]+) %: ([+-][\d.]+) pts",
                       summary)
    assert shown
    for half, null, diff in shown:
        assert Decimal(half) - Decimal(null) == Decimal(diff)
    novel = pd.read_parquet(run_folder / "novel_labels.parquet")
    assert not novel.duplicated(["env", "policy", "reference", "unit", "label"]).any()
    assert "all" not in set(novel["env"])


def test_the_realism_results_a_run_was_given_have_their_section(run_folder):
    page = (run_folder / "report.html").read_text()
    section = page[page.index("<h2>Realism of the simulated traffic</h2>"):]
    assert "0.791 [0.726, 0.850]" in section[:section.index("<h2>", 5)]
    assert "Left Turn" in section
