"""A quick behaviour-coverage signal for training: the share of a reference label set seen.

The benchmark's coverage metric (:mod:`tap_bench.bench.scores.coverage`), frequency-weighted and
with confidence intervals, is the measure of record (the training curve of
:mod:`tap_bench.rl.curve` uses it); this one is its point estimate against the SDL
vocabulary, for a quick look at a set of labels.
"""

from __future__ import annotations

from collections.abc import Collection, Iterable

from tap_bench import sdl
from tap_bench.errors import ParameterError

__all__ = ["label_coverage", "vocabulary_tokens"]


def vocabulary_tokens(level: str = "action") -> frozenset[str]:
    """Every single label of ``level``, lateral and longitudinal (``"Left Merge"``,
    ``"Maintain Fast Speed"`` ...): the default reference of :func:`label_coverage`."""
    return frozenset(sdl.vocabulary(level, "lateral")) | frozenset(
        sdl.vocabulary(level, "longitudinal"))


def label_coverage(sdl_labels: Iterable[str], reference: Collection[str] | None = None, *,
                   level: str = "action") -> float:
    """Share of ``reference`` seen in ``sdl_labels``, in [0, 1].

    Args:
        sdl_labels: SDL labels (``"Straight > Left Merge | Maintain Fast Speed"``).
        reference: the labels to cover. Whole SDL labels (e.g. those of an IDM corpus) are
            matched whole. None: the single labels of ``level`` (:func:`vocabulary_tokens`),
            matched against the single labels the SDL labels are made of.
        level: the TAP level of ``sdl_labels`` (only used when ``reference`` is None).

    Returns:
        ``len(seen & reference) / len(reference)``.
    """
    labels = set(sdl_labels)
    if reference is None:
        reference = vocabulary_tokens(level)
        seen: set[str] = set()
        for label in labels:
            for side in sdl.parse_sdl(label):
                seen.update(side)
    else:
        reference = set(reference)
        seen = labels
    if not reference:
        raise ParameterError("reference", reference, "",
            message="label_coverage: the reference set is empty.")
    return len(seen & set(reference)) / len(reference)
