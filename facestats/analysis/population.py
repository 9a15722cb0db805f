"""Which subjects and samples enter a population analysis (Weyrich et al. 2006 §7).

Weyrich et al. analyse 149 subjects measured once under normal conditions,
and one male subject measured under seven external conditions.  Every
statistic of :mod:`facestats.analysis` starts from the helpers here:

* :func:`population_index` reads the population index of a *source* (a
  parameter store, anything with a ``subjects()`` method returning the index,
  see :mod:`facestats.io.summary` for its columns, or that index as a
  :class:`pandas.DataFrame` indexed by ``subject_id``);
* :func:`select_population` picks the rows a population statistic uses (by
  default the subjects measured under normal conditions, so the repeated
  measurements of one person do not count seven times);
* :func:`region_samples` gathers the per-region BRDF samples of many
  subjects of a store (the 2 × n matrices of Fig. 15);
* :func:`default_subject` is the subject a single-subject analysis uses when
  none is named;
* :func:`index_columns` names the index columns of a specular model.
"""

from __future__ import annotations

import numpy as np

from facestats.core.conventions import EDIT_SOURCE, parse_condition
from facestats.core.validate import check_choice
from facestats.errors import StoreError, ValidationError

__all__ = [
    "LOBE_NAMES",
    "MODEL_NAMES",
    "index_columns",
    "population_index",
    "select_population",
    "region_samples",
    "default_subject",
]

#: model -> (scale column stem, lobe column stem, short lobe name used in results).
LOBE_NAMES = {"ts": ("ts_rho_s", "ts_m", "m"), "bp": ("bp_rho_s", "bp_exponent", "exponent")}
#: Full names of the specular models.
MODEL_NAMES = {"ts": "Torrance-Sparrow", "bp": "Blinn-Phong"}


def index_columns(model: str) -> tuple[str, str, str]:
    """Column stems of a specular model in the population index: (scale, lobe, lobe short name).

    Parameters
    ----------
    model : {"ts", "bp"}
        Torrance-Sparrow or Blinn-Phong.

    Returns
    -------
    tuple of str
        ``LOBE_NAMES[model]``, e.g. ``("ts_rho_s", "ts_m", "m")``.

    Raises
    ------
    ValidationError
        For another ``model``.
    """
    check_choice(model, "model", tuple(LOBE_NAMES))
    return LOBE_NAMES[model]


def population_index(source):
    """The population index (one row per subject, indexed by ``subject_id``) of a store or a DataFrame.

    Parameters
    ----------
    source : store or pandas.DataFrame
        A parameter store (``subjects()`` returns its index) or the index itself.

    Returns
    -------
    pandas.DataFrame

    Raises
    ------
    ValidationError
        If ``source`` is neither, or the index lacks age, gender, skin_type or condition.
    """
    import pandas as pd

    if isinstance(source, pd.DataFrame):
        frame = source
    elif callable(getattr(source, "subjects", None)):
        frame = source.subjects()
    else:
        raise ValidationError(
            f"source must be a parameter store (with a subjects() method) or its population index DataFrame, "
            f"got {type(source).__name__}"
        )
    if "subject_id" in frame.columns and frame.index.name != "subject_id":
        frame = frame.set_index("subject_id")
    if len(frame) == 0 and len(frame.columns) == 0:
        raise ValidationError("the store has no subjects (its population index is empty): nothing to analyse")
    missing = [c for c in ("age", "gender", "skin_type", "condition") if c not in frame.columns]
    if missing:
        raise ValidationError(
            f"the population index must have columns age, gender, skin_type, condition; missing {missing}"
        )
    return frame


