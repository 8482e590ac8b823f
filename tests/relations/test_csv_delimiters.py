"""A CSV of semicolon- or tab-separated numbers reads as its columns, not as a one-cell header."""

import numpy as np
import pytest

from jaml.sources.file import _read_csv


@pytest.mark.parametrize("sep", [";", "\t", ","])
def test_separators_with_and_without_a_header(tmp_path, sep):
    path = tmp_path / "rows.csv"
    path.write_text(sep.join("abc") + "\n" + "\n".join(sep.join(map(str, r))
                                                       for r in ([1, 2, 3], [4, 5, 6.5])) + "\n")
    rows, names = _read_csv(path)
    assert names == ("a", "b", "c")
    np.testing.assert_array_equal(rows, [[1, 2, 3], [4, 5, 6.5]])
    path.write_text(f"1{sep}2\n3{sep}4\n")
    rows, names = _read_csv(path)
    assert names == () and rows.shape == (2, 2)


def test_a_decimal_comma_is_named_not_guessed(tmp_path):
    path = tmp_path / "eu.csv"
    path.write_text("1,5;2\n3;4\n")  # the first line has a comma: read as comma-separated
    with pytest.raises(ValueError, match="line 2 has 1 columns"):
        _read_csv(path)
