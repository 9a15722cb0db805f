"""``notebooks/microstructure.ipynb`` runs at small size: Fig. 11/12, the strain of a smile, before/after normals."""

import re

import pytest

from tests.helpers import (
    assert_nothing_left,
    NOTEBOOKS,
    TEST_DATA,
    assert_no_errors,
    cell_text,
    execute_once,
    read_committed,
    shows_figure,
    tagged,
)

NOTEBOOK = NOTEBOOKS / "microstructure.ipynb"

#: Cells (by tag) that must display a figure.
FIGURES = ("fig12", "fit-landscape", "table-fit", "strain", "before-after")


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    env = {"ICT_FACEKIT": TEST_DATA / "ict-facekit"}  # the kernel runs in the temporary workdir
    return execute_once(NOTEBOOK, tmp_path_factory, env=env)


def test_committed_notebook_is_valid_small_and_has_no_outputs():
    nb = read_committed(NOTEBOOK)
    assert "SMALL = True" in tagged(nb, "setup").source
    assert sum(c.cell_type == "markdown" for c in nb.cells) >= 6


@pytest.mark.slow
def test_runs_without_errors_and_writes_nothing_to_its_directory(executed):
    nb, workdir = executed
    assert_no_errors(nb)
    assert_nothing_left(workdir)  # the sequence goes to a temporary directory


@pytest.mark.slow
def test_every_figure_is_displayed(executed):
    nb, _ = executed
    for tag in FIGURES:
        assert shows_figure(tagged(nb, tag)), tag


@pytest.mark.slow
def test_profiles_follow_the_table_and_the_smile_is_shown(executed):
    nb, _ = executed
    text = cell_text(tagged(nb, "fig11"))
    # Where the table's sigma is over a texel (r >= 0.88), alpha given sigma is within 0.1 of eq. 8.
    for r, alpha in ((0.88, -0.371), (1.15, 0.463), (1.22, 0.68), (1.28, 0.865)):
        row = next(line.split() for line in text.splitlines() if re.match(rf"\s*\d+\s+{r}\s", line))
        assert abs(float(row[4]) - alpha) <= 0.1, (r, row)
    assert "alpha(1) = 0.0;" in cell_text(tagged(nb, "table-fit"))
    assert "0 degenerate triangles" in cell_text(tagged(nb, "strain"))
    assert "4 frames" in cell_text(tagged(nb, "sequence"))


@pytest.mark.slow
def test_dense_surface_argmin_is_printed_within_tolerance(executed):
    nb, _ = executed
    text = cell_text(tagged(nb, "dense-argmin"))
    alpha, sigma = (float(x) for x in re.search(r"argmin alpha = (\S+), sigma = (\S+) um", text).groups())
    assert abs(alpha + 1.0) <= 0.1 and abs(sigma - 20.0) <= 10.0  # one texel (the notebook works at 10 um/texel)
