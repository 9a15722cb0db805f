"""One edit of one store subject, from reading the source to writing the new subject (:class:`EditSession`).

Every store-level edit (:mod:`facestats.edit.subjects`) follows the same steps,
which :class:`EditSession` holds once:

1. check the stores: ``store`` holds the source and the targets, the new
   subject goes to ``out_store`` (default ``store``), which must be writable
   (the embedded default store is read-only: pass
   ``open_store(PATH, mode="a")``);
2. :meth:`~EditSession.open` the source, a *map* subject (fitted maps; a sample
   subject imported from a statistics file has no maps to edit), and make the
   working copy :attr:`~EditSession.dataset` (all variables and attributes);
3. :meth:`~EditSession.assign_id`: the new id is ``new_id`` or
   ``<source id>.<edit>-<digest>``, the digest being the first 8 hex digits of
   the SHA-256 of the edit record (so the same edit of the same subject gets
   the same id, and is refused the second time unless ``overwrite=True``).  The
   source is never modified: an edit refuses to write the source's own id into
   the source's store, even with ``overwrite=True``;
4. the edit replaces variables of the working copy (:meth:`~EditSession.set`);
5. :meth:`~EditSession.write` sets, in ``attrs``, ``subject_id``, any changed
   metadata (e.g. ``skin_type``) and ``provenance`` (JSON): ``source`` =
   :data:`EDIT_SOURCE`, ``source_subject``, ``source_store``,
   ``source_provenance`` (the source's own provenance), ``edit`` (``name``,
   ``parameters``, ``target``, ``regions_edited``) and ``software``; writes the
   subject with :meth:`facestats.io.Store.write_subject` and returns a
   :class:`~facestats.edit.result.SubjectEdit`.  With ``commit=False`` it
   writes nothing and returns a :class:`PendingEdit`: the complete result, whose
   :meth:`PendingEdit.commit` writes it later (``facestats edit`` saves the
   before/after images first, so that a failure there leaves the store as it was).
"""

from __future__ import annotations

import hashlib
import json
import os
import threading

import numpy as np

from facestats.core.conventions import EDIT_SOURCE
from facestats.core.version import __version__
from facestats.edit.masks import parse_regions, present_regions
from facestats.edit.result import SubjectEdit
from facestats.errors import SchemaError, StoreError, ValidationError

__all__ = [
    "EDIT_SOURCE",
    "ON_DISK",
    "EditSession",
    "PendingEdit",
    "check_store",
    "read_map_subject",
    "replace_values",
]


def check_store(store, name):
    """Raise unless ``store`` is a :class:`facestats.io.Store`.

    Parameters
    ----------
    store : object
    name : str
        Name of the argument in error messages.

    Returns
    -------
    facestats.io.Store
    """
    # local import: keeps facestats.io (22 modules) out of this module's import
    from facestats.io.store import Store

    if not isinstance(store, Store):
        raise ValidationError(
            f"{name} must be a facestats Store (facestats.open_store(...)), got {type(store).__name__}"
        )
    return store


#: Variables no edit reads or changes: :func:`read_map_subject` leaves them on disk, and the new subject receives
#: them band by band from the source's files (a 2048² subject's 16-camera micro-normal map is 805 MB).
ON_DISK = ("micro_normal",)


def read_map_subject(store, subject):
    """A map subject (fitted maps) of a store and its region map.

    Every variable is loaded, CRC-verified and validated against the schema, as
    :meth:`facestats.io.Store.subject` does, except those of :data:`ON_DISK`: they
    stay on disk as dask arrays of one stored band of rows each (``on_disk``),
    each band CRC-verified when it is read, the values validated when the new
    subject is written.  Reading them needs the source's generation: if a writer
    replaces or deletes the source first, the edit fails with a
    :class:`~facestats.errors.StoreError` saying so and writes nothing.

    Parameters
    ----------
    store : facestats.io.Store
    subject : str
        Subject id.

    Returns
    -------
    dataset : xarray.Dataset
    region : numpy.ndarray of int
        The region map (0 outside the face, 1-10 the regions of Weyrich Fig. 15).
    """
    # local import: keeps facestats.io (22 modules) out of this module's import
    from facestats.io.schema import subject_kind

    sid = str(subject)
    ds = store.subject(sid, on_disk=ON_DISK)
    if subject_kind(ds) != "maps":
        raise ValidationError(
            f"subject must be a map subject (fitted maps), got {sid!r}, a sample subject imported from a "
            "statistics file: it has no maps to edit"
        )
    return ds, np.asarray(ds["region"].values)


