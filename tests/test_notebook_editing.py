"""``notebooks/appearance_editing.ipynb`` runs at small size: freckles, skin type II → V, normal → lotion."""

import pathlib

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOK = pathlib.Path(__file__).resolve().parent.parent / "notebooks" / "appearance_editing.ipynb"

#: Cells (by tag) that must display a figure.
FIGURES = ("freckles-figure", "freckles-before-after", "skin-type", "skin-type-means", "lotion-histograms",
           "lotion-before-after")


def _text(cell):
    """All text a cell displayed (streams and text/plain results)."""
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
    return nb, workdir


def test_committed_notebook_is_valid_small_and_has_no_outputs():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(c.outputs == [] and c.execution_count is None for c in code)
    assert "SMALL = True" in _tagged(nb, "setup").source
    assert sum(c.cell_type == "markdown" for c in nb.cells) >= 6


def test_runs_without_errors_and_writes_nothing_to_its_directory(executed):
    nb, workdir = executed
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.execution_count is not None
            errors = [o for o in cell.outputs if o.output_type == "error"]
            assert not errors, f"{errors[0].ename}: {errors[0].evalue}"
    assert list(workdir.iterdir()) == []  # edits go to a temporary store


def test_every_figure_is_displayed(executed):
    nb, _ = executed
    for tag in FIGURES:
        assert any("image/png" in o.get("data", {}) for o in _tagged(nb, tag).outputs), tag


def test_edits_and_their_provenance_are_shown(executed):
    import facestats
    from facestats.acquire.population import default_population
    from facestats.edit import select_subjects

    nb, _ = executed
    freckled = [s.subject_id for s in default_population().subjects
                if s.features.get("freckles") and s.skin_type == 3 and s.condition == "normal"]
    text = _text(_tagged(nb, "freckles"))
    assert f"target (freckled, type III): {freckled[0]}" in text
    assert '"regions_edited": [\n  2,\n  6,\n  7\n ]' in text
    with facestats.open_store() as store:
        n_type_v = len(select_subjects(store, {"skin_type": 5}))
    assert f"skin type 5, target subset of {n_type_v} type V subjects" in _text(_tagged(nb, "skin-type"))
    assert "R_d(sigma_s', sigma_a) after" in _text(_tagged(nb, "skin-type-translucency"))
    assert "target: ('P150-lotion',)" in _text(_tagged(nb, "lotion"))
    table = _text(_tagged(nb, "provenance"))
    assert table.count("facestats.edit") == 3
    for name in ("transfer_texture", "change_skin_type", "transfer_brdf", "P150-normal"):
        assert name in table
