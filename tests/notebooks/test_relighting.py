"""``notebooks/relighting.ipynb`` runs at small size: a store subject relit under three probes and rotated,
compression error against ratio, separation maps, a novel view and shadow maps."""

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

NOTEBOOK = NOTEBOOKS / "relighting.ipynb"
FIGURES = ("stage", "relit", "compression", "separation", "novel")


@pytest.fixture(scope="module")
def executed(tmp_path_factory):
    env = {"FACESTATS_PROBES": TEST_DATA / "polyhaven-probes"}  # the kernel runs in the temporary workdir
    return execute_once(NOTEBOOK, tmp_path_factory, env=env)


def test_committed_notebook_is_valid_small_and_has_no_outputs():
    nb = read_committed(NOTEBOOK)
    assert "SMALL = True" in tagged(nb, "setup").source
    assert sum(c.cell_type == "markdown" for c in nb.cells) >= 6


def test_runs_without_errors_shows_every_figure_and_writes_nothing(executed):
    nb, workdir = executed
    assert_no_errors(nb)
    assert_nothing_left(workdir)
    for tag in FIGURES:
        assert shows_figure(tagged(nb, tag)), tag


def test_the_numbers_it_prints_hold(executed):
    nb, _ = executed
    diff = float(re.search(r"max relative difference ([0-9.e+-]+)", cell_text(tagged(nb, "relit"))).group(1))
    assert diff <= 1e-3  # relit field = direct render
    assert len(re.findall(r"^ratio ", cell_text(tagged(nb, "compression")), re.M)) >= 3
    median = float(re.search(r"median ([0-9.]+)°", cell_text(tagged(nb, "separation"))).group(1))
    assert median < 10
    agree = [float(a) for a in re.findall(r"agreement ([0-9.]+)", cell_text(tagged(nb, "shadows")))]
    assert agree[1] >= 0.99 and agree[1] > agree[0]