def select_population(source, subjects=None, conditions=("normal",)):
    """Rows of the population index that enter a population statistic.

    Parameters
    ----------
    source : store or pandas.DataFrame
        A parameter store (``subjects()`` returns its index) or the index itself.
    subjects : sequence of str, optional
        Subject ids to keep (default: every measured subject; subjects written by an edit, index ``source``
        ``facestats.edit``, enter only when named here).  Unknown ids raise.
    conditions : sequence of str or None, optional
        Measurement conditions to keep, default ``("normal",)`` as in Weyrich
        §7, where the population statistics use one normal measurement per
        subject.  ``None`` keeps every condition.

    Returns
    -------
    pandas.DataFrame
        The selected rows, indexed by ``subject_id``.

    Raises
    ------
    ValidationError
        If an id is unknown or nothing is left.
    """
    frame = population_index(source)
    n_edited = 0
    if subjects is not None:
        ids = [str(s) for s in ([subjects] if isinstance(subjects, str) else subjects)]
        unknown = [s for s in ids if s not in frame.index]
        if unknown:
            raise ValidationError(f"subjects must be ids of the store, got unknown id(s) {unknown[:5]}")
        frame = frame.loc[ids]
    elif "source" in frame.columns:  # edited subjects are not measurements: only ids asked for by name enter
        edited = frame["source"] == EDIT_SOURCE
        n_edited = int(edited.sum())
        frame = frame[~edited]
    before = len(frame)
    if conditions is not None:
        conds = [parse_condition(c) for c in ([conditions] if isinstance(conditions, str) else conditions)]
        frame = frame[frame["condition"].isin(conds)]
    if len(frame) == 0:
        if before:
            who = "the subjects named" if subjects is not None else "the store's measured subjects"
            what = f"none of {who} was measured under condition(s) {', '.join(map(str, conds))}"
        else:
            what = "the store holds no measured subject"
        if n_edited:
            what += f" ({n_edited} edited subject(s) left out: an edit is no measurement; name them to analyse them)"
        raise ValidationError(f"no subject to analyse: {what}")
    return frame


def region_samples(store, model="ts", subjects=None):
    """Per-region BRDF samples of many subjects of a store as a long :class:`pandas.DataFrame`.

    The samples of one subject are those of
    :func:`facestats.io.summary.region_samples` (unflagged texels of map
    subjects, stored samples of imported subjects); each subject is opened
    lazily with only the variables the samples come from loaded (and, in a
    store, checksum-verified: ``store.subject(id, lazy=True, variables=...)``).

    Parameters
    ----------
    store : parameter store
        Anything with ``subjects()`` (the population index, rows sorted by
        id, with a ``kind`` column) and ``subject(id, lazy=..., variables=...)``.
    model : {"ts", "bp"}
        Torrance-Sparrow (ρs, m) or Blinn-Phong (ρs, exponent n).
    subjects : str or sequence of str, optional
        Subject ids, in the order wanted (default: every subject, by id).

    Returns
    -------
    pandas.DataFrame
        Columns ``subject_id, region, rho_s, lobe`` (``lobe`` is m for
        ``model="ts"``, the Blinn-Phong exponent for ``"bp"``), subjects in
        order, regions in Fig. 15 order within a subject.
    """
    import pandas as pd

    # local import: keeps facestats.io (22 modules) out of this module's import
    from facestats.io.summary import MODEL_PARAMS, region_sample_variables
    from facestats.io.summary import region_samples as subject_region_samples

    check_choice(model, "model", MODEL_PARAMS)
    if subjects is None:
        ids = [str(s) for s in store.subjects().index]
    else:
        ids = [str(s) for s in ([subjects] if isinstance(subjects, str) else subjects)]
    table = store.subjects()
    kind_of = dict(zip(table.index.astype(str), table["kind"].tolist())) if "kind" in table else {}
    sid_parts, reg_parts, rho_parts, lobe_parts = [], [], [], []
    for sid in ids:
        needed = region_sample_variables(kind_of.get(sid, "maps"), model)
        for r, (rho, lobe) in subject_region_samples(store.subject(sid, lazy=True, variables=needed), model).items():
            sid_parts.append(np.full(rho.size, sid, dtype=object))
            reg_parts.append(np.full(rho.size, r, dtype=np.int64))
            rho_parts.append(rho)
            lobe_parts.append(lobe)

    def cat(parts, dtype):
        return np.concatenate(parts) if parts else np.empty(0, dtype=dtype)

    return pd.DataFrame(
        {
            "subject_id": cat(sid_parts, object),
            "region": cat(reg_parts, np.int64),
            "rho_s": cat(rho_parts, np.float64),
            "lobe": cat(lobe_parts, np.float64),
        }
    )


def default_subject(store) -> str:
    """The first subject (by id) measured under normal conditions, else the first subject.

    Parameters
    ----------
    store : parameter store
        Anything with ``subjects()`` (the population index, rows sorted by id, with a ``condition`` column) and
        ``label``.

    Returns
    -------
    str
        The subject id.

    Raises
    ------
    StoreError
        If the store holds no subject.
    """
    frame = store.subjects()
    if len(frame) == 0:
        raise StoreError(f"store {store.label} holds no subject")
    normal = frame.index[frame["condition"] == "normal"]
    return str(normal[0] if len(normal) else frame.index[0])
