"""``facestats microstructure``: dynamic skin microstructure of mesh sequences (facestats.pipeline.microstructure)."""

from __future__ import annotations

from facestats.cli.options import ascii_float, ascii_int, check_apart_from_store, named_options, store_path_option

__all__ = ["add_microstructure"]


def _cmd_render(args) -> int:
    from facestats.core.validate import check_integer
    from facestats.errors import ValidationError
    from facestats.pipeline.microstructure import render_files

    if args.size is not None:
        check_integer(args.size, "--size", 1)
    if args.frames is not None and args.targets is not None:
        raise ValidationError("--targets go with --weights (blendshapes), not with --frames; got both")
    with named_options(
        height_range_um="--height-range-um",
        tile="--tile",
        scale="--scale",
        table="--table",
        weights="--weights",
        window="--window",
        neutral_map="--map",
        neutral="--neutral",
        root="--neutral",  # read_ict_facekit's name for a neutral given as a folder
        frames="--frames",
        targets="--targets",
        path="--map",  # read_image's name for the one image read, the map
    ):
        report = render_files(
            args.neutral,
            args.map,
            args.out,
            frames=args.frames,
            targets=args.targets,
            weights=args.weights,
            scale=args.scale,
            height_range_um=args.height_range_um,
            map_shape=None if args.size is None else (args.size, args.size),
            window=args.window,
            table=args.table,
            exr_dir=args.exr_dir,
            tile=args.tile,
            progress=not args.quiet,
            overwrite=args.overwrite,
        )
    print(report.to_text())
    return 0


def _check_generate(args) -> None:
    """The options of ``microstructure generate``, checked before any work with messages naming them."""
    from facestats.core.outputs import check_output_file
    from facestats.core.validate import as_finite, check_integer, check_window
    from facestats.errors import ValidationError
    from facestats.pipeline.microstructure import MAX_NEUTRAL_MAP_SIZE

    if args.store is not None and args.subject is None:
        raise ValidationError(f"--store names the store of --subject; give --subject too (got --store {args.store!r})")
    check_output_file(args.out, "--out", (".exr",), overwrite=args.overwrite)
    check_apart_from_store(args.out, "--out", args.store)  # never a file mixed into the store
    check_integer(args.size, "--size", 2, MAX_NEUTRAL_MAP_SIZE)
    with named_options(window="--window"):
        check_window(args.size, args.window)
    as_finite(args.texel_um, "--texel-um", 0.0, 1000.0, low_inclusive=False, unit="um")
    if args.seed is not None:
        check_integer(args.seed, "--seed", 0)


def _cmd_generate(args) -> int:
    from facestats.pipeline.microstructure import generate_neutral_map

    _check_generate(args)
    with named_options(texel_um="--texel-um", size="--size", window="--window", subject="--subject"):
        path = generate_neutral_map(
            args.out,
            args.size,
            texel_um=args.texel_um,
            subject=args.subject,
            store=store_path_option(args.store),
            seed=args.seed,
            window=args.window,
        )
    print(f"wrote {path}")
    return 0


def add_microstructure(sub):
    """Register ``facestats microstructure`` and its ``render`` and ``generate`` commands.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handlers (``func``) return 0; ``microstructure`` alone prints its help and returns 2 (as
        ``calibrate``, ``capture``, ``emulate`` and ``edit`` do without a subcommand); a
        :class:`~facestats.errors.FacestatsError` raised becomes exit status 2 in :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "microstructure",
        help="dynamic skin microstructure: strain-driven displacement-map convolution (Nagano et al. 2015)",
        description=(
            "Blur skin microstructure along stretch and sharpen it along compression: per-frame displacement and "
            "normal maps of a mesh sequence from a neutral displacement map (Nagano et al. 2015)."
        ),
    )
    commands = p.add_subparsers(title="subcommands", metavar="SUBCOMMAND")
    r = commands.add_parser(
        "render",
        help="render a sequence's deformed displacement and normal maps to zarr (and EXR); resumable",
        description=(
            "Read a neutral mesh with UVs (OBJ/PLY, or an ICT-FaceKit checkout) and its frames (one mesh per frame, "
            "or blendshape targets with a CSV of per-frame weights), measure each frame's strain and convolve the "
            "neutral displacement map accordingly. Rerunning with the same inputs continues an interrupted render."
        ),
    )
    r.add_argument(
        "--neutral", required=True, metavar="MESH", help="neutral mesh (OBJ/PLY with UVs) or ICT-FaceKit dir"
    )
    frames = r.add_mutually_exclusive_group(required=True)
    frames.add_argument("--frames", nargs="+", metavar="MESH", help="one OBJ/PLY per frame, in order")
    frames.add_argument("--weights", metavar="CSV", help="per-frame blendshape weights (header: target names)")
    r.add_argument("--targets", nargs="+", metavar="MESH", help="blendshape target meshes (stems name the columns)")
    r.add_argument("--map", required=True, metavar="IMAGE", help="neutral displacement map (EXR/PFM in um, PNG16/TIFF)")
    r.add_argument("--height-range-um", type=ascii_float, help="um spanned by an integer map's code range")
    r.add_argument("--out", required=True, metavar="ZARR", help="output zarr group")
    r.add_argument("--exr-dir", metavar="DIR", help="also write per-frame EXR files here")
    r.add_argument("--size", type=ascii_int, help="side of the whole UV map in texels (default: the map's)")
    r.add_argument(
        "--window", type=ascii_int, nargs=4, metavar=("ROW0", "COL0", "H", "W"), help="render part of the map"
    )
    r.add_argument("--table", default="forehead", help="kernel table (default: forehead, Nagano eq. 8-9)")
    r.add_argument("--scale", type=ascii_float, default=1.0, help="mesh units to mm (e.g. 10 for cm)")
    r.add_argument("--tile", type=ascii_int, default=512,
                   help="tile side in texels (default 512); each tile carries a halo of up to several hundred "
                   "texels, so smaller tiles cost more time and memory, not less")  # fmt: skip
    r.add_argument("--overwrite", action="store_true", help="replace an output holding another render")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=_cmd_render)
    g = commands.add_parser(
        "generate",
        help="write a procedural neutral microstructure map (EXR, um), per region from a store subject",
        description=(
            "Pores and fine anisotropic furrows, seeded; with --subject, per region from its maps. A subject's map "
            "is its face: --size texels of --texel-um must be the size of its face's UV layout (refused otherwise); "
            "--window writes the part of that map a render's --window covers, a patch of the face at that scale."
        ),
    )
    g.add_argument("--out", required=True, metavar="EXR", help="output .exr file")
    g.add_argument("--size", type=ascii_int, default=1024,
                   help="side of the whole UV map in texels, 2-16384 (default 1024): the file's without --window, "
                   "render's --size with it")  # fmt: skip
    g.add_argument(
        "--window", type=ascii_int, nargs=4, metavar=("ROW0", "COL0", "H", "W"),
        help="write only this part of the map (as render's --window)",
    )  # fmt: skip
    g.add_argument("--texel-um", type=ascii_float, default=15.0, help="um per texel, in (0, 1000] (default 15)")
    g.add_argument("--subject", help="store subject id (e.g. S001)")
    g.add_argument("--store", help="store of --subject (default, or 'default': the embedded store)")
    g.add_argument("--seed", type=ascii_int, help="seed, >= 0 (default: from the subject id)")
    g.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    g.set_defaults(func=_cmd_generate)
    p.set_defaults(func=lambda args: p.print_help() or 2)  # no subcommand: a usage error, as calibrate's
