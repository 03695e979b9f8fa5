"""The docs' figure scripts run from anywhere, and what a caption states is what its script
draws: every ``docs/figures/*.py`` writes its PNG (into a temporary folder here), skipped
where the real data it draws is absent."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
FIGURES = sorted((ROOT / "docs" / "figures").glob("*.py"))
WOMD = (ROOT / ".." / "shared" / "data" / "womd").resolve()
NEEDS = {"closed_loop.py": WOMD / "womd_scenario_input.tfrecord"}
"""Data a script draws, outside the project (skipped when absent)."""
SLOW = {"realism_histograms.py"}
"""Scripts that run for minutes (every real scene, rollouts of each traffic): in the slow
suite. The fast suite runs the other scripts from elsewhere the same way, and
tests/realism/test_realism_cli.py the realism rollouts and features this one pools."""


def run_script(script: Path, out: Path) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
    done = subprocess.run([sys.executable, str(script), "-o", str(out)], cwd=out.parent,
                          env=env, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return done.stdout


def test_every_figure_of_the_docs_has_a_script():
    assert {p.name for p in FIGURES} >= {"closed_loop.py", "interactions.py"}
    for png in (ROOT / "docs" / "figures").glob("*.png"):
        assert png.with_suffix(".py").is_file(), f"{png.name} has no script"


@pytest.mark.parametrize("script", [
    pytest.param(p, id=p.stem, marks=pytest.mark.slow if p.name in SLOW else ())
    for p in FIGURES])
def test_a_figure_script_runs_from_anywhere(script, tmp_path):
    need = NEEDS.get(script.name)
    if need is not None and not need.is_file():
        pytest.skip(f"{need} not found (real WOMD data, outside the project)")
    out = tmp_path / "elsewhere" / f"{script.stem}.png"
    out.parent.mkdir()
    stdout = run_script(script, out)
    if script.name != "closed_loop.py":
        return
    # the caption of docs/closed_loop.md states what the script drew
    facts = dict(re.findall(r"^(idm|lane-keeping|log): (.+)$", stdout, flags=re.M))
    assert set(facts) == {"log", "idm", "lane-keeping"}, stdout
    doc = (ROOT / "docs" / "closed_loop.md").read_text()
    caption = doc[doc.index("(`python docs/figures/closed_loop.py`)"):]
    caption = caption[:caption.index("*\n")]
    for policy, fact in facts.items():
        sdl, _, measures = fact.partition("; ")
        assert sdl in caption, (policy, sdl)
        if policy != "log":
            ade = re.search(r"mean distance (\S+) m", measures).group(1)
            progress = re.search(r"route progress (\S+)", measures).group(1).rstrip(",")
            assert f"{policy}" in caption and f"{ade} m" in caption, (policy, measures)
            assert f"route progress {progress}" in caption, (policy, measures)
            assert ("crashed" in measures) == (f"{policy} crashes" in caption), measures
            assert ("off road" in measures) == (f"{policy} leaves the road" in caption), \
                measures
