"""Execute a notebook of ``notebooks/`` and read what its cells displayed (shared by the notebook tests)."""

import pathlib

import nbformat
from nbclient import NotebookClient

NOTEBOOKS = pathlib.Path(__file__).resolve().parent.parent / "notebooks"


def read_committed(path):
    """The notebook as committed, asserted to be valid nbformat 4 with code cells and no outputs."""
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(c.outputs == [] and c.execution_count is None for c in code)
    return nb


def execute(path, workdir):
    """The notebook at ``path`` after running every cell with ``workdir`` as the working directory."""
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(workdir)}}).execute()
    return nb


def cell_text(cell):
    """All text a cell displayed (streams and text/plain results)."""
    parts = []
    for o in cell.outputs:
        if o.output_type == "stream":
            parts.append(o.text)
        elif "data" in o:
            parts.append(o.data.get("text/plain", ""))
    return "\n".join(parts)


def tagged(nb, tag):
    """The one cell carrying ``tag`` in its metadata."""
    cells = [c for c in nb.cells if tag in c.metadata.get("tags", [])]
    assert len(cells) == 1, f"expected one cell tagged {tag!r}"
    return cells[0]


def assert_no_errors(nb):
    """Assert that every code cell of an executed notebook ran and none displayed an error."""
    for cell in nb.cells:
        if cell.cell_type == "code":
            assert cell.execution_count is not None
            errors = [o for o in cell.outputs if o.output_type == "error"]
            assert not errors, f"{errors[0].ename}: {errors[0].evalue}"


def shows_figure(cell):
    """True if the cell displayed a PNG image."""
    return any("image/png" in o.get("data", {}) for o in cell.outputs)
