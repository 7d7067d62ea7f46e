"""The console's plain text tables (gonio.console)."""

import numpy as np

from gonio.console import format_table


def test_columns_aligned_floats_to_four_digits_and_a_rule_under_the_header():
    text = format_table(["name", "value"], [["rho_d", np.float64(0.123456)], ["alpha_x", 12]])
    lines = text.splitlines()
    assert lines[0] == "name     value"
    assert lines[1] == "-------  ------"
    assert lines[2] == "rho_d    0.1235"
    assert lines[3] == "alpha_x  12"
    assert all(line == line.rstrip() for line in lines)


def test_a_table_without_rows_is_its_header_and_rule():
    assert format_table(["a", "bb"], []).splitlines() == ["a  bb", "-  --"]