def replace_values(ds, name, values):
    """Replace the values of variable ``name`` of ``ds`` in place, keeping its dims, attrs and dtype.

    Parameters
    ----------
    ds : xarray.Dataset
    name : str
    values : array_like
        New values, the variable's shape (cast to its dtype).
    """
    ds[name] = ds[name].copy(data=np.asarray(values).astype(ds[name].dtype, copy=False))


def _writable(out, name="out_store"):
    if out.read_only:
        what = "the embedded default store" if out.label == "default" else f"store {out.label}"
        raise StoreError(
            f"{what} is read-only and an edit writes a new subject: pass {name}=open_store(PATH, mode='a') "
            "(a directory store, created if missing; CLI: --out-store PATH)"
        )
    return out


def _same_store(a, b) -> bool:
    return a is b or os.path.realpath(a.path) == os.path.realpath(b.path)


def _record_digest(record) -> str:
    """First 8 hex digits of the SHA-256 of a JSON record (keys sorted)."""
    text = json.dumps(record, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:8]


class EditSession:
    """One edit of one subject of ``store``, written as a new subject of ``out_store``.

    Parameters
    ----------
    store : facestats.io.Store
        Store holding the source subject (and the targets).
    out_store : facestats.io.Store, optional
        Where the new subject goes (default ``store``); must be writable.  Both
        are checked here, before any work.

    Attributes
    ----------
    store, out : facestats.io.Store
        Source and output stores.
    source : xarray.Dataset
        The source subject as read (set by :meth:`open`; never modified).
    source_id : str
        Its id.
    region : numpy.ndarray of int
        Its region map.
    present : list of int
        The regions of its region map.
    dataset : xarray.Dataset
        The working copy the edit changes: a shallow copy of :attr:`source`, whose variables the edit replaces
        whole (:func:`replace_values`); unedited variables share their arrays with :attr:`source`, so write
        new arrays into it, never into ``dataset[v].values``.
    new_id : str
        Id of the new subject (set by :meth:`assign_id`).

    Examples
    --------
    The steps of an edit (:func:`facestats.edit.transfer_colour_subject` in short)::

        session = EditSession(store, out_store).open("S012")
        record = {"name": "transfer_colour", "parameters": {...}, "target": {...}}
        session.assign_id("colour", record, new_id=None, overwrite=False)
        session.set("albedo", new_albedo)
        edit = session.write(record, variables=["albedo"], targets=["S007"])
    """

    def __init__(self, store, out_store=None):
        self.store = check_store(store, "store")
        self.out = _writable(check_store(store if out_store is None else out_store, "out_store"))
        self.source = self.source_id = self.region = self.present = self.dataset = None
        self.new_id, self.overwrite = None, False

    def open(self, subject) -> EditSession:
        """Read the source (a map subject of :attr:`store`) and make the working copy.

        Parameters
        ----------
        subject : str
            Id of the subject to edit.

        Returns
        -------
        EditSession
            The session itself.
        """
        self.source, self.region = read_map_subject(self.store, subject)
        self.source_id = str(subject)
        self.present = present_regions(self.region)
        # A shallow copy: every edit replaces whole variables and attributes (replace_values, assignment), never
        # the source's arrays in place; a deep one held a second copy of every map (about 1 GB of a 2048²
        # subject with its micro-normals; the speed red team).  tests/edit/test_subjects.py checks the source.
        self.dataset = self.source.copy(deep=False)
        return self

    def regions(self, regions, name="regions"):
        """Regions of the source by number or name, checked present.

        Parameters
        ----------
        regions : None, int, str or iterable of int or str
            Regions 1-10 or names (:func:`facestats.edit.masks.parse_regions`).
        name : str
            Name of the argument in error messages.

        Returns
        -------
        list of int or None
            Sorted region numbers; None for None (the whole face).
        """
        return parse_regions(regions, self.present, name)

    def assign_id(self, tag, record, *, new_id=None, overwrite=False) -> str:
        """Choose and check the id of the new subject.

        Parameters
        ----------
        tag : str
            Short name of the edit in a derived id, e.g. ``"brdf"``, ``"skin-V"``.
        record : dict
            The edit record as far as known (``name``, ``parameters``,
            ``target``); its digest names a derived id.
        new_id : str, optional
            Explicit id; default ``<source id>.<tag>-<digest>`` (the source id
            shortened so the id has at most 64 characters).
        overwrite : bool
            Replace an existing subject of :attr:`out` written by an earlier edit.  An edit never
            replaces its source, its target subjects or any measured subject.

        Returns
        -------
        str
        """
        # local import: keeps facestats.io (22 modules) out of this module's import
        from facestats.io.ids import MAX_SUBJECT_ID_LENGTH, check_subject_id

        sid = self.source_id
        if new_id is None:
            suffix = f".{tag}-{_record_digest({'source_subject': sid, 'edit': record})}"
            new_id = sid[: MAX_SUBJECT_ID_LENGTH - len(suffix)] + suffix
        new_id = check_subject_id(new_id)
        if _same_store(self.store, self.out) and new_id == sid:
            raise ValidationError(
                f"new_id must differ from the source subject {sid!r}: an edit never overwrites its source"
            )
        target = record.get("target") or {}
        if new_id == target.get("subject") or new_id in (target.get("subjects") or ()):
            raise ValidationError(f"new_id must differ from the edit's target subjects, got {new_id!r}")
        if new_id in self.out:
            if not overwrite:
                raise StoreError(
                    f"subject {new_id!r} already exists in store {self.out.label}; pass overwrite=True (--overwrite) "
                    "to replace it or choose another new_id (--id)"
                )
            if self.out.index_entries()[new_id]["row"].get("source") != EDIT_SOURCE:
                raise StoreError(
                    f"subject {new_id!r} of store {self.out.label} is a measured subject, not an earlier edit: an edit "
                    "never replaces one, even with overwrite=True (--overwrite); choose another new_id (--id)"
                )
        self.new_id, self.overwrite = new_id, overwrite
        return new_id

    def set(self, name, values) -> None:
        """Replace the values of a variable of the working copy (:func:`replace_values`).

        Parameters
        ----------
        name : str
            Variable of :attr:`dataset`.
        values : array_like
            New values, the variable's shape (cast to its dtype).
        """
        replace_values(self.dataset, name, values)

    def write(
        self, record, *, variables, targets=(), target_means=None, texture=None, attrs=None, commit=True
    ) -> SubjectEdit | PendingEdit:
        """Set id, attributes and provenance of the working copy, write it to :attr:`out` and return the result.

        Parameters
        ----------
        record : dict
            The complete edit record (``name``, ``parameters``, ``target``,
            ``regions_edited``, …), stored as provenance ``edit``.
        variables : iterable of str
            Variables the edit changed.
        targets : iterable of str
            Subjects whose statistics formed the target.
        target_means : dict, optional
            Means of the target samples (:attr:`SubjectEdit.target_means`).
        texture : facestats.edit.TextureTransfer, optional
            Convergence report of a texture transfer.
        attrs : dict, optional
            Attributes that change with the edit (e.g. ``skin_type``).
        commit : bool
            Write the new subject now (default); False: write nothing and return a :class:`PendingEdit`, whose
            :meth:`~PendingEdit.commit` writes it.

        Returns
        -------
        SubjectEdit or PendingEdit
            The result, written; with ``commit=False`` the result to write.
        """
        # local import: keeps facestats.io (22 modules) out of this module's import
        from facestats.io.schema import STANDARD_ERRORS, provenance, set_provenance, set_variable_attrs

        ds = self.dataset
        # An edited parameter is no measurement: its standard-error map would describe the source.
        stale = [STANDARD_ERRORS[v] for v in variables if STANDARD_ERRORS.get(v) in ds.data_vars]
        if stale:
            ds = self.dataset = ds.drop_vars(stale)
        ds.attrs["subject_id"] = self.new_id
        ds.attrs.update(attrs or {})
        ds.attrs["provenance"] = "{}"
        set_provenance(
            ds,
            source=EDIT_SOURCE,
            source_subject=str(self.source.attrs["subject_id"]),
            source_store=self.store.label,
            source_provenance=provenance(self.source),
            edit=record,
            software=f"facestats {__version__}",
        )
        set_variable_attrs(ds)
        edit = SubjectEdit(
            subject_id=self.new_id,
            dataset=ds,
            source=self.source,
            edit=record,
            store=self.out.label,
            variables=tuple(variables),
            targets=tuple(targets),
            target_means=target_means or {},
            texture=texture,
        )
        pending = PendingEdit(self.out, edit, overwrite=self.overwrite)
        return pending.commit() if commit else pending


