"""In-memory stand-in of the parameter store for the analysis tests and benchmark.

:class:`MemoryStore` implements the part of the store interface that
:mod:`facestats.analysis` uses (``subjects()``, ``subject(id, lazy=..., variables=...)``)
over subjects built by
``tests/factories.py``; :func:`make_population` builds a small population
with known structure.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from facestats.core.conventions import CONDITIONS
from facestats.io.summary import summarise_subject
from tests.factories import make_map_subject

__all__ = ["MemoryStore", "make_population"]

#: Skin-type frequencies of Weyrich Table 2 (types II-VI).
_TYPE_P = np.array([14, 67, 48, 15, 5]) / 149


class MemoryStore:
    """In-memory stand-in of the store interface used by :mod:`facestats.analysis`."""

    def __init__(self, datasets):
        self._ds = {str(ds.attrs["subject_id"]): ds for ds in datasets}
        self._index = pd.DataFrame.from_records([summarise_subject(ds) for ds in datasets]).set_index("subject_id")

    def subjects(self):
        return self._index.copy()

    def subject(self, subject_id, *, lazy=False, variables=None):
        return self._ds[subject_id]


def make_population(n=40, seed=0, size=24, conditions=True):
    """``n`` normal-condition subjects (skin types as Table 2) plus one person under the seven conditions.

    ρs rises with skin type and is higher for women (so CCA has something to
    find); σtr rises 4 % per skin type.
    """
    rng = np.random.default_rng(seed)
    datasets = []
    for i in range(n):
        st = int(rng.choice([2, 3, 4, 5, 6], p=_TYPE_P)) if i >= 5 else 2 + i  # every type present
        if st == 2 and rng.uniform() < 0.3:
            st = 1  # some type I subjects (grouped with II)
        gender = "F" if rng.uniform() < 0.3 else "M"
        age = int(rng.integers(18, 66))
        shift = 0.02 * (st - 3) + 0.015 * (gender == "F") + 0.004 * rng.standard_normal()
        ds = make_map_subject(
            f"S{i:03d}", size=size, skin_type=st, gender=gender, age=age, seed=seed * 1000 + i, rho_shift=shift
        )
        ds["site_sigma_tr"] = ds["site_sigma_tr"] * (1 + 0.04 * (st - 3))
        datasets.append(ds)
    if conditions:
        for j, cond in enumerate(CONDITIONS):
            datasets.append(
                make_map_subject(
                    f"C{j}",
                    size=size,
                    skin_type=3,
                    gender="M",
                    age=30,
                    condition=cond,
                    seed=seed * 1000 + 900 + j,
                    rho_shift=0.03 * j,
                    person_id="P-cond",
                )
            )
    return MemoryStore(datasets)
