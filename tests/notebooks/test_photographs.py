"""``notebooks/photographs_in.ipynb`` runs at small size: response, LED calibration, photographs → subject."""

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

NOTEBOOK = NOTEBOOKS / "photographs_in.ipynb"
FIGURES = ("response-figure", "real-bracket-figure", "leds-figure", "frame-figure", "albedo-figure")


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    return execute_once(NOTEBOOK, tmp_path_factory)


def test_committed_notebook_is_valid_small_and_has_no_outputs():
    nb = read_committed(NOTEBOOK)
    assert "SMALL = True" in tagged(nb, "setup").source
    assert sum(c.cell_type == "markdown" for c in nb.cells) >= 5


@pytest.mark.slow
def test_runs_shows_its_figures_and_numbers(executed):
    nb, workdir = executed
    assert_no_errors(nb)
    assert_nothing_left(workdir)  # everything went to a temporary directory, removed at the end
    for tag in FIGURES:
        assert shows_figure(tagged(nb, tag)), tag
    text = cell_text(tagged(nb, "response"))
    g_err = float(text.split("codes 20-250: ")[1].split(" ")[0])
    assert g_err < 0.03
    real = cell_text(tagged(nb, "real-bracket"))
    medians = [float(line.split(": ")[1].split("%")[0]) for line in real.splitlines() if " s -> " in line]
    assert len(medians) == 2 and max(medians) < 5  # the real bracket's exposures agree (3.3 %, 3.6 %)
    leds = cell_text(tagged(nb, "leds"))
    assert "camera gains relative to camera" in leds
    assert float(leds.split("largest intensity error: ")[1].split("%")[0]) < 1.0  # the 1 %
    assert "'format': 'facestats.capture-folder/1'" in cell_text(tagged(nb, "write"))
    ingest = cell_text(tagged(nb, "ingest"))
    assert "ingested PH001" in ingest and "frames flagged for head motion" in ingest
