"""``notebooks/translucency_from_image.ipynb`` runs at small size: Table 3, noise, auto width, rank, faces."""

import re

import pytest

from tests.helpers import (
    assert_nothing_left,
    NOTEBOOKS,
    assert_no_errors,
    cell_text,
    execute_once,
    read_committed,
    shows_figure,
    tagged,
)

NOTEBOOK = NOTEBOOKS / "translucency_from_image.ipynb"
FIGURES = ("fig5", "noise", "surface", "face-image", "face-fit", "face-study")


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    return execute_once(NOTEBOOK, tmp_path_factory)


def test_committed_notebook_is_valid_small_and_has_no_outputs():
    nb = read_committed(NOTEBOOK)
    assert "SMALL = True" in tagged(nb, "setup").source
    assert sum(c.cell_type == "markdown" for c in nb.cells) >= 6


def test_runs_without_errors_writes_nothing_and_shows_its_figures(executed):
    nb, workdir = executed
    assert_no_errors(nb)
    assert_nothing_left(workdir)
    for tag in FIGURES:
        assert shows_figure(tagged(nb, tag)), tag


def test_table3_beside_the_paper_and_the_studies(executed):
    nb, _ = executed
    table = cell_text(tagged(nb, "table3"))
    row = next(line for line in table.splitlines() if line.strip().startswith("0.25 |"))
    cells = [c.split() for c in row.split("|")]
    assert cells[1] == ["2.19", "0.0021"] and cells[3] == ["2.19", "0.0021"]  # paper and default
    assert "paper" in table and "pinv" in table and "monotone" in table
    noise = cell_text(tagged(nb, "noise"))
    assert "'coverage': 1.0" in noise or re.search(r"'coverage': 0\.(8[5-9]|9)", noise)
    assert "width" in cell_text(tagged(nb, "auto")) and "warning:" in cell_text(tagged(nb, "rank"))
    fits = dict(re.findall(r"^(\w+) +exitance .*sigma_s' ([\d.]+)", cell_text(tagged(nb, "surface")), re.M))
    assert abs(float(fits["surface"]) / 2.19 - 1) <= 0.01, fits  # the plate's surface quadrature, SMALL size
    err = float(re.search(r"vs truth ([\d.]+)%", cell_text(tagged(nb, "face-study"))).group(1))
    assert err <= 10.0
