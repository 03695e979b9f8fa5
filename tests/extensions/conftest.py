"""The extension examples of docs/contributing.md, copied as written into a temporary
package (``tapext``): a measure (``tapext.measures``) and a data format
(``tapext.my_formats``); registered for one test and removed afterwards."""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

DOCS = Path(__file__).resolve().parents[2] / "docs" / "contributing.md"


def docs_example(section: str) -> str:
    """The first Python code block under the ``## <section>`` heading of the docs."""
    text = DOCS.read_text(encoding="utf-8")
    start = text.index(f"## {section}\n")
    end = text.find("\n## ", start + 1)
    block = re.search(r"```python\n(.*?)```", text[start:end if end > 0 else None], re.S)
    assert block, f"docs/contributing.md has no python example under '## {section}'"
    return block.group(1)


def write_drive(path: Path, accel: float) -> None:
    """One scenario as the docs' CSV format: two vehicles, 6 s at 10 Hz, the first one
    speeding up or braking at ``accel`` [m/s^2]."""
    t = np.arange(60) / 10
    rows = []
    for track, x0, a in (("1", 0.0, accel), ("2", 40.0, 0.0)):
        v = 15.0 + a * t
        rows.append(pd.DataFrame({"track_id": track, "t": t, "x": x0 + 15.0 * t + a * t * t / 2,
                                  "y": 0.0, "heading": 0.0, "speed": v}))
    pd.concat(rows).to_csv(path, index=False)


@pytest.fixture
def extension(tmp_path, monkeypatch):
    """The docs' examples as the package ``tapext`` on sys.path (workers get it as
    PYTHONPATH), two drives in the docs' CSV format, and the module names to pass as
    plugins; the registrations are undone afterwards."""
    from tap_bench import plugins
    from tap_bench.bench.measures import MEASURES
    from tap_bench.sources.registry import READERS

    package = tmp_path / "pkgs" / "tapext"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "measures.py").write_text(docs_example("Add a measure"))
    (package / "my_formats.py").write_text(docs_example("Add a data format"))
    monkeypatch.syspath_prepend(str(package.parent))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(  # for a command in a subprocess
        [str(package.parent), *filter(None, [os.environ.get("PYTHONPATH")])]))
    monkeypatch.setattr(plugins, "_LOADED", {})  # this test's plugins only
    drives = [tmp_path / "a.scn.csv", tmp_path / "b.scn.csv"]
    write_drive(drives[0], -1.5)
    write_drive(drives[1], 0.8)
    yield {"modules": ["tapext.measures", "tapext.my_formats"], "drives": drives,
           "measure": "max_decel", "format": "my-csv"}
    for registry, name in ((MEASURES, "max_decel"), (READERS, "my-csv")):
        if name in registry:
            registry.unregister(name)
    for module in ("tapext.measures", "tapext.my_formats", "tapext"):
        sys.modules.pop(module, None)
