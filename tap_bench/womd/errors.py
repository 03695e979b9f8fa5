"""The error raised for a WOMD file or record that cannot be read."""

from __future__ import annotations

from tap_bench.errors import FileFormatError

__all__ = ["WomdRecordError"]


class WomdRecordError(FileFormatError):
    """A record of a WOMD file is damaged or is not what the reader expects.

    The message names the file, the record (0-based) and its byte offset, what was wrong and
    the fix.

    Attributes:
        path: the file.
        record: 0-based index of the record in the file.
        offset: byte offset of the record's start (in the decompressed stream of a GZIP file).
        problem: what was wrong, without the location.
        resumable: whether the records after this one can still be read (false when the
            framing itself is broken: the next record's start is unknown).
    """

    def __init__(self, path: str, record: int, offset: int, problem: str, fix: str,
                 resumable: bool = True):
        self.path = str(path)
        self.record = record
        self.offset = offset
        self.problem = problem
        self.fix = fix
        self.resumable = resumable
        super().__init__(f"{path}: record {record} at byte {offset}: {problem}. {fix}")

    def __reduce__(self):  # keeps the attributes across worker processes
        return (type(self), (self.path, self.record, self.offset, self.problem, self.fix,
                             self.resumable))

    def as_dict(self) -> dict:
        """The location and the problem, for a report."""
        return {"path": self.path, "record": self.record, "offset": self.offset,
                "problem": self.problem}
