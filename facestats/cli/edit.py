"""``facestats edit``: appearance edits of store subjects (Weyrich et al. 2006 §8).

Parsing and printing only.  Each action makes one call to
:mod:`facestats.edit.subjects` with ``commit=False``, which makes the edited
subject (new id, provenance) without writing it
(:class:`facestats.edit.session.PendingEdit`); then, all or none as far as the
file system allows, the before/after PNGs are rendered under temporary names in
the ``--images`` folder (:func:`facestats.edit.plots.stage_edit_images` in a
:class:`facestats.core.outputs.OutputSet`), the subject is committed, and the
PNGs are renamed into place; the report of the result
(:meth:`facestats.edit.SubjectEdit.to_text`) is printed last.  The target options
become an API target through :func:`facestats.edit.targets.target_from_options`.
Heavy modules are imported inside the commands.

Registered in :mod:`facestats.cli` with :func:`add_edit`.
"""

from __future__ import annotations

import os
import sys

from facestats.cli.options import (
    QUERY_FILTER_OPTIONS,
    add_store_option,
    ascii_float,
    ascii_int,
    check_apart_from_store,
    check_store_to_write,
    named_options,
    non_empty,
    open_store_option,
    store_path_option,
)

__all__ = ["add_edit"]

_DESCRIPTION = (
    "Change a face's appearance with the statistics of another subject or of a population subset (Weyrich et al. "
    "2006 §8). Each edit writes a NEW subject (id SOURCE.<edit>-<digest> unless --id is given) with its provenance "
    "(source subject and store, edit parameters) and never modifies its source; before/after images of the albedo "
    "(sRGB-encoded) and of the edited BRDF maps are saved as PNG. The embedded default store is read-only: pass "
    "--out-store PATH (a directory store, created if missing) to write there."
)


