"""The replay viewer used as a person would, in headless Chromium: it loads without console
errors, playback moves the time and the label timeline, A and B stay on one clock, filters
narrow the list, WOMD scenarios show their map and labels, and each pane draws the other
pane's ego as a ghost (on a highway pair, and the human's beside a policy's on a WOMD run).
Each test writes a screenshot.
"""

from __future__ import annotations

import json
import time

import pandas as pd
import pytest

from .conftest import console_errors, open_page


def _state(driver, expr: str):
    return driver.execute_script(f"return {expr};")


def _paired_seed(run) -> tuple[str, str]:
    """(A's scenario id, B's policy): random against idm on the first highway seed."""
    eps = pd.read_parquet(run / "episodes.parquet")
    a = eps[(eps["env"] == "highway") & (eps["policy"] == "random")].iloc[0]
    return a["scenario_id"], "idm"


def test_viewer_loads_without_console_errors(tiny_run, browser, screenshots):
    page = tiny_run / "viewer" / "index.html"
    open_page(browser, page)
    assert console_errors(browser) == []
    eps = pd.read_parquet(tiny_run / "episodes.parquet")
    items = _state(browser, "document.querySelectorAll('#episode-list li').length")
    assert items == len(eps)
    assert _state(browser, "TAPVIEW.state.a.doc.id") == eps["scenario_id"].iloc[0]
    # the road is drawn: the map of the env has lanes
    assert _state(browser, "TAPVIEW.state.index.maps.highway.length") > 0
    browser.save_screenshot(str(screenshots / "viewer-first-episode.png"))


def test_playback_advances_time_and_the_label_timeline(tiny_run, browser, screenshots):
    sid, b = _paired_seed(tiny_run)
    open_page(browser, tiny_run / "viewer" / "index.html", f"#ep={sid}&b={b}&t=0")
    x0 = float(_state(browser, "TAPVIEW.state.a.view.timeline.playhead.getAttribute('x1')"))
    browser.find_element("id", "speed").send_keys("4")  # 4x
    browser.find_element("id", "play").click()
    # at 4x, 0.5 s of the scene take ~0.13 s of wall time; a loaded machine (the suite runs
    # in two processes) may starve the browser for a while, so wait up to 10 s for it
    deadline = time.monotonic() + 10.0
    while _state(browser, "TAPVIEW.state.t") <= 0.5 and time.monotonic() < deadline:
        time.sleep(0.05)
    browser.find_element("id", "play").click()  # pause
    # a starved browser may still be drawing a frame queued before the pause: read the time
    # once it holds still
    t, deadline = _state(browser, "TAPVIEW.state.t"), time.monotonic() + 10.0
    while time.monotonic() < deadline:
        time.sleep(0.3)
        now_t = _state(browser, "TAPVIEW.state.t")
        if now_t == t:
            break
        t = now_t
    assert t > 0.5  # playback moved the time
    x1 = float(_state(browser, "TAPVIEW.state.a.view.timeline.playhead.getAttribute('x1')"))
    assert x1 > x0
    shown = browser.find_element("id", "time").text
    assert shown.startswith(f"t = {t:.1f} s")
    # the readout names the labels under the playhead, as the data has them
    runs = _state(browser, "TAPVIEW.state.a.doc.labels[TAPVIEW.state.a.ego.id]")
    lat = next(r[2] for r in runs["lateral"] if r[0] <= min(t, 5.9) < r[1])
    now = browser.find_element("css selector", "#pane-a .now").text
    assert now.startswith(f"now: {lat}")
    browser.save_screenshot(str(screenshots / "viewer-playing.png"))
    # stepping moves by one 0.1 s step, back then forward: a starved test may read the time
    # only once playback reached the scene's end, where a step forward stays put
    browser.find_element("id", "step-back").click()
    back = _state(browser, "TAPVIEW.state.t")
    assert back == pytest.approx(round(t * 10 - 1) / 10)
    browser.find_element("id", "step-fwd").click()
    assert _state(browser, "TAPVIEW.state.t") == pytest.approx(round(back * 10 + 1) / 10)
    assert console_errors(browser) == []


