"""A run's trajectories on disk, one part per episode, instead of in memory.

A suite run over recorded scenes keeps each episode's labels, measures and episode row, but
not its trajectory table: :class:`TrajectorySpill` takes each task result as it arrives
(:meth:`TrajectorySpill.keep`), writes its trajectories to a Parquet part in a folder beside
the run folder and drops them from the result, so the run's memory does not grow with its
scenes' rows. Afterwards the parts are joined into ``trajectories.parquet`` a row group at a
time (:meth:`TrajectorySpill.write`), in the run's episode order, giving the table an
in-memory run writes; a step that needs every row at once (matching against a reference's
scenarios, the replay viewer) reads them back (:meth:`TrajectorySpill.table`).

The folder is the run's own (a fresh hidden folder beside the output) and is removed when
the run ends (:meth:`TrajectorySpill.close`), or when the spill is dropped (a run that
raised) or the interpreter exits.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import weakref
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["TrajectorySpill", "spills"]


def spills(scenarios: Any) -> bool:
    """Whether a run of these scenarios (env name -> scenario) spills its trajectories:
    when any env is recorded scenes (their count has no bound)."""
    from tap_bench.sim.womd_scene import WomdScenes

    return any(isinstance(s, WomdScenes) for s in scenarios.values())


class TrajectorySpill:
    """The trajectory parts of one run (module docstring).

    Args:
        output: the run folder the parts go beside (as ``.<name>.trajectories-*``).

    Attributes:
        rows: trajectory rows spilled so far.
    """

    def __init__(self, output: str | os.PathLike) -> None:
        output = Path(output)
        output.parent.mkdir(parents=True, exist_ok=True)
        self.folder = Path(tempfile.mkdtemp(prefix=f".{output.name}.trajectories-",
                                            dir=output.parent))
        self.parts: dict[int, Path] = {}
        self.rows = 0
        # removed with the spill too when the run raises (its frame, and so the spill, go)
        self._remove = weakref.finalize(self, shutil.rmtree, self.folder, True)

    def keep(self, index: int, result: dict[str, Any]) -> dict[str, Any]:
        """Write the trajectories of task result ``index`` (its ``"trajectories"``, when
        there) to a part; the result without them."""
        from tap_bench.tableio import atomic_path

        table = result.get("trajectories")
        if table is not None and len(table):
            path = self.folder / f"part-{index:08d}.parquet"
            with atomic_path(path) as tmp:
                table.to_parquet(tmp, index=False)
            self.parts[index] = path
            self.rows += len(table)
        return {**result, "trajectories": None}

    def __len__(self) -> int:
        return self.rows

    def _ordered(self) -> list[Path]:
        return [self.parts[i] for i in sorted(self.parts)]

    def table(self) -> pd.DataFrame | None:
        """Every row, in episode order, as one table (None: no rows): what an in-memory run
        holds."""
        import pandas as pd

        if not self.parts:
            return None
        return pd.concat([pd.read_parquet(p) for p in self._ordered()], ignore_index=True)

    def write(self, path: str | os.PathLike) -> int:
        """Join the parts into one Parquet table at ``path`` (one part and one row group in
        memory at a time); the rows written."""
        from tap_bench.sim.rollout_stream import join_parquet

        return join_parquet(self._ordered(), Path(path))

    def close(self) -> None:
        """Remove the parts and their folder (:attr:`parts` still names them)."""
        self._remove()
