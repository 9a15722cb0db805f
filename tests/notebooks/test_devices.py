"""``notebooks/device_capture.ipynb`` runs at small size: plan, protocol, clean and faulty sessions, resume, sensor."""

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

NOTEBOOK = NOTEBOOKS / "device_capture.ipynb"
FIGURES = ("link-figure", "sheet-figure", "bracket-figure")


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    return execute_once(NOTEBOOK, tmp_path_factory)


def test_committed_notebook_is_valid_small_and_has_no_outputs():
    nb = read_committed(NOTEBOOK)
    assert "SMALL = True" in tagged(nb, "setup").source
    assert sum(c.cell_type == "markdown" for c in nb.cells) >= 8


@pytest.mark.slow
def test_runs_shows_its_figures_and_the_sessions_agree(executed):
    nb, workdir = executed
    assert_no_errors(nb)
    assert_nothing_left(workdir)  # everything went to a temporary directory, removed at the end
    for tag in FIGURES:
        assert shows_figure(tagged(nb, tag)), tag
    assert "estimated duration on the hardware" in cell_text(tagged(nb, "plan"))
    assert "facestats-dome emulator" in cell_text(tagged(nb, "protocol"))
    assert "complete: 60/60 steps" in cell_text(tagged(nb, "clean"))
    faults = cell_text(tagged(nb, "faults"))
    assert "identical to the clean session: True" in faults and "reboots 1" in faults and "reconnects 1" in faults
    resume = cell_text(tagged(nb, "resume"))
    assert "manifest written: False" in resume and "identical to the clean session: True" in resume
    sensor = cell_text(tagged(nb, "sensor"))
    z = float(sensor.split("|z| ≤ ")[1].split(",")[0])
    assert "complete: 69/69 steps" in sensor and z < 5
    assert "facestats ingest" in cell_text(tagged(nb, "folder"))
