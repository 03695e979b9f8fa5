"""The replay viewer: episodes as top-down animations with their label timelines and safety
measures, two policies side by side on the same seed, in one folder that opens from disk.

- :mod:`~tap_bench.bench.report.viewer.data`: tables to the viewer's compact documents;
- :mod:`~tap_bench.bench.report.viewer.build`: writing the folder for a run or for WOMD files;
- ``static/``: the page, its script and style (plain HTML, JavaScript and Canvas).
"""

from __future__ import annotations

from tap_bench.bench.report.viewer.build import write_run_viewer, write_viewer, write_womd_viewer

__all__ = ["write_run_viewer", "write_viewer", "write_womd_viewer"]
