"""``notebooks/export_and_web.ipynb`` runs at small size: EXR set, glTF, Mitsuba scene, validation render, web JSON."""

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

NOTEBOOK = NOTEBOOKS / "export_and_web.ipynb"


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    return execute_once(NOTEBOOK, tmp_path_factory)


def test_committed_notebook_is_small_and_has_no_outputs():
    nb = read_committed(NOTEBOOK)
    assert "SMALL = True" in tagged(nb, "setup").source


def test_runs_and_shows_exports_render_and_web_numbers(executed):
    nb, workdir = executed
    assert_no_errors(nb)
    assert_nothing_left(workdir)
    assert "ict-48" in cell_text(tagged(nb, "exr"))
    assert "vertices," in cell_text(tagged(nb, "gltf"))
    assert shows_figure(tagged(nb, "validation"))
    rmse = float(cell_text(tagged(nb, "validation")).split("relative RMSE ")[1].split(" %")[0])
    assert rmse < 5
    assert "web JSON equals the query API: True" in cell_text(tagged(nb, "web"))
    pytest.importorskip("mitsuba")
    assert shows_figure(tagged(nb, "mitsuba"))
