"""Table columns built in bulk (:func:`tap_bench.sim.recorder.text_column`,
:func:`~tap_bench.sim.recorder.flag_column`) equal the columns pandas makes of one Python
object per row, dtype included."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from tap_bench.sim.recorder import flag_column, string_dtype, text_column

LABELS = (["womd-sim"], ["a", "", "é 1", "a b", "123", "x" * 40], [str(i) for i in range(300)])


def _infer_string(on: bool):
    """pandas' string inference on or off (pandas 3 warns that the switch will go)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return pd.option_context("future.infer_string", on)
        except (KeyError, pd.errors.OptionError):
            pytest.skip("this pandas has no future.infer_string option")


@pytest.mark.parametrize("labels", LABELS)
@pytest.mark.parametrize("n", [0, 1, 7, 5000])
@pytest.mark.parametrize("infer", [True, False])
def test_text_column_is_the_column_of_one_string_per_row(labels, n, infer):
    rng = np.random.default_rng(n + len(labels))
    codes = rng.integers(0, len(labels), n)
    with _infer_string(infer), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        per_row = pd.DataFrame({"c": np.array([labels[k] for k in codes] or [], dtype=object),
                                "x": np.arange(n, dtype=float)})
        built = pd.DataFrame({"c": text_column(labels, codes), "x": np.arange(n, dtype=float)},
                             copy=False)
        pd.testing.assert_frame_equal(built, per_row, check_exact=True)
        assert built["c"].tolist() == [labels[k] for k in codes]


@pytest.mark.parametrize("infer", [True, False])
def test_text_column_takes_labels_as_arrays_and_the_dtype_follows_pandas_option(infer):
    labels = ["7", "é 1", "", "12"]
    codes = np.array([3, 0, 0, 1, 2, 3, 3])
    with _infer_string(infer), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert string_dtype() == pd.Series(np.array(["a"], dtype=object)).dtype
        per_row = pd.Series(np.array([labels[k] for k in codes], dtype=object))
        for given in (labels, np.array(labels), pd.array(labels, dtype=string_dtype()),
                      np.array(labels, dtype=object)):
            built = pd.Series(text_column(given, codes))
            pd.testing.assert_series_equal(built, per_row, check_exact=True)
            assert all(type(v) is str for v in built.tolist())
        # one label: the same column whatever the route
        pd.testing.assert_series_equal(pd.Series(text_column(["é"], np.zeros(3, int))),
                                       pd.Series(np.array(["é"] * 3, dtype=object)))


@pytest.mark.parametrize("n", [0, 1, 9, 4000])
def test_flag_column_is_the_boolean_column_of_objects(n):
    rng = np.random.default_rng(n)
    values = rng.random(n) < 0.5
    for missing in (None, rng.random(n) < 0.3, np.ones(n, bool)):
        objects = np.array([None if missing is not None and missing[k] else bool(values[k])
                            for k in range(n)] or [], dtype=object)
        per_row = pd.DataFrame({"f": pd.array(objects, dtype="boolean")})
        built = pd.DataFrame({"f": flag_column(values, missing)}, copy=False)
        pd.testing.assert_frame_equal(built, per_row, check_exact=True)
        assert built["f"].isna().tolist() == [o is None for o in objects]