def _common(p, images=True):
    add_store_option(
        p,
        help="store holding the subject and the targets: a directory (X.zarr), a zip, or "
        "texture-sample (six subjects with 512² maps for 7-level texture transfer, built once "
        "into the cache); default: the store embedded in facestats",
    )
    p.add_argument(
        "--out-store",
        default=None,
        metavar="PATH",
        help="directory store for the edited subject (created if missing); default --store, which must "
        "then be a writable directory store",
    )
    p.add_argument(
        "--id",
        default=None,
        metavar="NEW_ID",
        dest="new_id",
        help="id of the edited subject (default SUBJECT.<edit>-<digest of the edit>)",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing subject NEW_ID in the output store")
    if images:
        p.add_argument(
            "--images",
            default=".",
            metavar="DIR",
            help="directory for the before/after PNGs (default: the current directory)",
        )


def _query_args(p, what):
    p.add_argument("--target", type=non_empty, metavar="ID", help=f"take the {what} of this subject")
    p.add_argument(
        "--skin-type",
        type=non_empty,
        metavar="TYPE",
        help="... or of the subjects of this skin type (I-VI or 1-6; condition normal unless --condition)",
    )
    p.add_argument(
        "--condition",
        type=non_empty,
        metavar="NAME",
        help="... or of the subjects measured under this condition ('any': every condition; default normal)",
    )
    p.add_argument("--gender", type=non_empty, metavar="M|F", help="restrict the subset to one gender")
    p.add_argument(
        "--age", type=non_empty, metavar="RANGE", help="restrict the subset to an age range (20s, 30s, MIN-MAX, ...)"
    )


def _regions_arg(p, help_text):
    p.add_argument("--regions", nargs="+", metavar="R", default=None, help=help_text)


def _t_arg(p):
    p.add_argument("--t", type=ascii_float, default=1.0, help="interpolation weight in [0, 1] (default 1: the target)")


def _keep_translucency_arg(p):
    p.add_argument("--keep-translucency", action="store_true", help="keep albedo_avg, σ's and σa")


def _subsample_seed_arg(p):
    p.add_argument("--seed", type=ascii_int, default=None, help="seed of the subsample of a very large target subset")


def _target(args, *, stats=False):
    """The API target from --target / --stats / the query options."""
    from facestats.edit.targets import target_from_options

    return target_from_options(
        target=args.target,
        stats=getattr(args, "stats", None),
        query={k: getattr(args, k, None) for k in ("skin_type", "condition", "gender", "age")},
        stats_allowed=stats,
    )


def _open(args):
    """(source store, output store) from --store / --out-store."""
    from facestats.errors import StoreError
    from facestats.io.store import open_store

    if args.out_store:
        return open_store_option(args.store), open_store(args.out_store, mode="a")
    if args.store is None:
        raise StoreError(
            "the embedded default store is read-only: pass --out-store PATH (a directory store, created if "
            "missing) for the edited subject"
        )
    path = store_path_option(args.store)
    if os.path.isfile(path):
        raise StoreError(f"store {args.store} is a read-only zip store: pass --out-store PATH for the edited subject")
    store = open_store(path, mode="r+")
    return store, store


def _report(pending, images, overwrite) -> int:
    """Save the images of a pending edit and commit it, all or none as far as the file system allows; print it.

    The PNGs are rendered under temporary names beside their targets in the ``--images`` folder ``images``
    (:func:`facestats.edit.plots.stage_edit_images` in a :class:`facestats.core.outputs.OutputSet`), then the
    subject is committed (:meth:`facestats.edit.session.PendingEdit.commit`), then the PNGs are renamed into
    place (:func:`os.replace`, atomic per file; an existing PNG, with ``--overwrite`` (``overwrite``), is put back
    if a rename fails; without it, a PNG that appeared since the check is kept and the renames fail).  A failure
    or an interruption before the commit leaves neither the subject nor a PNG (a folder made for them is
    removed); one while renaming, after the commit, leaves the folder as it was, and the message says that the
    subject was written.  The exit code: 0, or 130 when interrupted after the commit.
    """
    from facestats.core.outputs import OutputSet
    from facestats.edit.plots import stage_edit_images
    from facestats.errors import FacestatsError, StoreError

    edit = pending.edit
    try:
        # the PNGs under temporary names, renamed into place when the block ends (without --overwrite, never onto
        # a file that appeared meanwhile: another edit's of the same --id)
        with OutputSet(images, overwrite=overwrite) as out:
            scales = stage_edit_images(edit, out)
            try:
                pending.commit()
            except OSError as exc:  # the store's failure: the OutputSet would report an OSError as the images'
                raise StoreError(
                    f"cannot write subject {edit.subject_id!r} to store {edit.store}: {exc.strerror or exc}; "
                    "nothing was written"
                ) from None
    except FacestatsError as exc:
        if not pending.committed:
            raise
        raise FacestatsError(
            f"the edited subject {edit.subject_id!r} was written to store {edit.store}, but its images could not be "
            f"moved into {images}, which is as it was ({exc}); rerun the same command with --overwrite to make them"
        ) from None
    except KeyboardInterrupt:
        if not pending.committed:
            raise
        print(  # the subject is committed: say so, not only "interrupted"
            f"facestats: interrupted: the edited subject {edit.subject_id!r} was written to store {edit.store}, its "
            f"images were not moved into {images}, which is as it was; rerun the same command with --overwrite to "
            "make them",
            file=sys.stderr,
        )
        return 130
    print(edit.to_text(images=out.written, directory=images, scales=scales))
    return 0


def _check_outputs(args):
    """The new id and the images folder, checked before any work (a failed command leaves no side effects).

    Returns the ``--images`` folder (``~`` expanded, :func:`facestats.core.outputs.check_output_dir`).
    """
    from facestats.core.outputs import check_apart, check_names_free, check_output_dir
    from facestats.errors import ValidationError
    from facestats.io.ids import check_subject_id
    from facestats.io.store import default_store_path

    if args.new_id is not None:
        with named_options(subject_id="--id"):
            check_subject_id(args.new_id)
    if args.out_store is not None and not args.out_store.strip():
        raise ValidationError("--out-store must name a directory store, got ''")
    check_store_to_write(args.out_store, "--out-store")
    if args.out_store is not None and args.out_store.lower().endswith(".zip"):
        raise ValidationError(
            "--out-store must name a directory store (e.g. edits.zarr; a zip store is read-only), got "
            f"{args.out_store!r}"
        )
    images = check_output_dir(args.images, "--images")
    if args.new_id is not None and not args.overwrite:  # a default id names a subject that exists too: refused
        from facestats.edit.plots import edit_image_names

        check_names_free(images, edit_image_names(args.new_id), "--images", "this edit's images", " or --id")
    source = store_path_option(args.store) if args.store is not None else default_store_path()
    check_apart(args.images, source, "--images", "the source store")
    if args.out_store is not None:  # the source store itself, or a store elsewhere; never one nested inside it
        check_apart(args.out_store, source, "--out-store", "the source store", same=True)
        check_apart(args.images, args.out_store, "--images", "the output store")
    return images


def _run(args, edit_function, target, target_names=QUERY_FILTER_OPTIONS, **kwargs) -> int:
    """Open the stores, make the edit ``edit_function(store, SUBJECT, target, ..., commit=False)``, save its images
    and commit it (:func:`_report`), report it; the exit code.

    A store created by ``--out-store`` is removed again if the command fails before the subject is written.  Errors
    name the options; ``target_names`` (:func:`~facestats.cli.options.named_options`) those of the target, the subset
    filters unless the command takes the target otherwise (``skin-type``'s positional TYPE).
    """
    from facestats.io.root import new_store_guard

    images = _check_outputs(args)
    with new_store_guard(args.out_store):
        store, out = _open(args)
        with store, out:
            # the options, not the API's names
            with named_options(t="--t", feather="--feather", seed="--seed", region="--regions", **target_names):
                pending = edit_function(
                    store,
                    args.subject,
                    target,
                    out_store=out,
                    new_id=args.new_id,
                    overwrite=args.overwrite,
                    commit=False,
                    **kwargs,
                )
            if args.new_id is None and not args.overwrite:  # the default id is known only now: before any write
                from facestats.core.outputs import check_names_free
                from facestats.edit.plots import edit_image_names

                check_names_free(images, edit_image_names(pending.edit.subject_id), "--images", "this edit's images")
            return _report(pending, images, args.overwrite)


def _cmd_skin_type(args) -> int:
    from facestats.edit.subjects import change_skin_type

    return _run(
        args,
        change_skin_type,
        args.skin_type,
        target_names={"skin type": "TYPE"},
        t=args.t,
        brdf=not args.no_brdf,
        colour=not args.no_colour,
        keep_translucency=args.keep_translucency,
        seed=args.seed,
    )


def _cmd_brdf(args) -> int:
    from facestats.edit.subjects import transfer_brdf_subject

    return _run(args, transfer_brdf_subject, _target(args), t=args.t, model=args.model, regions=args.regions)


def _cmd_colour(args) -> int:
    from facestats.edit.subjects import transfer_colour_subject

    return _run(
        args,
        transfer_colour_subject,
        _target(args, stats=True),
        t=args.t,
        regions=args.regions,
        feather=args.feather,
        keep_translucency=args.keep_translucency,
        seed=args.seed,
    )


def _cmd_texture(args) -> int:
    from facestats.edit.subjects import transfer_texture_subject

    with named_options(bins="--bins", levels="--levels", iterations="--iterations", noise="--noise"):
        return _run(
            args,
            transfer_texture_subject,
            _target(args, stats=True),
            regions=args.regions,
            levels=args.levels,
            bins=args.bins,
            iterations=args.iterations,
            seed=args.seed,
            noise=args.noise,
            feather=args.feather,
            keep_translucency=args.keep_translucency,
        )


def _cmd_stats(args) -> int:
    from facestats.edit.statistics import statistics_path
    from facestats.edit.subjects import subject_texture_statistics

    with named_options(path="--out"):
        path = statistics_path(args.out, overwrite=args.overwrite)  # checked before the work
    check_apart_from_store(path, "--out", args.store)  # never a file mixed into the store
    with open_store_option(args.store) as store, named_options(levels="--levels", bins="--bins", region="--regions"):
        stats = subject_texture_statistics(
            store, args.subject, regions=args.regions, levels=args.levels, bins=args.bins
        )
    path = stats.save(args.out)
    print(
        f"wrote the texture statistics of {args.subject} ({stats.n_bands} bands x {stats.bins} bins x 3 channels, "
        f"{stats.levels} levels, {stats.orientations} orientations) to {path}"
    )
    return 0


def add_edit(sub) -> None:
    """Register ``facestats edit`` and its actions on the top-level subparsers ``sub``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handlers (``func``) return 0, or 130 when interrupted after the subject was written, while its images
        were moved into place; ``edit`` alone prints its help and returns 2; a
        :class:`~facestats.errors.FacestatsError` raised becomes exit status 2 in :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "edit",
        help="appearance edits (§8): skin type, BRDF, colour, texture; writes a new subject",
        description=_DESCRIPTION,
    )
    actions = p.add_subparsers(title="actions", metavar="ACTION")

    def _help(args) -> int:
        p.print_help()
        return 2

    p.set_defaults(func=_help)

    a = actions.add_parser(
        "skin-type",
        help="change the skin type with the statistics of the subjects of that type",
        description="Match the face albedo (in a decorrelated colour space) and the per-region BRDF histograms to "
        "the pooled statistics of the subjects of skin type TYPE (condition normal; I and II grouped). "
        "Translucency (albedo_avg, σ's, σa) follows the new albedo through §5.4 unless "
        "--keep-translucency.",
    )
    a.add_argument("subject", metavar="SUBJECT", help="subject id")
    a.add_argument("skin_type", metavar="TYPE", help="target skin type, I-VI or 1-6")
    _t_arg(a)
    a.add_argument("--no-brdf", action="store_true", help="leave the BRDF maps")
    a.add_argument("--no-colour", action="store_true", help="leave the albedo")
    _keep_translucency_arg(a)
    _subsample_seed_arg(a)
    _common(a)
    a.set_defaults(func=_cmd_skin_type)

    a = actions.add_parser(
        "brdf",
        help="per-region BRDF histogram transfer / interpolation from a subject or a subset",
        description="Move each region's Torrance-Sparrow and/or Blinn-Phong parameter histograms to the target's "
        "(histogram interpolation of Matusik et al. 2005), e.g. normal -> lotion half-way: "
        "brdf S008 --condition lotion --t 0.5.",
    )
    a.add_argument("subject", metavar="SUBJECT", help="subject id")
    _query_args(a, "BRDF")
    _t_arg(a)
    a.add_argument(
        "--model",
        choices=("both", "ts", "bp"),
        default="both",
        help="Torrance-Sparrow (ts), Blinn-Phong (bp) or both (default)",
    )
    _regions_arg(a, "regions to edit, 1-10 or names (default: all with target samples)")
    _common(a)
    a.set_defaults(func=_cmd_brdf)

    a = actions.add_parser(
        "colour",
        help="albedo histogram transfer in a decorrelated colour space",
        description="Match the albedo histograms of SUBJECT, in the target's PCA colour basis, to those of a "
        "subject, a subset or saved texture statistics. Translucency follows the new albedo (§5.4) "
        "unless --keep-translucency.",
    )
    a.add_argument("subject", metavar="SUBJECT", help="subject id")
    _query_args(a, "albedo")
    a.add_argument(
        "--stats", type=non_empty, metavar="FILE", help="... or use the image histograms of saved texture statistics"
    )
    _t_arg(a)
    _regions_arg(a, "regions to edit and take the target albedo from, 1-10 or names (default: the face)")
    a.add_argument("--feather", type=ascii_float, default=0.0, help="blend width in texels inside the edge (default 0)")
    _keep_translucency_arg(a)
    _subsample_seed_arg(a)
    _common(a)
    a.set_defaults(func=_cmd_colour)

    a = actions.add_parser(
        "texture",
        help="Heeger-Bergen texture transfer (band statistics, e.g. of freckled skin) from a subject or statistics",
        description="Give the albedo of SUBJECT the texture statistics (histograms of the steerable-pyramid bands in "
        "a decorrelated colour space) of another subject or of a statistics file, optionally only in "
        "some regions (each matched on its own; texels outside are unchanged).",
    )
    a.add_argument("subject", metavar="SUBJECT", help="subject id")
    a.add_argument("--target", type=non_empty, metavar="ID", help="take the texture of this subject")
    a.add_argument("--stats", type=non_empty, metavar="FILE", help="... or of saved statistics (facestats edit stats)")
    _regions_arg(a, "regions to edit, 1-10 or names, e.g. 2 6 7 (forehead, nose, cheeks); default: the face")
    a.add_argument("--seed", type=ascii_int, default=None, help="seed of the start noise (same seed, same result)")
    a.add_argument("--iterations", type=ascii_int, default=5, help="Heeger-Bergen iterations, 0-100 (default 5)")
    a.add_argument(
        "--levels", type=ascii_int, default=None, help="pyramid levels (default: the most the map supports, <= 7)"
    )
    a.add_argument(
        "--bins",
        type=ascii_int,
        default=None,
        help="histogram bins for a subject target (default 256); a --stats target fixes its own",
    )
    a.add_argument("--noise", type=ascii_float, default=0.1, help="start-noise amplitude (default 0.1)")
    a.add_argument("--feather", type=ascii_float, default=2.0, help="blend width in texels inside the edge (default 2)")
    _keep_translucency_arg(a)
    _common(a)
    a.set_defaults(func=_cmd_texture)

    a = actions.add_parser(
        "stats",
        help="save the texture statistics of a subject (a target for texture / colour)",
        description="Compute the §8 texture statistics (256-bin histograms of the albedo and its steerable-pyramid "
        "bands in a decorrelated colour space) of a subject's face or regions and save them (.npz).",
    )
    a.add_argument("subject", metavar="SUBJECT", help="subject id")
    a.add_argument("--out", required=True, metavar="FILE", help="output file (.npz appended if missing)")
    a.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    _regions_arg(a, "regions to analyse, 1-10 or names (default: the face)")
    a.add_argument(
        "--levels", type=ascii_int, default=None, help="pyramid levels (default: the most the map supports, <= 7)"
    )
    a.add_argument("--bins", type=ascii_int, default=256, help="histogram bins (default 256)")
    add_store_option(
        a,
        help="store holding the subject (a directory, a zip or texture-sample); default: the "
        "store embedded in facestats",
    )
    a.set_defaults(func=_cmd_stats)