def test_a_and_b_stay_in_sync(tiny_run, browser, screenshots):
    sid, b = _paired_seed(tiny_run)
    open_page(browser, tiny_run / "viewer" / "index.html", f"#ep={sid}&b={b}&t=0")
    a_entry = _state(browser, "TAPVIEW.state.a.entry")
    b_entry = _state(browser, "TAPVIEW.state.b.entry")
    assert (a_entry["policy"], b_entry["policy"]) == ("random", "idm")
    assert (a_entry["env"], a_entry["seed"]) == (b_entry["env"], b_entry["seed"])
    for target in (1.7, 3.2):
        browser.execute_script(f"TAPVIEW.seek({target});")
        heads = _state(browser, "[TAPVIEW.state.a, TAPVIEW.state.b].map(e => "
                                "[e.view.timeline.playhead.getAttribute('x1'), "
                                "e.view.chart.playhead.getAttribute('x1')])")
        assert heads[0] == heads[1]  # one clock, one time axis
        # both panes draw the same instant: the canvases say so
        stamps = _state(browser, "Array.from(document.querySelectorAll('#panes .now'))"
                                 ".map(p => p.textContent)")
        assert len(stamps) == 2 and all(s.startswith("now: ") for s in stamps)
    browser.find_element("id", "play").click()
    time.sleep(0.5)
    browser.find_element("id", "play").click()
    heads = _state(browser, "[TAPVIEW.state.a, TAPVIEW.state.b].map(e => "
                            "e.view.timeline.playhead.getAttribute('x1'))")
    assert heads[0] == heads[1]
    browser.save_screenshot(str(screenshots / "viewer-side-by-side.png"))
    # the hash names the replay, so the address opens it again
    assert f"ep={sid.replace('/', '%2F')}" in browser.current_url
    assert console_errors(browser) == []


def test_filters_narrow_the_list(tiny_run, browser, screenshots):
    from selenium.webdriver.support.ui import Select

    open_page(browser, tiny_run / "viewer" / "index.html")
    eps = pd.read_parquet(tiny_run / "episodes.parquet")

    def listed() -> list[str]:
        return _state(browser, "Array.from(document.querySelectorAll('#episode-list li'))"
                               ".map(li => li.dataset.id)")

    Select(browser.find_element("id", "filter-policy")).select_by_value("random")
    assert sorted(listed()) == sorted(eps.loc[eps["policy"] == "random", "scenario_id"])
    Select(browser.find_element("id", "filter-env")).select_by_value("roundabout")
    want = eps[(eps["policy"] == "random") & (eps["env"] == "roundabout")]
    assert sorted(listed()) == sorted(want["scenario_id"])
    Select(browser.find_element("id", "filter-crash")).select_by_value("yes")
    assert sorted(listed()) == sorted(want.loc[want["crashed"].astype(bool), "scenario_id"])
    browser.find_element("id", "filter-clear").click()
    assert len(listed()) == len(eps)
    label = eps["lateral"].dropna().iloc[0].split(" > ")[0]
    browser.find_element("id", "filter-label").send_keys(label)
    hits = eps[eps["sdl"].fillna("").str.lower().str.contains(label.lower(), regex=False)]
    assert sorted(listed()) == sorted(hits["scenario_id"])
    assert 0 < len(hits) <= len(eps)
    count = browser.find_element("id", "list-count").text
    assert count.startswith(f"{len(hits)} of {len(eps)} episodes")
    browser.save_screenshot(str(screenshots / "viewer-filtered.png"))
    # clicking a listed episode opens it
    first = listed()[0]
    browser.find_element("css selector", f"#episode-list li[data-id='{first}']").click()
    browser.execute_async_script("const d = arguments[0]; setTimeout(d, 200);")
    assert _state(browser, "TAPVIEW.state.a.doc.id") == first
    assert console_errors(browser) == []


