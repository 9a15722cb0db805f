"""CCA of the region BRDF means against skin type, gender and age (Weyrich et al. 2006 §7, Fig. 16).

Weyrich et al. store, per subject, the region means of the Torrance-Sparrow
parameters (10 regions × (ρs, m)) with gender [0 = M, 1 = F], age and skin
type [II-VI] in a 23 × 149 matrix, and run CCA between the BRDF block and the
experimental variables.  :func:`brdf_cca` builds these blocks from the
population index and runs :func:`facestats.analysis.cca.cca` (the method and
its tests are described there).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from facestats.analysis.cca import cca
from facestats.analysis.population import index_columns, select_population
from facestats.core.conventions import REGION_IDS
from facestats.errors import ValidationError

__all__ = ["brdf_cca", "EXPERIMENTAL_VARIABLES", "CODING"]

#: Experimental variables of Weyrich Fig. 16 (population index columns; :func:`brdf_cca` codes them).
EXPERIMENTAL_VARIABLES = ("skin_type", "gender", "age")
#: How :func:`brdf_cca` codes the experimental variables (recorded in its result's ``coding``).
CODING = {
    "skin_type": "Fitzpatrick number, types I and II grouped as 2 (labelled I-II), 2-6",
    "gender": "0 = M, 1 = F",
    "age": "years",
}


def brdf_cca(
    source,
    model="ts",
    variables=EXPERIMENTAL_VARIABLES,
    subjects=None,
    conditions=("normal",),
    regularization=0.0,
    n_permutations=999,
    seed=0,
):
    """CCA of the per-region BRDF means against skin type, gender and age (Weyrich et al. 2006 §7, Fig. 16).

    Builds the subjects × (20 + 3) matrix of the paper from the population
    index: X = region means (``{model}_rho_s_mean_r{r}``, lobe mean) of the 10
    regions, Y = the experimental variables coded as in the paper: skin type
    as its Fitzpatrick number with I grouped into II (the paper's "II-VI"),
    gender 0 = M / 1 = F, age in years.  Regions without samples in any
    subject are dropped; subjects with a missing region mean are left out
    (listed in ``dropped``).  Then :func:`cca`.

    Parameters
    ----------
    source : store or pandas.DataFrame
        Parameter store or its population index.
    model : {"ts", "bp"}
        Specular model (the paper uses Torrance-Sparrow).
    variables : sequence of str
        Experimental variables among ``skin_type``, ``gender``, ``age``.
    subjects, conditions
        Population selection, see :func:`facestats.analysis.population.select_population`.
    regularization, n_permutations, seed
        As :func:`cca`.

    Returns
    -------
    CCAResult
        ``index`` holds subject ids; ``y_data`` the coded experimental variables.
    """
    import pandas as pd

    rho_stem, lobe_stem, lobe_name = index_columns(model)
    variables = tuple(variables)
    if not variables:
        raise ValidationError(f"variables must name one or more of {EXPERIMENTAL_VARIABLES}, got none")
    for v in variables:
        if v not in EXPERIMENTAL_VARIABLES:
            raise ValidationError(f"variables must be among {EXPERIMENTAL_VARIABLES}, got {v!r}")
    frame = select_population(source, subjects, conditions)
    cols, names = [], []
    for r in REGION_IDS:
        for stem, short in ((rho_stem, "rho_s"), (lobe_stem, lobe_name)):
            c = f"{stem}_mean_r{r}"
            if c in frame.columns and frame[c].notna().any():
                cols.append(c)
                names.append(f"{short}_r{r}")
    if not cols:
        raise ValidationError(f"the population index has no {model} region means")
    X = frame[cols].astype(float).set_axis(names, axis=1)
    coded = {
        "skin_type": np.maximum(frame["skin_type"].astype(int), 2),
        "gender": (frame["gender"].astype(str) == "F").astype(float),
        "age": frame["age"].astype(float),
    }
    Y = pd.DataFrame({v: coded[v] for v in variables}, index=frame.index).astype(float)
    res = cca(X, Y, regularization=regularization, n_permutations=n_permutations, seed=seed, missing="drop")
    return replace(res, model=model, coding={v: CODING[v] for v in variables})
