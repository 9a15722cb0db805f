"""``notebooks/appearance_editing.ipynb`` runs at small size: freckles, skin type II → V, normal → lotion."""

import re

import pytest

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

NOTEBOOK = NOTEBOOKS / "appearance_editing.ipynb"

#: Cells (by tag) that must display a figure.
FIGURES = (
    "freckles-figure",
    "freckles-before-after",
    "skin-type",
    "skin-type-means",
    "lotion-histograms",
    "lotion-before-after",
)


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    return execute_once(NOTEBOOK, tmp_path_factory)


def test_committed_notebook_is_valid_small_and_has_no_outputs():
    nb = read_committed(NOTEBOOK)
    assert "SMALL = True" in tagged(nb, "setup").source
    assert sum(c.cell_type == "markdown" for c in nb.cells) >= 6


def test_runs_without_errors_and_writes_nothing_to_its_directory(executed):
    nb, workdir = executed
    assert_no_errors(nb)
    assert_nothing_left(workdir)  # edits go to a temporary store


def test_every_figure_is_displayed(executed):
    nb, _ = executed
    for tag in FIGURES:
        assert shows_figure(tagged(nb, tag)), tag


def test_edits_and_their_provenance_are_shown(executed):
    import facestats
    from facestats.acquire.synthetic.population import default_population
    from facestats.edit import select_subjects

    nb, _ = executed
    freckled = [
        s.subject_id
        for s in default_population().subjects
        if s.features.get("freckles") and s.skin_type == 3 and s.condition == "normal"
    ]
    text = cell_text(tagged(nb, "freckles"))
    assert f"target (freckled, type III): {freckled[0]}" in text
    assert '"regions_edited": [\n  2,\n  6,\n  7\n ]' in text
    # 48² regions: the distances stay near their sampling floor (README, *Texture transfer needs coefficients*)
    start, end, floor = (float(x) for x in re.search(r"distance (\S+) -> (\S+); sampling floor (\S+)", text).groups())
    assert 0.3 < floor < end < start
    with facestats.open_store() as store:
        n_type_v = len(select_subjects(store, {"skin_type": 5}))
    assert f"skin type 5, target subset of {n_type_v} type V subjects" in cell_text(tagged(nb, "skin-type"))
    assert "R_d(sigma_s', sigma_a) after" in cell_text(tagged(nb, "skin-type-translucency"))
    assert "target: ('S008-lotion',)" in cell_text(tagged(nb, "lotion"))
    table = cell_text(tagged(nb, "provenance"))
    assert table.count("facestats.edit") == 3
    for name in ("transfer_texture", "change_skin_type", "transfer_brdf", "S008"):
        assert name in table
