"""The run report read as a person would, in headless Chromium: it loads without console
errors, its text is legible (at least 10 px, figures not shrunk), its long tables fold and
search, and a link from a report row opens the replay of the right episode."""

from __future__ import annotations

from urllib.parse import unquote

import pandas as pd

from .conftest import console_errors, open_page


def test_report_reads_summary_first_legibly(tiny_run, browser, screenshots):
    open_page(browser, tiny_run / "report.html")
    assert console_errors(browser) == []
    first = browser.execute_script("return document.querySelector('table').id")
    assert first == "summary"
    rows = browser.execute_script("return document.querySelector('#summary tbody').rows.length")
    assert rows == pd.read_parquet(tiny_run / "episodes.parquet")["policy"].nunique()
    # every piece of visible text is at least 10 px high
    small = browser.execute_script(
        "return Array.from(document.querySelectorAll('body *')).filter(e => "
        "e.offsetParent !== null && Array.from(e.childNodes).some(n => n.nodeType === 3 && "
        "n.textContent.trim()) && parseFloat(getComputedStyle(e).fontSize) < 10)"
        ".map(e => e.tagName + ': ' + e.textContent.slice(0, 40))")
    assert small == []
    # figures (inline SVG) are shown at their drawn size (their 12 px text stays 12 px)
    figures = browser.execute_script(
        "return Array.from(document.querySelectorAll('figure svg')).map(s => "
        "[parseFloat(s.getAttribute('width')), s.getBoundingClientRect().width])")
    assert figures and all(shown >= 0.95 * drawn for drawn, shown in figures)
    images = browser.execute_script(
        "return Array.from(document.images).map(i => [i.naturalWidth, "
        "i.getBoundingClientRect().width])")
    assert all(shown >= 0.95 * natural for natural, shown in images)
    # no table is wider than the page's column
    wide = browser.execute_script(
        "return Array.from(document.querySelectorAll('.scroll')).filter(d => "
        "d.getBoundingClientRect().width > document.body.clientWidth).length")
    assert wide == 0
    browser.save_screenshot(str(screenshots / "report-top.png"))


def test_long_tables_fold_and_search(tiny_run, browser, screenshots):
    open_page(browser, tiny_run / "report.html")
    visible = ("return Array.from(document.querySelectorAll('#paired_measures tbody tr'))"
               ".filter(r => r.offsetParent !== null).length")
    total = browser.execute_script(
        "return document.querySelector('#paired_measures tbody').rows.length")
    assert total > 10 and browser.execute_script(visible) == 10
    box = "document.querySelector('#paired_measures').closest('.tablebox')"
    browser.execute_script(f"{box}.querySelector('button.more').click()")
    assert browser.execute_script(visible) == total
    search = browser.execute_script(f"return {box}.querySelector('input.search')")
    search.send_keys("crash rate")
    shown = browser.execute_script(visible)
    assert 0 < shown < total
    browser.execute_script("document.querySelector('#paired_measures th').click()")  # sort
    assert browser.execute_script(visible) == shown
    assert console_errors(browser) == []


def test_a_report_row_opens_its_replay(tiny_run, browser, screenshots):
    open_page(browser, tiny_run / "report.html")
    links = browser.execute_script(
        "return Array.from(document.querySelectorAll('#novel_labels a.replay'))"
        ".map(a => [a.href, a.closest('tr').cells[7].textContent])")  # example
    assert links, "the novel-label rows link to their example episode"
    href, example = links[0]
    assert href.split("#")[0].endswith("/viewer/index.html")
    open_page(browser, tiny_run / "viewer" / "index.html", "#" + href.split("#", 1)[1])
    assert browser.execute_script("return TAPVIEW.state.a.doc.id") == example
    assert browser.execute_script("return TAPVIEW.state.b.entry.policy") == "idm"
    assert console_errors(browser) == []
    browser.save_screenshot(str(screenshots / "report-link-replay.png"))


def test_a_paired_label_row_opens_an_episode_with_that_label(tiny_run, browser):
    open_page(browser, tiny_run / "report.html")
    href = browser.execute_script(
        "const a = document.querySelector('#paired_labels a.replay'); return a && a.href")
    assert href
    params = dict(p.split("=", 1) for p in href.split("#", 1)[1].split("&"))
    label, policy = unquote(params["f_sdl"]), unquote(params["f_policy"])
    open_page(browser, tiny_run / "viewer" / "index.html", "#" + href.split("#", 1)[1])
    a = browser.execute_script("return TAPVIEW.state.a.entry")
    assert (a["sdl"], a["policy"]) == (label, policy)
    listed = browser.execute_script("return document.querySelectorAll('#episode-list li')"
                                    ".length")
    eps = pd.read_parquet(tiny_run / "episodes.parquet")
    assert listed == ((eps["sdl"] == label) & (eps["policy"] == policy)).sum()
    assert console_errors(browser) == []