def test_womd_scenarios_show_their_map_and_labels(womd_dir, tmp_path, browser, screenshots):
    from tap_bench.bench.report.viewer import write_womd_viewer

    files = [womd_dir / "motion_data_one_scenario.tfrecord",
             womd_dir / "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl"]
    page = write_womd_viewer(files, tmp_path / "womd")
    open_page(browser, page, "#ep=637f20cafde22ff8&t=4")
    assert console_errors(browser) == []
    assert _state(browser, "TAPVIEW.state.index.episodes.length") == 2
    doc = json.loads(_state(browser, "JSON.stringify({n: TAPVIEW.state.a.doc.map.length, "
                                     "labelled: Object.keys(TAPVIEW.state.a.doc.labels).length,"
                                     "kinds: [...new Set(TAPVIEW.state.a.doc.map"
                                     ".map(f => f[0]))]})"))
    assert doc["n"] > 100 and {"lane", "road_edge"} <= set(doc["kinds"])
    assert doc["labelled"] > 10  # every labelled vehicle, not only the ego
    now = browser.find_element("css selector", "#pane-a .now").text
    assert now.startswith("now: ") and "(no label)" not in now
    browser.save_screenshot(str(screenshots / "viewer-womd.png"))


def _record_ghosts(browser) -> None:
    """Record the dashed outlines the panes stroke (drawGhost), with the canvas transform."""
    browser.execute_script("""
      window.ghosts = [];
      const proto = CanvasRenderingContext2D.prototype, raw = proto.strokeRect;
      proto.strokeRect = function (x, y, w, h) {
        if (this.getLineDash().length) {
          const m = this.getTransform();
          window.ghosts.push({canvas: this.canvas, w, h, e: m.e, f: m.f});
        }
        return raw.call(this, x, y, w, h);
      };""")


def _check_ghosts(browser, t: float) -> float:
    """Seek to ``t`` and check that each pane strokes one ghost, the other pane's ego (its
    size, at its position in this pane's pixels); returns how far apart [m] the two egos
    are then."""
    browser.execute_script(f"window.ghosts = []; TAPVIEW.seek({t});")
    for me, other in (("a", "b"), ("b", "a")):
        got = _state(browser, f"""window.ghosts.filter(g => g.canvas ===
            TAPVIEW.state.{me}.view.canvas).map(g => [g.w, g.h, g.e, g.f])""")
        assert len(got) == 1, (me, got)  # one ghost a frame
        w, h, e, f = got[0]
        # where the other pane's ego is at t, in this pane's pixels
        want = _state(browser, f"""(() => {{
            const me = TAPVIEW.state.{me}, o = TAPVIEW.state.{other}, tr = o.ego;
            const i = Math.round({t} * 10) - tr.s0;
            const x = tr.x[i] * o.q + o.origin[0], y = tr.y[i] * o.q + o.origin[1];
            const [s, cx, cy, W, H] = me.view.transform;
            return [tr.len, tr.wid, W / 2 + s * (x - cx), H / 2 - s * (y - cy)];
        }})()""")
        assert [w, h] == pytest.approx(want[:2])
        assert [e, f] == pytest.approx(want[2:], abs=0.5)
    world = ("(() => { const ep = TAPVIEW.state.%s, tr = ep.ego, i = %d - tr.s0;"
             " return [tr.x[i] * ep.q + ep.origin[0], tr.y[i] * ep.q + ep.origin[1]]; })()")
    a_at = _state(browser, world % ("a", round(t * 10)))
    b_at = _state(browser, world % ("b", round(t * 10)))
    return abs(a_at[0] - b_at[0]) + abs(a_at[1] - b_at[1])


def test_each_pane_draws_the_other_panes_ego_as_a_ghost(tiny_run, browser, screenshots):
    sid, b = _paired_seed(tiny_run)
    open_page(browser, tiny_run / "viewer" / "index.html", f"#ep={sid}&b={b}&t=0")
    _record_ghosts(browser)
    # the two egos have parted by then (random against idm): the ghost is not the ego
    assert _check_ghosts(browser, 2.0) > 0.5
    assert console_errors(browser) == []
    browser.save_screenshot(str(screenshots / "viewer-ghost.png"))


