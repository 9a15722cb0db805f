"""``notebooks/population_scale.ipynb`` at small size: engines, a cluster fit, Blinn-Phong residuals, uncertainty."""

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

NOTEBOOK = NOTEBOOKS / "population_scale.ipynb"


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    pytest.importorskip("distributed")
    return execute_once(NOTEBOOK, tmp_path_factory)


def test_committed_notebook_is_valid_small_and_has_no_outputs():
    nb = read_committed(NOTEBOOK)
    assert "SMALL = True" in tagged(nb, "setup").source
    assert sum(c.cell_type == "markdown" for c in nb.cells) >= 5


def test_runs_without_errors_and_writes_nothing_to_its_directory(executed):
    nb, workdir = executed
    assert_no_errors(nb)
    assert_nothing_left(workdir)


def test_engines_agree_and_the_cluster_fit_is_stored(executed):
    nb, _ = executed
    text = cell_text(tagged(nb, "engines"))
    diffs = [float(x) for x in re.findall(r"between the engines: ([0-9.e+-]+)", text)]
    assert len(diffs) == 4 and diffs[1] == 0 and diffs[0] < 1e-6 and max(diffs) < 1e-3  # normals: the same bits
    cluster = cell_text(tagged(nb, "cluster"))
    assert "written: ['S001', 'S002', 'S003']" in cluster and "3 done, 0 running, 0 interrupted, 0 failed" in cluster


def test_figures_and_numbers_are_shown(executed):
    nb, _ = executed
    for tag in ("residual-figure", "model-errors"):
        assert shows_figure(tagged(nb, tag)), tag
    assert "relative RMSE: Torrance-Sparrow" in cell_text(tagged(nb, "residual-figure"))
    cover = [int(x) for x in re.findall(r"cover (\d+)%", cell_text(tagged(nb, "coverage")))]
    assert len(cover) == 2 and all(40 <= c <= 100 for c in cover)
    assert "Within-subject uncertainty" in cell_text(tagged(nb, "query"))
