"""``format_table3``: Suzuki Table 3 as text (the rendering studies themselves: tests/model/fitting)."""

import pytest

from facestats.errors import ValidationError
from facestats.pipeline.suzuki_studies import format_table3


def test_a_width_not_in_the_paper_reads_a_dash_and_a_failed_fit_reads_failed():
    rows = [
        {"width": 8.0, "paper": (2.1, 0.0021), "pinv": (2.2, 0.0022), "pinv_fit": None},
        {"width": 3.0, "paper": None, "pinv": None, "pinv_fit": None},
    ]
    lines = format_table3(rows).splitlines()
    assert lines[0].split("|")[2].strip() == "pinv" and len(lines) == 5
    assert [c.strip() for c in lines[3].split("|")] == ["8", "2.10  0.0021", "2.20  0.0022"]
    assert [c.strip() for c in lines[4].split("|")] == ["3", "-", "failed"]


def test_no_rows_is_refused_by_name():
    with pytest.raises(ValidationError, match="rows must hold at least one row of table3"):
        format_table3([])
