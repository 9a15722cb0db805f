"""``facestats export-subject``: one subject out to a renderer (EXR texture set, Mitsuba 3 scene or glTF 2.0).

Parses, calls :func:`facestats.io.subject_export.export_subject` and prints what was written.
"""

from __future__ import annotations

from facestats.cli.options import (
    add_mesh_scale_option,
    add_store_option,
    ascii_int,
    named_options,
    store_path_option,
)

__all__ = ["add_export_subject"]


def _cmd_export_subject(args) -> int:
    with named_options(
        mesh_scale="--mesh-scale",
        mesh_format="--mesh-format",
        out="--out",
        width="--width",
        height="--height",
        spp="--spp",
        subject_id="ID",
        **{"light probe": "--probe"},
    ):
        res = _export(args)
    print(f"exported {res['subject_id']} as {res['format']} to {res['out']}: {len(res['files'])} files")
    for name in res["files"]:
        print(f"  {name}")
    return 0


def _export(args):
    from facestats.io.subject_export import export_subject

    return export_subject(
        args.subject_id,
        args.out,
        args.format,
        store=store_path_option(args.store),
        overwrite=args.overwrite,
        mesh=args.mesh,
        mesh_scale=args.mesh_scale,
        mesh_format=args.mesh_format,
        probe=args.probe,
        material=args.material,
        width=args.width,
        height=args.height,
        spp=args.spp,
    )


def add_export_subject(sub):
    """Register ``facestats export-subject``.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        What ``add_subparsers()`` returned for the ``facestats`` parser.

    Returns
    -------
    None
        The handler (``func``) returns 0; a :class:`~facestats.errors.FacestatsError` raised becomes exit status 2 in
        :func:`facestats.cli.main`.
    """
    p = sub.add_parser(
        "export-subject",
        help="write one subject for a renderer: EXR texture set, Mitsuba 3 scene or glTF 2.0",
        description=(
            "Export a map subject: 'exr' writes one OpenEXR file per map (albedo, normals in object and tangent "
            "space, rho_s, m, Blinn-Phong exponent, sigma_a, sigma_s', sigma_tr, modulation, regions, flags, any "
            "*_std maps) with units and colour space in the headers, the face mesh (OBJ/PLY with UVs) and a "
            "manifest; 'mitsuba' adds a Mitsuba 3 scene (scene.xml, scene.json) with a light probe; 'gltf' writes "
            "a glTF 2.0 asset with a metallic-roughness material. The directory appears whole or not at all. "
            "Options of another format than the one chosen are refused."
        ),
    )
    p.add_argument("subject_id", metavar="ID", help="subject id (see facestats query)")
    p.add_argument("--out", required=True, metavar="DIR", help="output directory (must not exist or be empty)")
    p.add_argument(
        "--format",
        choices=("exr", "mitsuba", "gltf"),
        default="exr",
        help="exr: one EXR per map with the mesh (default); mitsuba: a Mitsuba 3 scene; gltf: glTF 2.0 with PBR maps",
    )
    add_store_option(p)
    p.add_argument(
        "--mesh",
        metavar="PATH",
        help="OBJ/PLY scan the maps belong to (default: the face the subject's provenance records; an edit's: its "
        "source's)",
    )
    add_mesh_scale_option(p)
    p.add_argument(
        "--mesh-format", choices=("obj", "ply"), default=None, help="EXR set: mesh file (default obj; Mitsuba: obj)"
    )
    p.add_argument("--probe", metavar="FILE", help="Mitsuba: lat-long HDR light probe (default: a studio probe)")
    p.add_argument(
        "--material", choices=("surface", "subsurface"), default=None, help="Mitsuba material (default surface)"
    )
    p.add_argument("--width", type=ascii_int, default=None, help="Mitsuba: image width (default 256)")
    p.add_argument("--height", type=ascii_int, default=None, help="Mitsuba: image height (default 256)")
    p.add_argument("--spp", type=ascii_int, default=None, help="Mitsuba: samples per pixel (default 64)")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty output directory")
    p.set_defaults(func=_cmd_export_subject)
