"""A batch of subjects written together: the checks before any byte is written, and the commit.

:meth:`facestats.io.store.Store.write_subjects` checks the whole batch with
:func:`prepare_batch` (schema, subject id, provenance, duplicates) so an
invalid subject is refused without touching the store, writes one generation
per subject, then commits them all at once with the index mutation of
:func:`batch_commit`.
"""

from __future__ import annotations

from facestats.errors import SchemaError, StoreError, ValidationError
from facestats.io.ids import check_subject_id
from facestats.io.index import make_entry
from facestats.io.schema import provenance, validate_subject
from facestats.io.summary import albedo_histogram, summarise_subject

__all__ = ["prepare_batch", "refuse_existing", "batch_commit"]


def prepare_batch(datasets) -> list:
    """Check the subjects of one write and summarise them for the index.

    Parameters
    ----------
    datasets : iterable of xarray.Dataset

    Returns
    -------
    list of tuple
        ``(subject id, dataset, index row, albedo histogram)`` per subject, in order.

    Raises
    ------
    ValidationError
        Not a Dataset, an invalid subject id, or an id twice in the batch.
    SchemaError
        A subject that breaks the schema or whose provenance is not a JSON object string.
    """
    import xarray as xr

    prepared = []
    seen = set()
    for k, ds in enumerate(datasets):
        if not isinstance(ds, xr.Dataset):
            raise ValidationError(f"datasets[{k}] must be an xarray.Dataset, got {type(ds).__name__}")
        validate_subject(ds)
        sid = check_subject_id(ds.attrs["subject_id"])
        try:
            provenance(ds)
        except (ValueError, TypeError):
            raise SchemaError(
                f"subject {sid!r}: attribute provenance must be a JSON object string, "
                f"got {str(ds.attrs['provenance'])[:60]!r}"
            ) from None
        if sid in seen:
            raise ValidationError(f"subject_id {sid!r} appears twice in one write")
        seen.add(sid)
        prepared.append((sid, ds, summarise_subject(ds), albedo_histogram(ds)))
    return prepared


def refuse_existing(index: dict, ids) -> None:
    """Raise :class:`StoreError` if any of ``ids`` is already in the index document.

    Parameters
    ----------
    index : dict
        The index document (:mod:`facestats.io.index`); only its ``subjects`` mapping is read.
    ids : iterable of str
        Subject ids about to be written.

    Raises
    ------
    StoreError
        Naming the ids (sorted) the index already holds.
    """
    clash = sorted(set(ids) & set(index["subjects"]))
    if clash:
        raise StoreError(
            f"subject(s) {clash} already exist in the store; pass overwrite=True (--overwrite) to replace them "
            "(edits should write a new subject id)"
        )


def batch_commit(prepared: list, written: list, overwrite: bool, superseded: list):
    """The index mutation committing a batch: point each subject at its new generation.

    Parameters
    ----------
    prepared : list
        From :func:`prepare_batch`.
    written : list
        ``(sid, gen, lock, when)`` per subject, aligned with ``prepared``.
    overwrite : bool
        Without it, subjects already in the index (at commit time) are refused.
    superseded : list
        The ``(sid, generation)`` replaced are appended to it by the mutation.

    Returns
    -------
    callable
        ``mutate(index)``: changes the index document in place and returns the ids written.
    """
    ids = {sid for sid, *_ in prepared}

    def mutate(index):
        if not overwrite:
            refuse_existing(index, ids)
        for (sid, gen, _, when), (_, _, row, hist) in zip(written, prepared):
            old = index["subjects"].get(sid)
            if old is not None:
                superseded.append((sid, old["generation"]))
            index["subjects"][sid] = make_entry(gen, when, row, hist)
        return [sid for sid, *_ in written]

    return mutate
