"""Write facestats/model/skin_colour_tables.py: the colour-science tables of
:func:`facestats.model.skin_colour.skin_albedo`.

Usage::

    python scripts/make_skin_colour_tables.py && ruff format facestats/model/skin_colour_tables.py

(the formatter gives the committed layout; the script alone writes the same values in ``pprint``'s). Rerun it
when colour-science's datasets change (``tests/acquire/test_population.py`` compares the shipped tables with
colour-science's, bit for bit, and fails until then).
"""

import pathlib
import pprint

from facestats.model.skin_colour import colour_science_tables

out = pathlib.Path(__file__).resolve().parent.parent / "facestats" / "model" / "skin_colour_tables.py"
tables = colour_science_tables()
out.write_text(
    '"""colour-science\'s tables of :func:`facestats.model.skin_colour.skin_albedo` (colour-science '
    f'{tables["colour_science"]}).\n\nWritten by ``scripts/make_skin_colour_tables.py``; do not edit.\n"""\n\n'
    f"TABLES = {pprint.pformat(tables, width=116, sort_dicts=False)}\n"
)
print(f"wrote {out}")