def test_a_womd_run_draws_the_human_as_the_ghost(womd_dir, tmp_path, browser, screenshots):
    import warnings

    from tap_bench.bench.run.runner import run_suite
    from tap_bench.bench.suite import suite_from_dict

    # ee519cf571686d19: the SDC drives ~40 m along a street; IDM drives it ~7 m apart
    suite = suite_from_dict({
        "name": "womd-ghost", "envs": [{"womd": [str(womd_dir / "womd_scenario_input.tfrecord")],
                                        "traffic": "log"}],
        "policies": ["idm", "log"], "reference_policy": "log", "seeds": "all",
        "bootstrap": {"n_resamples": 200}}, source="womd-ghost")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        folder = run_suite(suite, tmp_path / "run", workers=1, progress=False).folder
    open_page(browser, folder / "viewer" / "index.html", "#ep=ee519cf571686d19/idm&b=log&t=0")
    assert console_errors(browser) == []
    entries = _state(browser, "[TAPVIEW.state.a.entry, TAPVIEW.state.b.entry].map(e => "
                              "[e.policy, e.seed])")
    assert entries == [["idm", 0], ["log", 0]]  # the policy beside the human, one scene
    # a recorded scene's map comes with its episode's document (the index's maps are the
    # synthetic roads'), as the page's own mapOf reads it
    lanes = _state(browser, "(TAPVIEW.state.a.doc.map || TAPVIEW.state.index.maps["
                            "TAPVIEW.state.a.entry.map] || []).filter(f => f[0] === 'lane')"
                            ".length")
    assert lanes > 100  # the scene's WOMD lanes
    _record_ghosts(browser)
    # before the current time (1.0 s) both replay the log: the ghost covers the ego
    assert _check_ghosts(browser, 0.5) < 0.05
    # later the policy's ego and the human's part: pane A draws the human as its ghost
    assert _check_ghosts(browser, 7.0) > 2.0
    assert console_errors(browser) == []
    browser.save_screenshot(str(screenshots / "viewer-womd-ghost.png"))


def test_womd_signals_are_drawn_in_their_state_at_each_step(womd_dir, tmp_path, browser,
                                                            screenshots):
    from tap_bench.bench.report.viewer import write_womd_viewer

    # 637f20cafde22ff8: red lights hold the SDC for the whole record
    page = write_womd_viewer([womd_dir / "motion_data_one_scenario.tfrecord"],
                             tmp_path / "womd")
    open_page(browser, page, "#ep=637f20cafde22ff8&t=0")
    browser.execute_script("""
      window.discs = [];
      const proto = CanvasRenderingContext2D.prototype, arc = proto.arc, fill = proto.fill;
      proto.arc = function (x, y) {
        this._disc = [x, y];
        return arc.apply(this, arguments);
      };
      proto.fill = function () {
        if (this._disc) window.discs.push([...this._disc, this.fillStyle]);
        this._disc = null;
        return fill.apply(this, arguments);
      };""")
    colour = {"r": "#e03131", "y": "#f5c400", "g": "#2f9e44", "u": "#868e96"}
    signals = _state(browser, "TAPVIEW.state.a.doc.signals")
    assert len(signals["points"]) > 0 and len(signals["states"]) == 91
    for t in (0.0, 4.0, 8.5):
        browser.execute_script(f"window.discs = []; TAPVIEW.seek({t});")
        discs = _state(browser, "window.discs.filter(d => true)")
        now = signals["states"][round(t * 10)]
        assert _state(browser, f"TAPVIEW.signalsAt(TAPVIEW.state.a, {t})") == now
        # one disc a stop point, drawn over the map before the vehicles (walkers are discs)
        n = len(signals["points"])
        assert len(discs) >= n
        for (x, y, fill), (px, py), s in zip(discs[:n], signals["points"], now, strict=True):
            assert (x, y) == pytest.approx((px, py))
            assert fill == colour[s]
        assert "r" in now
    assert console_errors(browser) == []
    browser.save_screenshot(str(screenshots / "viewer-womd-signals.png"))
