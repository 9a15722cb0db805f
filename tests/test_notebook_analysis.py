"""``notebooks/population_analysis.ipynb`` runs on the default store and shows Fig. 14-16, Table 1, posteriors."""

import pathlib

import nbformat
import pytest
from nbclient import NotebookClient

import facestats
from facestats import analysis as fa

NOTEBOOK = pathlib.Path(__file__).resolve().parent.parent / "notebooks" / "population_analysis.ipynb"

#: Cells (by tag) that must display a figure.
FIGURES = ("fig15", "fig16", "fig14", "table1-figure", "conditions", "posterior", "population-posterior")


def _text(cell):
    """All text a cell displayed (streams and text/plain or text/html results)."""
    parts = []
    for o in cell.outputs:
        if o.output_type == "stream":
            parts.append(o.text)
        elif "data" in o:
            parts.append(o.data.get("text/plain", ""))
    return "\n".join(parts)


def _tagged(nb, tag):
    cells = [c for c in nb.cells if tag in c.metadata.get("tags", [])]
    assert len(cells) == 1, f"expected one cell tagged {tag!r}"
    return cells[0]


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    nb = nbformat.read(NOTEBOOK, as_version=4)
    workdir = tmp_path_factory.mktemp("notebook")
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(workdir)}}).execute()
    return nb


def test_committed_notebook_is_valid_and_has_no_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    assert nb.nbformat == 4
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(c.outputs == [] and c.execution_count is None for c in code)
    assert sum(c.cell_type == "markdown" for c in nb.cells) >= 7  # every figure is explained


def test_runs_without_errors(executed):
    for cell in executed.cells:
        if cell.cell_type == "code":
            assert cell.execution_count is not None
            errors = [o for o in cell.outputs if o.output_type == "error"]
            assert not errors, f"{errors[0].ename}: {errors[0].evalue}"


def test_every_figure_is_displayed(executed):
    for tag in FIGURES:
        cell = _tagged(executed, tag)
        assert any("image/png" in o.get("data", {}) for o in cell.outputs), tag


def test_tables_show_our_numbers_beside_the_paper(executed):
    with facestats.open_store() as store:
        cca = fa.brdf_cca(store, n_permutations=0)
        tr = fa.translucency_table(store)
    text = _text(_tagged(executed, "fig16-table"))
    assert "Weyrich Fig. 16" in text and "0.768" in text and "0.537" in text
    assert f"{cca.correlations[0]:.4f}" in text and f"{cca.direct_correlations[0]:.4f}" in text
    text = _text(_tagged(executed, "table1"))
    assert "paper 'Var.'" in text and "0.1727" in text and "0.5508" in text
    assert f"{tr.table.loc['R', ('cheek', 'std')]:.4f}" in text and tr.max_subject in text
    text = _text(_tagged(executed, "fig15-table"))
    assert "Weyrich §7" in text and "[1, 3, 8, 9, 10]" in text
    text = _text(_tagged(executed, "posterior-table"))
    assert "stored fit" in text and "converged" in text and "False" not in text
