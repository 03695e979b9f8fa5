"""Size of a run's report and replay viewer, the time to write the viewer, and the time to
open both in headless Chromium.

For a run of fewer seeds than a suite has, the viewer's episode data is extrapolated in
proportion to the episodes (``--scale-to``): the chunks hold one env and seed each, so
their size grows with the number of seeds, while the page, script and road maps do not.

Usage: ``python benchmarks/bench_viewer.py RUN_DIR [--scale-to EPISODES]``.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

import pandas as pd
from machine import report

from tap_bench.bench.run.runner import run_viewer


def _size(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def _open_seconds(page: Path, fragment: str = "") -> float:
    """Seconds from asking Chromium for a page to the viewer's first episode drawn (or the
    report's load event)."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium")
    profile = tempfile.mkdtemp()
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--window-size=1400,1000", f"--user-data-dir={profile}"):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(shutil.which("chromedriver")), options=options)
    try:
        driver.get("about:blank")  # the browser's own start-up is not the page's
        start = time.perf_counter()
        driver.get(page.resolve().as_uri() + fragment)
        driver.execute_async_script(
            "const done = arguments[arguments.length - 1];"
            "const wait = () => (typeof TAPVIEW === 'undefined') ? done(null) :"
            "  TAPVIEW.state.ready ? TAPVIEW.state.ready.then(() => done(true)) :"
            "  setTimeout(wait, 10);"
            "wait();")
        return time.perf_counter() - start
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--scale-to", type=int, help="extrapolate the viewer to this many "
                        "episodes (the full suite)")
    args = parser.parse_args()
    episodes = len(pd.read_parquet(args.run / "episodes.parquet"))
    out = Path(tempfile.mkdtemp()) / "viewer"
    t0 = time.perf_counter()
    page = run_viewer(args.run, out)
    write_s = time.perf_counter() - t0
    chunks = [p for p in (out / "data").glob("*.js") if p.name != "index.js"]
    chunk_bytes = sum(p.stat().st_size for p in chunks)
    fixed = _size(out) - chunk_bytes
    figures = {
        "episodes": episodes, "viewer_mb": _size(out) / 1e6,
        "viewer_index_mb": (out / "data" / "index.js").stat().st_size / 1e6,
        "viewer_chunks": len(chunks), "largest_chunk_mb": max(p.stat().st_size
                                                             for p in chunks) / 1e6,
        "bytes_per_episode": chunk_bytes / episodes,
        "write_viewer_s": write_s,
        "open_viewer_s": _open_seconds(page),
        "report_mb": (args.run / "report.html").stat().st_size / 1e6,
        "open_report_s": _open_seconds(args.run / "report.html"),
    }
    if args.scale_to:
        figures["viewer_mb_extrapolated"] = (fixed + chunk_bytes * args.scale_to / episodes) / 1e6
        figures["extrapolated_to_episodes"] = args.scale_to
    report(f"viewer_{args.run.name}", figures)
    shutil.rmtree(out.parent, ignore_errors=True)


if __name__ == "__main__":
    main()
