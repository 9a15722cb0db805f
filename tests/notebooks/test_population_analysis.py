"""``notebooks/population_analysis.ipynb`` runs on the default store and shows Fig. 14-16, Table 1, posteriors."""

import pytest

import facestats
from facestats import analysis as fa
from tests.helpers import (
    NOTEBOOKS,
    assert_no_errors,
    assert_nothing_left,
    cell_text,
    execute_once,
    read_committed,
    shows_figure,
    tagged,
)

NOTEBOOK = NOTEBOOKS / "population_analysis.ipynb"

#: Cells (by tag) that must display a figure.
FIGURES = ("fig15", "fig16", "fig14", "table1-figure", "conditions", "posterior", "population-posterior")


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    return execute_once(NOTEBOOK, tmp_path_factory)


def test_committed_notebook_is_valid_and_has_no_outputs():
    nb = read_committed(NOTEBOOK)
    assert nb.nbformat == 4
    assert sum(c.cell_type == "markdown" for c in nb.cells) >= 7  # every figure is explained


def test_runs_without_errors_and_leaves_nothing(executed):
    nb, workdir = executed
    assert_no_errors(nb)
    assert_nothing_left(workdir)


def test_every_figure_is_displayed(executed):
    for tag in FIGURES:
        assert shows_figure(tagged(executed[0], tag)), tag


def test_tables_show_our_numbers_beside_the_paper(executed):
    with facestats.open_store() as store:
        cca = fa.brdf_cca(store, n_permutations=0)
        tr = fa.translucency_table(store)
        cond = fa.condition_differences(store)
    text = cell_text(tagged(executed[0], "fig16-table"))
    assert "Weyrich Fig. 16" in text and "0.768" in text and "0.537" in text
    assert f"{cca.correlations[0]:.4f}" in text and f"{cca.direct_correlations[0]:.4f}" in text
    text = cell_text(tagged(executed[0], "table1"))
    assert "paper 'Var.'" in text and "0.1727" in text and "0.5508" in text
    assert f"{tr.table.loc['R', ('cheek', 'std')]:.4f}" in text and tr.max_subject in text
    text = cell_text(tagged(executed[0], "fig15-table"))
    assert "Weyrich §7" in text and "[1, 3, 8, 9, 10]" in text
    text = cell_text(tagged(executed[0], "conditions-table"))
    a, b, d = cond.most_different_pair()
    assert f"most different pair: {a} / {b} ({d:.1f} pooled within-region sd)" in text
    text = cell_text(tagged(executed[0], "posterior-table"))
    assert "stored fit" in text and "converged" in text and "False" not in text