class PendingEdit:
    """An edit made but not yet written: what a store-level edit returns with ``commit=False``.

    :attr:`edit` is the complete result (the new subject with its id, attributes and provenance, exactly as it
    will be written), so a caller can first do what must succeed before the store changes, then write it with
    :meth:`commit`.  Until then the output store is untouched; a pending edit never committed leaves nothing
    behind.  ``facestats edit`` saves the before/after images under temporary names, commits, then renames
    them into place, so that a failed command leaves neither a subject nor images.  Commit while the stores are
    open: the variables left on disk (:data:`ON_DISK`) are read from the source's files as the subject is
    written, and :meth:`facestats.io.Store.write_subject` checks again that the id is free (unless
    ``overwrite``), so a subject written meanwhile by another writer is not replaced.

    Parameters
    ----------
    out : facestats.io.Store
        The writable store the subject goes to.
    edit : SubjectEdit
        The result to write (:meth:`EditSession.write` with ``commit=False`` makes both).
    overwrite : bool
        Replace an existing subject of the same id (checked by :meth:`EditSession.assign_id`).

    Attributes
    ----------
    edit : SubjectEdit
        The result; its ``store`` is the label of ``out``.
    committed : bool
        Whether :meth:`commit` has written it.
    """

    def __init__(self, out, edit: SubjectEdit, *, overwrite: bool = False):
        self.edit = edit
        self.committed = False
        self._out = out
        self._overwrite = bool(overwrite)
        self._lock = threading.Lock()  # one commit at a time: a second caller waits for the first's result

    def __repr__(self) -> str:
        state = "committed" if self.committed else "not written"
        return f"PendingEdit({self.edit.subject_id!r} -> store {self.edit.store}, {state})"

    def commit(self) -> SubjectEdit:
        """Write the new subject to the output store (atomic: :meth:`facestats.io.Store.write_subject`).

        Writes once: a second call returns the result without writing again, also from another thread (it waits
        for the first: two threads both wrote, the second failing on the id the first had taken, or writing it
        twice with ``overwrite``).

        Returns
        -------
        SubjectEdit
            :attr:`edit`, now written.

        Raises
        ------
        StoreError
            The id was taken meanwhile (without ``overwrite``), the store is read-only, or the write failed (e.g.
            a full disk); nothing was written.  (A directory store holds nothing open, so a commit after its
            ``close()`` writes as before.)  An exception (e.g. ``KeyboardInterrupt``) that arrives after the
            store's commit landed is raised with :attr:`committed` True: the subject is written.
        SchemaError
            A source variable left on disk (:data:`ON_DISK`) is invalid, found only now; nothing was written.
        """
        with self._lock:
            if self.committed:
                return self.edit
            sid = self.edit.subject_id
            before = self._generation(sid)
            try:
                self._out.write_subject(self.edit.dataset, overwrite=self._overwrite)  # ON_DISK band by band (Store)
            except SchemaError as exc:  # e.g. a source variable left on disk (ON_DISK), checked only now
                raise SchemaError(
                    f"{exc} (in the edit of subject {self.edit.source.attrs['subject_id']!r}, whose unedited "
                    "variables are copied as stored; nothing was written)"
                ) from None
            except BaseException:  # e.g. Ctrl-C: after the store's commit landed, the subject is written all the same
                if self._generation(sid) not in (None, before) and self._stored_is_this_edit(sid):
                    self.committed = True
                raise
            self.committed = True
        return self.edit

    def _generation(self, sid):
        """The output store's generation of subject ``sid`` (a new one per write), or None; None also when the
        index cannot be read (then :meth:`commit` cannot tell that its write landed, and says it did not)."""
        try:
            entry = self._out.index_entries().get(sid)
        except Exception:  # noqa: BLE001 - only asked after a failure, whose exception is the one to report
            return None
        return None if entry is None else entry.get("generation")

    def _stored_is_this_edit(self, sid):
        """Whether the subject ``sid`` now stored carries this edit's provenance (every entry of it; the store adds
        ``software_version``): a new generation after a failed write may be another writer's (the same id committed
        meanwhile, which made this write fail), not this one.  False when it cannot be read (as :meth:`_generation`).
        """
        from facestats.io.schema import provenance

        try:
            stored = provenance(self._out.subject(sid, lazy=True))
        except Exception:  # noqa: BLE001 - only asked after a failure, whose exception is the one to report
            return False
        return all(stored.get(k, self) == v for k, v in provenance(self.edit.dataset).items())
