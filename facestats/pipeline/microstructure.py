"""Render dynamic skin microstructure for a mesh sequence: per-frame displacement and normal maps, resumable.

Nagano et al. 2015 §5-6 on an animation: for every frame of a sequence
(:mod:`facestats.io.mesh_sequence`: OBJ/PLY frames or blendshape weights), the
per-texel strain of the frame against the neutral mesh
(:class:`facestats.model.strain.MeshStrain`) drives the convolution of the
neutral microstructure map (:func:`facestats.model.microstructure.deform_microstructure`).

This is a pipeline stage (not an edit of store subjects) because it streams a
sequence to files, in tiles, and resumes after an interruption — the same job
as :mod:`facestats.pipeline.build` for populations.

Output: a zarr group at ``out`` with ``displacement`` (frame, v, u) float32 in
µm, ``normal`` (frame, v, u, 3) float32 tangent-space normals, ``stretch``
(frame, 7) — percentiles 1/50/99 of r_s and r_t over the mesh's texels (NaN,
with a :class:`~facestats.errors.FacestatsWarning`, for a frame whose every
triangle is degenerate: no strain is measured) and the count of degenerate
triangles —, and ``done`` (frame,) bool; optionally
``displacement.NNNNN.exr`` (channel Y, units um) and ``normal.NNNNN.exr`` (R, G,
B = n_u, −n_v, n_n: G up the texture, the OpenGL / glTF convention of the export's
tangent-space maps, recorded in the header ``normal_space``; the group keeps n_v
down the map) per frame in ``exr_dir``, each with the headers ``map_shape`` and
``window`` (JSON, texels).  A frame is marked done only after
all its outputs are written (EXR files through a temporary name and an atomic
rename), so an interrupted run leaves the finished frames intact and the next
run with the same inputs continues where it stopped; different inputs at the
same path raise instead of mixing renders: the group records a SHA-256 of the
neutral mesh, of every frame's vertex positions and of the neutral map.  The
group is created under a temporary name and renamed into place, so a run killed
while creating it leaves no group; ``overwrite`` replaces only a render of this
function (never another folder, nor what a symbolic link points to).  EXR
files carry a header attribute naming the render (a SHA-256 of its inputs) and
the frame; every run with ``exr_dir`` writes each frame rendered in this run and
each finished frame whose files there are missing or from another render (only
the headers are read); a folder holding frame files beyond the sequence is
refused.

Tiling: the window is processed in tiles of ``tile`` texels, each with a halo of
the reach of both passes at the largest σ of the tables, ⌈3 · 100 µm / smallest
rest texel⌉ + 2 texels each, the smallest texel taken around the tile
(:func:`tile_halo`), so any map size runs in bounded memory and the result does
not depend on the tiling.
"""

from __future__ import annotations

import hashlib
import json
import os
import pathlib
import re
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

import facestats
from facestats.acquire.synthetic.microstructure import (
    procedural_microstructure,
    region_labels,
    subject_microstructure,
)
from facestats.core.compiled import resolve_backend
from facestats.core.outputs import OutputSet, check_output_file
from facestats.core.progress import progress_bar
from facestats.core.validate import as_scalar, check_choice, check_integer, check_window
from facestats.core.version import __version__
from facestats.errors import FacestatsError, FacestatsWarning, StoreError, ValidationError
from facestats.face.named import parse_face_name
from facestats.io.displacement import read_displacement, write_displacement
from facestats.io.ict_facekit import read_ict_facekit
from facestats.io.images import read_exr_attributes, write_exr
from facestats.io.mesh import recorded_geometry, subject_mesh
from facestats.io.mesh_sequence import (
    BlendshapeSequence,
    FrameSequence,
    check_mesh_file,
    read_mesh,
    read_vertices,
    read_weights,
)
from facestats.model.microstructure.convolve import displacement_limit
from facestats.model.microstructure.deform import deform_microstructure
from facestats.model.microstructure.kernel import SIGMA_RANGE_UM, TRUNCATE
from facestats.model.microstructure.tables import TABLES, KernelTable
from facestats.model.strain import SLIVER_RATIO, MeshStrain

__all__ = ["SequenceReport", "render_sequence", "tile_halo", "mesh_texel_um", "TEXEL_SIZE_TOLERANCE"]

#: Largest side of a generated neutral map (:func:`generate_neutral_map`), and of the whole map a window of it is
#: generated from: a 16K map.  The generator works in blocks of rows, so memory is the float32 map (1 GiB at
#: 16384²) plus about 90 MB.
MAX_NEUTRAL_MAP_SIZE = 16384

STRETCH_STATS = ("r_s_p1", "r_s_p50", "r_s_p99", "r_t_p1", "r_t_p50", "r_t_p99", "n_degenerate")


@dataclass
class SequenceReport:
    """What :func:`render_sequence` did.

    Attributes
    ----------
    path : str
        The Zarr group written (``out``).
    n_frames : int
        Frames of the sequence.
    rendered : list of int
        Indices of the frames rendered by this call.
    skipped : list of int
        Indices of the frames the group already held (a continued render).
    seconds : float
        Wall-clock time of the frame loop.
    map_shape : tuple of int
        ``(height, width)`` of the whole UV map, texels.
    window : tuple of int
        ``(row0, col0, height, width)``: the part of the map rendered, texels.
    """

    path: str
    n_frames: int
    rendered: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    seconds: float = 0.0
    map_shape: tuple = ()
    window: tuple = ()

    def to_text(self) -> str:
        """What the render did, on one line."""
        per = self.seconds / max(len(self.rendered), 1)
        return (
            f"{self.path}: {self.n_frames} frame{'s' if self.n_frames != 1 else ''}, window {self.window} of a "
            f"{self.map_shape[0]} x {self.map_shape[1]} "
            f"map; rendered {len(self.rendered)} ({per:.2f} s/frame), already done {len(self.skipped)}"
        )


def tile_halo(mesh_strain: MeshStrain, map_shape, tile=None) -> int:
    """Halo (texels) around ``tile`` so that both passes at σ = 100 µm see only real neighbours (module docstring).

    ``tile`` = (row0, col0, height, width) in the map of ``map_shape`` = (H, W) texels, default the whole map.
    A texel's rest metric is the barycentric mix of its triangle's three UV-vertex metrics M
    (:meth:`MeshStrain.texels_strain`), so its texels per mm along any axis are at most the largest
    ‖diag(W, H) M‖₂ of those vertices (the norm is convex).  The reach of one pass over a region, in texels,
    is ⌈3 · 100 µm / smallest texel⌉ + 2, the smallest texel taken over the triangles whose UV box meets
    the cells of :data:`HALO_CELL` texels that the region touches (:class:`_TexelDensity`).  The first
    pass must be right over the tile widened by the second pass's reach, hence the halo
    = reach(tile) + reach(tile widened by reach(tile)) + 2.  Before 2026-12-06 one halo served every tile,
    from the smallest texel of the whole mesh: ICT-FaceKit's at 16K has a triangle of 0.31 µm texels, so
    every 512-texel tile of a face window grew by 1,940 texels a side (a 2,048² window took 88 s a frame).

    Parameters
    ----------
    mesh_strain : facestats.model.strain.MeshStrain
        The rest mesh's UV metrics.
    map_shape : tuple of int
        (H, W) of the map, texels.
    tile : tuple of int, optional
        (row0, col0, height, width) in texels; default the whole map.

    Returns
    -------
    int
        The halo, texels on each side of ``tile``.
    """
    h, w = map_shape
    return _TexelDensity(mesh_strain, map_shape).halo((0, 0, h, w) if tile is None else tile)


#: Cell size (texels) of the grid that bounds the texel density around a tile (:func:`tile_halo`).
HALO_CELL = 64


class _TexelDensity:
    """The largest texels per mm of each :data:`HALO_CELL`² cell of a map: the bound of :func:`tile_halo`."""

    def __init__(self, mesh_strain: MeshStrain, map_shape):
        h, w = map_shape
        self.shape = (-(-h // HALO_CELL), -(-w // HALO_CELL))
        scale = np.array([w, h], float)[None, :, None]  # diag(W, H) M, texels per mm
        per_vertex = np.linalg.norm(np.nan_to_num(mesh_strain.vertex_m * scale), ord=2, axis=(1, 2))
        tri = np.nonzero(~mesh_strain.rest_degenerate)[0]
        density = per_vertex[mesh_strain.uv_triangles[tri]].max(axis=1) if tri.size else np.zeros(0)
        x, y = mesh_strain.uv_corners[tri, :, 0] * w, mesh_strain.uv_corners[tri, :, 1] * h
        gh, gw = self.shape
        cx0, cx1 = (np.clip(np.floor(v / HALO_CELL), 0, gw - 1).astype(int) for v in (x.min(1) - 1, x.max(1) + 1))
        cy0, cy1 = (np.clip(np.floor(v / HALO_CELL), 0, gh - 1).astype(int) for v in (y.min(1) - 1, y.max(1) + 1))
        grid = np.zeros(self.shape)
        span_y, span_x = cy1 - cy0, cx1 - cx0
        for dy in range(int(span_y.max(initial=-1)) + 1):  # loop over cell offsets within the triangles' boxes
            for dx in range(int(span_x.max(initial=-1)) + 1):
                sel = (dy <= span_y) & (dx <= span_x)
                np.maximum.at(grid, (cy0[sel] + dy, cx0[sel] + dx), density[sel])
        self.grid = grid

    def reach(self, region) -> int:
        """Texels one pass at the largest σ reaches from any texel of ``region`` = (row0, col0, height, width)."""
        r0, c0, rh, rw = (int(v) for v in region)
        gh, gw = self.shape
        y0, y1 = (min(max(v // HALO_CELL, 0), gh - 1) for v in (r0 - 1, r0 + rh + 1))
        x0, x1 = (min(max(v // HALO_CELL, 0), gw - 1) for v in (c0 - 1, c0 + rw + 1))
        largest = float(self.grid[y0 : y1 + 1, x0 : x1 + 1].max(initial=0.0))
        return int(np.ceil(TRUNCATE * SIGMA_RANGE_UM[1] * largest / 1000.0)) + 2

    def halo(self, tile) -> int:
        r0, c0, th, tw = (int(v) for v in tile)
        first = self.reach((r0, c0, th, tw))
        return first + self.reach((r0 - first, c0 - first, th + 2 * first, tw + 2 * first)) + 2


#: A generated map whose recorded texel size differs from the mesh's by more than this factor is refused.
TEXEL_SIZE_TOLERANCE = 2.0


def mesh_texel_um(mesh_strain: MeshStrain, map_shape, window=None) -> float:
    """Median µm per texel of the rest mesh's triangles in a map of ``map_shape`` = (H, W) texels (or in a window).

    A triangle's texels per mm are the singular values of diag(W, H) M (M: the UV metric of
    :class:`facestats.model.strain.MeshStrain`, columns = UV per mm); their geometric mean sqrt(|det|) gives its
    µm per texel, 1000 / sqrt(|det|).  NaN for a mesh with no valid triangle (in the window).

    Parameters
    ----------
    mesh_strain : facestats.model.strain.MeshStrain
        The rest mesh's UV metrics (degenerate rest triangles are left out).
    map_shape : tuple of int
        (H, W) of the map, texels.
    window : (row0, col0, height, width), optional
        Only the triangles whose UV bounding box meets these texels (default: all).  A UV layout's texel size
        varies: ICT-FaceKit's face has 18.1 µm texels in a 16,384² map (median over all its triangles) and
        10.6 µm ones in the cheek window (9046, 6077, 512, 512).

    Returns
    -------
    float
        µm per texel (NaN without a triangle of nonzero area in UV).
    """
    (h, w), (r0, c0, wh, ww) = check_window(map_shape, window)
    keep = ~mesh_strain.rest_degenerate
    if window is not None:
        texels = mesh_strain.uv_corners * np.array([w, h], float)  # (F, 3, 2) (column, row) of the UV corners
        low, high = texels.min(1), texels.max(1)
        keep &= (high[:, 0] >= c0) & (low[:, 0] <= c0 + ww) & (high[:, 1] >= r0) & (low[:, 1] <= r0 + wh)
    m = mesh_strain.m[keep] * np.array([w, h], float)[None, :, None]
    det = np.abs(np.linalg.det(m)) if len(m) else np.zeros(0)
    det = det[det > 0]
    return float(np.median(1000.0 / np.sqrt(det))) if det.size else float("nan")


def _check_generated_map(path, mesh_strain, map_shape, window) -> None:
    """Refuse a map ``facestats microstructure generate`` made for another place or texel size than the render's.

    The generator records its ``texel_um`` and, for a subject's map (whose regions have places) or a window, the
    ``map_shape`` and ``window`` it covers.  A subject's map generated for one window and rendered at another
    puts the regions of one place on another (a whole face squeezed into the cheek window it was rendered at
    did: forehead furrows on the cheek).  Pores and ridges made at 15 µm per texel and mapped at 117 µm per
    texel come out 8× too large, and the table's kernels (σ of 5-40 µm) fall under a texel, a silent no-op;
    the texel size compared is the mesh's in the window rendered (:func:`mesh_texel_um`).  Maps without the
    attributes (not generated here, or older) are not checked.
    """
    if pathlib.Path(path).suffix.lower() != ".exr":
        return
    attrs = read_exr_attributes(path)
    try:
        made_shape, made_window = json.loads(attrs["map_shape"]), json.loads(attrs["window"])
    except (KeyError, TypeError, ValueError):
        made_shape = made_window = None
    if made_shape is not None and (list(made_shape) != list(map_shape) or list(made_window) != list(window)):
        raise ValidationError(
            f"neutral_map {os.fspath(path)!r} was generated for the window {list(made_window)} of a "
            f"{made_shape[0]} x {made_shape[1]} map ({attrs.get('source', 'facestats')}), but this render covers "
            f"the window {list(window)} of a {map_shape[0]} x {map_shape[1]} map: its regions would land on "
            f"another part of the face. Generate the map for this window (generate --size {map_shape[1]} "
            f"--window {' '.join(str(x) for x in window)}; size, window), or render the window it was made for "
            "(--size, --window; map_shape, window)"
        )
    try:
        made = float(attrs.get("texel_um"))
    except (TypeError, ValueError):
        return
    mesh = mesh_texel_um(mesh_strain, map_shape, window)
    if not (np.isfinite(mesh) and made > 0) or 1 / TEXEL_SIZE_TOLERANCE <= mesh / made <= TEXEL_SIZE_TOLERANCE:
        return
    raise ValidationError(
        f"neutral_map {os.fspath(path)!r} was generated at texel_um {made:g} um per texel, but the mesh maps a "
        f"{map_shape[0]} x {map_shape[1]} map at {mesh:.3g} um per texel (median over its triangles in the window "
        f"{list(window)}): its microstructure would be {mesh / made:.2g}x its size. Generate it at that texel "
        f"size (--texel-um {mesh:.3g}), or give the map size and window it was made for (--size, --window; "
        "map_shape, window)"
    )


def _neutral_map(neutral_map):
    """The neutral map as float32 µm, finite and within :func:`~facestats.model.microstructure.convolve.
    displacement_limit` of float32 (what the render's passes keep finite), checked before any work.

    A float64 map beyond float32's range became ±inf in the cast, and one beyond the limit was refused by the
    first tile's convolution as ``displacement`` (a name the caller never gave) after the output was opened.
    """
    if isinstance(neutral_map, (str, os.PathLike)):
        d, where = read_displacement(neutral_map), f" in {os.fspath(neutral_map)!r}"
    else:
        d, where = np.asarray(neutral_map), ""
        if d.dtype not in (np.float32, np.float64) or d.ndim != 2:
            raise ValidationError(f"neutral_map must be a 2-D float32/float64 map (µm), got {d.dtype} {d.shape}")
        if not np.all(np.isfinite(d)):
            raise ValidationError(f"neutral_map must be finite, got {int(np.sum(~np.isfinite(d)))} NaN/inf texels")
    limit = displacement_limit(np.float32)
    worst = max(float(np.max(d)), -float(np.min(d))) if d.size else 0.0
    if worst > limit:
        raise ValidationError(
            f"neutral_map must hold displacements within ±{limit:.4g} um (displacement_limit of float32: the "
            f"render's sharpening passes keep them finite), got |{worst:.4g}| um{where}"
        )
    return d.astype(np.float32)


def _sequence_sha256(sequence) -> str:
    """SHA-256 of the neutral mesh (positions, triangles, UVs) and of every frame's vertex positions.

    Reads every frame once: a resumed render must be of the same inputs, frame by frame.
    """
    h = hashlib.sha256()
    mesh = sequence.neutral
    for a in (mesh.vertices, mesh.triangles, mesh.uv, mesh.uv_triangles):
        h.update(np.ascontiguousarray(a).tobytes())
    for i in range(len(sequence)):  # loop over frames (a mesh each)
        h.update(np.ascontiguousarray(sequence.frame(i), np.float64).tobytes())
    return h.hexdigest()


def _config(sequence, neutral, map_shape, window, table, names):
    tab = table if isinstance(table, str) else repr(table)
    return {
        "neutral_mesh": sequence.neutral.name,
        "n_vertices": sequence.neutral.n_vertices,
        "frames": names,
        "sequence_sha256": _sequence_sha256(sequence),
        "neutral_map_sha256": hashlib.sha256(np.ascontiguousarray(neutral).tobytes()).hexdigest(),
        "map_shape": list(map_shape),
        "window": list(window),
        "table": tab,
    }


#: Attribute that marks a zarr group as a render of :func:`render_sequence`.
METHOD = "Nagano et al. 2015 eq. 1-13 (facestats.pipeline.microstructure)"


def _render_attributes(path):
    """The group attributes of ``path`` if it is a zarr group written by :func:`render_sequence`, else None."""
    meta = os.path.join(path, "zarr.json")
    if not os.path.isfile(meta):
        return None
    try:
        with open(meta, encoding="utf-8") as f:
            attrs = json.load(f).get("attributes", {})
    except (OSError, ValueError, AttributeError):
        return None
    return attrs if isinstance(attrs, dict) and attrs.get("method") == METHOD else None


def _reuse(path, config, overwrite) -> bool:
    """True if ``path`` holds this very render (reopen it); False if it may be created or replaced; else raise.

    Never replaced: a path that is not a render of :func:`render_sequence` (an empty folder is taken as absent),
    and a symbolic link (what it points to is not facestats' to delete); a render of other inputs only with
    ``overwrite``.
    """
    if not path:
        raise ValidationError("out must be a non-empty path, got ''")
    if not os.path.lexists(path):
        return False
    if os.path.isdir(path) and not os.path.islink(path) and not os.listdir(path):
        return False  # an empty folder: nothing to lose
    attrs = _render_attributes(path)
    if attrs is None:
        raise StoreError(
            f"out {path!r} exists and is not a microstructure render; facestats neither writes into nor "
            "deletes it, even with overwrite (--overwrite): choose another path"
        )
    try:
        old = json.loads(attrs.get("config", "null"))
    except (ValueError, TypeError):
        old = None
    if old == config:
        return True
    if os.path.islink(path):
        raise StoreError(
            f"out {path!r} is a symbolic link to a render of other inputs; facestats does not replace what a link "
            "points to: give another path"
        )
    if overwrite:
        return False
    if not isinstance(old, dict) or any(k not in old for k in config):
        raise StoreError(
            f"out {path!r} holds a render from an older facestats or with an unreadable record (missing "
            f"{sorted(k for k in config if not isinstance(old, dict) or k not in old)}); it cannot be resumed: "
            "overwrite=True (--overwrite) renders it again"
        )
    diff = sorted(k for k in config if old.get(k) != config[k])
    raise StoreError(
        f"out {path!r} holds a render of other inputs (differing: {diff}); use another path or "
        "overwrite=True (--overwrite)"
    )


#: The normal files' convention (header ``normal_space``), that of the export's tangent-space maps
#: (:data:`facestats.io.exr_set.TANGENT_SPACE`).
EXR_NORMAL_SPACE = (
    "tangent space: R = along +u, G = up the texture (-v; glTF/OpenGL +Y up), B = surface normal; unit vectors"
)
_EXR_NAME = re.compile(r"^(displacement|normal)\.(\d{5,})\.exr$")


def _check_exr_dir(exr_dir, n):
    """An EXR folder that is not a file and holds no frame files beyond this sequence's ``n`` frames."""
    if exr_dir is None:
        return None
    path = os.fspath(exr_dir)  # as given: the system resolves links and '..' (a lexical normpath would not)
    if not path:
        raise ValidationError("exr_dir must be a non-empty path, got ''")
    if os.path.lexists(path) and not os.path.isdir(path):
        raise ValidationError(f"exr_dir must be a folder, got {path!r}, which exists and is not a folder")
    if os.path.isdir(path):
        beyond = sorted(f for f in os.listdir(path) if (m := _EXR_NAME.match(f)) and int(m.group(2)) >= n)
        if beyond:
            raise ValidationError(
                f"exr_dir {os.fspath(exr_dir)!r} holds frame files beyond this sequence's {n} frames "
                f"({', '.join(beyond[:4])}{', ...' if len(beyond) > 4 else ''}): remove them or use another folder"
            )
    return path


def _open_group(out, config, n, window, tile, overwrite):
    """``(group, created)``: the render's zarr group, reopened if it holds the same render (``created`` False), else
    created (atomically, by a rename)."""
    import shutil

    import zarr

    path = os.fspath(out)
    if _reuse(path, config, overwrite):
        return zarr.open_group(path, mode="r+"), False
    parent, base = os.path.split(os.path.abspath(path))
    os.makedirs(parent, exist_ok=True)
    tmp = os.path.join(parent, f".{base}.creating")
    if os.path.isdir(tmp) and not os.path.islink(tmp):  # left by a run killed while creating its group
        shutil.rmtree(tmp)
    elif os.path.lexists(tmp):
        os.remove(tmp)
    h, w = window[2], window[3]
    g = zarr.open_group(tmp, mode="w")
    ch, cw = min(tile, h), min(tile, w)
    g.create_array("displacement", shape=(n, h, w), chunks=(1, ch, cw), dtype="float32", fill_value=np.nan,
                   dimension_names=("frame", "v", "u"))  # fmt: skip
    g.create_array("normal", shape=(n, h, w, 3), chunks=(1, ch, cw, 3), dtype="float32", fill_value=np.nan,
                   dimension_names=("frame", "v", "u", "component"))  # fmt: skip
    g.create_array("stretch", shape=(n, len(STRETCH_STATS)), chunks=(n, len(STRETCH_STATS)), dtype="float64",
                   fill_value=np.nan, dimension_names=("frame", "stat"))  # fmt: skip
    g.create_array("done", shape=(n,), chunks=(n,), dtype="bool", fill_value=False, dimension_names=("frame",))
    g.attrs.update(
        {
            "config": json.dumps(config),
            "stat": list(STRETCH_STATS),
            "units": json.dumps({"displacement": "um", "normal": "1"}),
            "method": METHOD,
            "facestats_version": __version__,
        }
    )
    if os.path.isdir(path) and not os.listdir(path):
        os.rmdir(path)  # an empty folder
    elif os.path.lexists(path):  # a render of other inputs, replaced (overwrite)
        shutil.rmtree(path)
    os.replace(tmp, path)
    return zarr.open_group(path, mode="r+"), True


def _tiles(window, tile):
    r0, c0, h, w = window
    for tr in range(0, h, tile):  # tiles of the window
        for tc in range(0, w, tile):
            yield tr, tc, min(tile, h - tr), min(tile, w - tc)


def _render_frame(ms, vertices, neutral, map_shape, window, table, tile, halos, backend, group, index):
    r0, c0, h, w = window
    stats = []
    for tr, tc, th, tw in _tiles(window, tile):
        halo = halos[tr, tc]
        er0, ec0 = max(0, r0 + tr - halo), max(0, c0 + tc - halo)
        er1, ec1 = min(map_shape[0], r0 + tr + th + halo), min(map_shape[1], c0 + tc + tw + halo)
        # The expanded tile, clipped to the window (the neutral map covers only the window).
        er0, ec0, er1, ec1 = max(er0, r0), max(ec0, c0), min(er1, r0 + h), min(ec1, c0 + w)
        strain = ms.texels_strain(vertices, map_shape, (er0, ec0, er1 - er0, ec1 - ec0))
        try:
            res = deform_microstructure(neutral[er0 - r0 : er1 - r0, ec0 - c0 : ec1 - c0], strain, table,
                                        backend=backend)  # fmt: skip
        except ValidationError as exc:
            if not str(exc).startswith("texel_um "):
                raise
            raise ValidationError(
                f"frame {index}: the mesh maps texels of the map rows {er0}-{er1 - 1}, columns {ec0}-{ec1 - 1} to "
                f"far less surface than a texel of the kernels needs ({exc}): a mesh in another unit than mm (pass "
                "--scale, e.g. 1000 for m), or a sliver triangle (near-zero area) there in the neutral mesh, whose "
                "UV-to-surface scale spreads to its neighbours' texels"
            ) from None
        ir, ic = r0 + tr - er0, c0 + tc - ec0
        sl = (slice(ir, ir + th), slice(ic, ic + tw))
        group["displacement"][index, tr : tr + th, tc : tc + tw] = res.displacement[sl]
        group["normal"][index, tr : tr + th, tc : tc + tw] = res.normals[sl]
        ok = strain.valid[sl]
        stats.append((strain.r_s[sl][ok], strain.r_t[sl][ok], strain.n_degenerate))
    r_s = np.concatenate([s[0] for s in stats])
    r_t = np.concatenate([s[1] for s in stats])
    n_degenerate = stats[0][2] if stats else 0
    if r_s.size and n_degenerate < len(ms.triangles):
        pct = (np.percentile(r_s, [1, 50, 99]), np.percentile(r_t, [1, 50, 99]))
    else:  # every triangle degenerate (a collapsed frame): no strain measured, not "no strain"
        pct = (np.full(3, np.nan), np.full(3, np.nan))
        warnings.warn(
            f"frame {index}: no valid strain ({n_degenerate} of {len(ms.triangles)} triangles degenerate: a "
            "collapsed frame?); its maps are the neutral ones and its stretch percentiles NaN",
            FacestatsWarning,
            stacklevel=3,
        )
    group["stretch"][index] = np.concatenate([*pct, [n_degenerate]])


def _exr_targets(exr_dir, index):
    return {
        "displacement": os.path.join(exr_dir, f"displacement.{index:05d}.exr"),
        "normal": os.path.join(exr_dir, f"normal.{index:05d}.exr"),
    }


def _exr_current(exr_dir, index, render_id) -> bool:
    """Whether both EXR files of frame ``index`` exist and were written from this render (their header says so),
    the normals in today's convention (``normal_space``: files of before 2026-12-06 held G down the texture and
    were kept by a rerun, a review)."""
    token = f"{render_id}:{index}"
    for kind, target in _exr_targets(exr_dir, index).items():
        try:
            attrs = read_exr_attributes(target)
        except (FacestatsError, OSError):
            return False
        if attrs.get("facestats_render") != token or (
            kind == "normal" and attrs.get("normal_space") != EXR_NORMAL_SPACE
        ):
            return False
    return True


def _write_exr(group, index, exr_dir, name, render_id):
    """Write frame ``index``'s EXR files (replacing any), each through a temporary name and a rename.

    The header attribute ``facestats_render`` (SHA-256 of the render's inputs : frame index) tells a later run
    whether a file in the folder is this frame of this render (:func:`_exr_current`).
    """
    os.makedirs(exr_dir, exist_ok=True)
    config = json.loads(group.attrs["config"])
    where = {"map_shape": json.dumps(config["map_shape"]), "window": json.dumps(config["window"])}
    attributes = {"frame": name, "facestats_render": f"{render_id}:{index}", **where}
    for kind, target in _exr_targets(exr_dir, index).items():
        tmp = target[:-4] + ".partial.exr"
        data = np.asarray(group[kind][index])
        if kind == "displacement":
            write_displacement(tmp, data, attributes=attributes)
        else:  # as the export's tangent-space maps: G up the texture (the group keeps t_v down the map)
            write_exr(tmp, {"R": data[..., 0], "G": -data[..., 1], "B": data[..., 2]},
                      attributes={**attributes, "units": "1", "normal_space": EXR_NORMAL_SPACE})  # fmt: skip
        os.replace(tmp, target)


def _check_window(neutral, map_shape, window):
    """(map_shape, window) as ints, checked (:func:`~facestats.core.validate.check_window`), the neutral map covering
    the window."""
    map_shape, window = check_window(neutral.shape if map_shape is None else map_shape, window)
    if neutral.shape != (window[2], window[3]):
        raise ValidationError(f"neutral_map must cover the window {window[2]} x {window[3]}, got shape {neutral.shape}")
    return map_shape, window


def _check_table(table):
    if isinstance(table, str):
        check_choice(table, "table", tuple(TABLES))
    elif not isinstance(table, KernelTable):
        raise ValidationError(f"table must be a table name or a KernelTable, got {type(table).__name__}")


def render_sequence(
    sequence,
    neutral_map,
    out,
    *,
    map_shape=None,
    window=None,
    table="forehead",
    exr_dir=None,
    tile=512,
    backend="auto",
    progress=True,
    overwrite=False,
) -> SequenceReport:
    """Render per-frame deformed displacement and normal maps of a mesh sequence (module docstring).

    Parameters
    ----------
    sequence : FrameSequence or BlendshapeSequence
        Frames on the topology of ``sequence.neutral`` (a mesh with UVs).
    neutral_map : ndarray (H, W) or path-like
        Neutral displacement map in µm over ``window`` (a path is read by
        :func:`facestats.io.displacement.read_displacement`).  A map ``facestats microstructure generate``
        wrote records its texel size: one that differs from the mesh's (:func:`mesh_texel_um`) by more than
        :data:`TEXEL_SIZE_TOLERANCE` is refused.
    out : path-like
        Zarr group to write (created; reopened and continued if it holds the same render).
    map_shape : (int, int), optional
        Size of the whole UV map in texels (default: the neutral map's shape).
    window : (row0, col0, height, width), optional
        Part of the map to render (default: all); the neutral map covers exactly it.
    table : str or KernelTable
        Kernel table (default the forehead table, eq. 8-9).
    exr_dir : path-like, optional
        Also write one displacement and one normal EXR per frame there.
    tile : int
        Tile side in texels (memory bound; the result does not depend on it).
    backend : {"auto", "numba", "numpy"}
    progress : bool
        Progress bar over frames.
    overwrite : bool
        Replace ``out`` if it holds a render of other inputs (a path that is not a render is never
        replaced: the call refuses).

    Returns
    -------
    SequenceReport
    """
    neutral = _neutral_map(neutral_map)
    tile = check_integer(tile, "tile", 16)
    map_shape, window = _check_window(neutral, map_shape, window)
    _check_table(table)
    backend = resolve_backend(backend)
    mesh = sequence.neutral.require_uv()
    ms = MeshStrain(mesh.vertices, mesh.triangles, mesh.uv, mesh.uv_triangles)
    n_slivers = int(np.count_nonzero(ms.rest_slivers))
    if n_slivers:
        warnings.warn(
            f"the neutral mesh has {n_slivers} sliver triangle(s) (near-zero area under UV triangles of ordinary "
            f"size: more than {SLIVER_RATIO:g}x the median UV per mm), e.g. triangle "
            f"{int(np.flatnonzero(ms.rest_slivers)[0])}; they are masked like degenerate ones: their texels get no "
            "strain and their neighbours' texel sizes leave them out",
            FacestatsWarning,
            stacklevel=2,
        )
    if isinstance(neutral_map, (str, os.PathLike)):
        _check_generated_map(neutral_map, ms, map_shape, window)
    n = len(sequence)
    names = sequence.frame_names()
    exr = _check_exr_dir(exr_dir, n)
    config = _config(sequence, neutral, map_shape, window, table, names)
    group, created = _open_group(out, config, n, window, tile, overwrite)
    report = SequenceReport(os.fspath(out), n, map_shape=map_shape, window=window)
    try:
        _render_frames(sequence, ms, neutral, map_shape, window, table, tile, backend, group, exr, names, config,
                       progress, report)  # fmt: skip
    except FacestatsError:  # bad input found while rendering (a mesh, a frame): a new render leaves nothing behind
        if created:
            import shutil

            shutil.rmtree(os.fspath(out), ignore_errors=True)
        raise
    return report


def _render_frames(sequence, ms, neutral, map_shape, window, table, tile, backend, group, exr, names, config,
                   progress, report):  # fmt: skip
    """The frames of :func:`render_sequence` not yet done, into ``group`` (and ``exr``), counted in ``report``."""
    render_id = hashlib.sha256(json.dumps(config, sort_keys=True).encode()).hexdigest()
    density = _TexelDensity(ms, map_shape)
    halos = {  # per tile, the same for every frame (the rest mesh decides them)
        (tr, tc): density.halo((window[0] + tr, window[1] + tc, th, tw)) for tr, tc, th, tw in _tiles(window, tile)
    }
    done = np.asarray(group["done"][:])
    start = time.perf_counter()
    frames = progress_bar(range(len(sequence)), desc="microstructure", unit="frame", enabled=progress)
    for i in frames:  # loop over frames
        if done[i]:
            report.skipped.append(i)
        else:
            vertices = sequence.frame(i)
            _render_frame(ms, vertices, neutral, map_shape, window, table, tile, halos, backend, group, i)
            report.rendered.append(i)
        if exr is not None and not (done[i] and _exr_current(exr, i, render_id)):
            _write_exr(group, i, exr, names[i], render_id)
        group["done"][i] = True
    report.seconds = time.perf_counter() - start


def open_sequence(neutral, *, frames=None, targets=None, weights=None, scale=1.0):
    """A mesh sequence from files: a neutral OBJ/PLY and either frame files or blendshape targets with a weights CSV.

    Parameters
    ----------
    neutral : path-like
        Neutral mesh with UVs, or an ICT-FaceKit checkout directory (face area, expressions as targets).
    frames : sequence of path-like, optional
        One OBJ/PLY per frame.
    targets : sequence of path-like, optional
        Blendshape target meshes (their file stems name the weight columns); with an
        ICT-FaceKit directory, expression names.
    weights : path-like, optional
        CSV of per-frame weights (:func:`facestats.io.mesh_sequence.read_weights`).
    scale : float
        Factor of the mesh files' units to mm (10 for cm).  An ICT-FaceKit directory is read in mm
        whatever ``scale`` is, but frame files given with it are scaled by ``scale`` (ICT-FaceKit's own
        OBJ files are in cm: pass 10).  A frame whose extent differs from the neutral's by more than 2×
        is refused (wrong units).

    Raises
    ------
    ValidationError
        Among others, a neutral, frame or target file that does not exist or is not .obj/.ply, the message
        starting with its parameter (``frames must be .obj or .ply, got 'f.txt'``), before any file is read.
    """
    scale = as_scalar(scale, "scale", 0, None, low_inclusive=False)  # checked also for an ICT-FaceKit folder
    if (frames is None) == (weights is None):
        raise ValidationError("pass either frames or weights (with targets), got " + ("both" if frames else "neither"))
    if frames is not None and targets is not None:
        raise ValidationError("targets go with weights (blendshapes), not with frames; got both frames and targets")
    if os.path.isdir(os.fspath(neutral)):  # an ICT-FaceKit folder: checked as it is read, then the frames
        names_w, w = read_weights(weights) if weights is not None else (None, None)
        if targets is not None and names_w is not None:
            _check_targets_weighted([str(t) for t in targets], names_w, weights)
        mesh, shapes = read_ict_facekit(neutral, names_w if targets is None else list(targets))
        _check_mesh_files(frames=frames)
        if frames is not None:
            return FrameSequence(mesh, frames, scale=scale)
        return BlendshapeSequence(mesh, shapes, w, names=names_w)
    _check_mesh_files(neutral=[neutral], frames=frames, targets=targets)  # every file before any is read
    mesh = read_mesh(neutral, scale=scale).require_uv()
    if frames is not None:
        return FrameSequence(mesh, frames, scale=scale)
    if not targets:  # only an ICT-FaceKit checkout names its blendshapes itself
        raise ValidationError(
            f"weights need targets: the blendshape meshes their columns name (or an ICT-FaceKit checkout as the "
            f"neutral), got weights {os.fspath(weights)!r} and no targets"
        )
    names_w, w = read_weights(weights)
    _check_targets_weighted([os.path.splitext(os.path.basename(os.fspath(t)))[0] for t in targets], names_w, weights)
    shapes = {
        os.path.splitext(os.path.basename(os.fspath(t)))[0]: read_vertices(t, mesh, scale=scale) for t in targets or []
    }
    return BlendshapeSequence(mesh, shapes, w, names=names_w)


def _check_mesh_files(**paths) -> None:
    """Refuse a file of ``paths`` (parameter name: its paths, or None) that is not an existing .obj or .ply file,
    naming the parameter and the file (:func:`facestats.io.mesh_sequence.check_mesh_file`): ``mesh file must be
    .obj`` did not say whether the neutral, a frame or a target (a red team of the command line)."""
    for name, files in paths.items():
        for path in files or []:
            check_mesh_file(path, name)


def _check_targets_weighted(names, columns, weights) -> None:
    """Refuse targets that no column of the weights CSV names: they would be read and then ignored."""
    unweighted = [n for n in names if n not in columns]
    if unweighted:
        raise ValidationError(
            f"targets {unweighted} are not columns of the weights {os.fspath(weights)!r} (its columns: "
            f"{list(columns)}): a target without weights would be ignored; add its column or leave it out"
        )


def render_files(neutral, neutral_map, out, *, frames=None, targets=None, weights=None, scale=1.0,
                 height_range_um=None, **options) -> SequenceReport:  # fmt: skip
    """:func:`render_sequence` of files (:func:`open_sequence`, read_displacement)."""

    sequence = open_sequence(neutral, frames=frames, targets=targets, weights=weights, scale=scale)
    if height_range_um is not None:  # an integer image: read here with its range (no texel size recorded)
        neutral_map = read_displacement(neutral_map, height_range_um=height_range_um)
    return render_sequence(sequence, neutral_map, out, **options)


def _check_subject_scale(ds, subject, size, texel_um, window) -> None:
    """Refuse a subject's map that would not be its face at the stated texel size, or a window off its face.

    The subject's region map spans its UV square; a map of ``size`` texels of ``texel_um`` µm covers a face only
    when that is the texel size the face's UV layout has at that size (within :data:`TEXEL_SIZE_TOLERANCE`, the
    render's rule, in the window): ``--size 512 --texel-um 15`` put all ten regions of a 200 mm face into 7.7 mm.
    The face is rebuilt from the subject's recorded geometry (:func:`facestats.io.mesh.subject_mesh`); a subject
    whose face facestats cannot rebuild (a scan) is not checked for scale.
    """
    (r0, c0, h, w) = window
    labels = region_labels(np.asarray(ds["region"].values), size, window)
    if not np.any(labels > 0):
        raise ValidationError(
            f"window {list(window)} of a {size} x {size} map holds no face texel of subject {subject!r} (its region "
            "map is 0 there, off the face): give a window on the face (--window ROW0 COL0 H W)"
        )
    name = recorded_geometry(ds)
    try:
        parse_face_name(str(name or ""))
    except ValidationError:
        return
    face = subject_mesh(ds)
    local = mesh_texel_um(MeshStrain(face.vertices, face.faces, face.uv), (size, size), window)
    if not np.isfinite(local) or 1 / TEXEL_SIZE_TOLERANCE <= local / texel_um <= TEXEL_SIZE_TOLERANCE:
        return
    where = "" if (h, w) == (size, size) else f" in the window {list(window)}"
    fit = int(round(size * local / texel_um))
    largest = ""
    if fit > MAX_NEUTRAL_MAP_SIZE:
        at_most = local * size / MAX_NEUTRAL_MAP_SIZE
        largest = f", above the largest, {MAX_NEUTRAL_MAP_SIZE}, at which they are {at_most:.3g} um"
    raise ValidationError(
        f"texel_um {texel_um:g} um does not fit the face of subject {subject!r} ({name}): its UV layout maps a "
        f"{size} x {size} map at {local:.3g} um per texel (median over its triangles{where}), so the microstructure "
        f"would be {local / texel_um:.2g}x its size on the face and its regions squeezed as much ({size} texels "
        f"of {texel_um:g} um span {size * texel_um / 1000:.3g} mm, {size} of the face's {size * local / 1000:.3g} "
        f"mm). Give the face's texel size at this size (--texel-um {local:.3g}; texel_um), or "
        f"the map size whose texels are {texel_um:g} um (--size about {fit}{largest}; size) with a window of it "
        "(--window ROW0 COL0 H W; window) for a patch of the face at that scale (docs/microstructure.md)"
    )


def generate_neutral_map(out, size, *, texel_um=15.0, subject=None, store=None, seed=None, window=None):
    """Write a procedural neutral microstructure map (EXR, µm) for a store subject or generic skin, or a window of one.

    Every argument is checked before any work (the output path first: an
    existing directory, a path under a file such as ``/dev/null/x.exr`` or
    another suffix than ``.exr`` fail at once); the file is written under a
    temporary name and renamed into place, so a failure leaves no partial file
    and no folder the call created.

    A subject's map is its face: ``size`` × ``texel_um`` must be the size its face's UV layout has at ``size``
    (the median texel size of the face's triangles, in the window, within :data:`TEXEL_SIZE_TOLERANCE`;
    refused otherwise, naming both), and a ``window`` of it is a patch of the face at that scale with the
    regions that lie there, the window :func:`render_sequence` renders with ``map_shape = (size, size)``.  The
    file records ``texel_um`` and, for a subject or a window, ``map_shape`` and ``window`` (JSON), which
    :func:`render_sequence` compares with its own.

    Parameters
    ----------
    out : path-like
        ``.exr`` file to write (missing parent folders are created).
    size : int
        Side in texels of the whole map, in [2, :data:`MAX_NEUTRAL_MAP_SIZE`] (the file's, without ``window``).
    texel_um : float
        µm per texel, in (0, 1000].
    subject : str, optional
        Store subject id: regions and roughness from its maps
        (:func:`facestats.acquire.synthetic.microstructure.subject_microstructure`).
    store : path-like, optional
        Store to read the subject from (default: the embedded store).
    seed : int, optional
        Seed, an integer >= 0 (default: from the subject id, or 0).
    window : (row0, col0, height, width), optional
        Write only these texels of the whole map (inside it; on the subject's face).

    Returns
    -------
    str
        The path written.

    Raises
    ------
    ValidationError
        An argument out of its domain, or ``out`` not a writable ``.exr`` path; the message names it.
    FacestatsError
        The file could not be written (e.g. a full disk); nothing was left behind.
    """

    path = check_output_file(out, "out", (".exr",))
    size = check_integer(size, "size", 2, MAX_NEUTRAL_MAP_SIZE)
    texel_um = as_scalar(texel_um, "texel_um", 0.0, 1000.0, low_inclusive=False, unit="um")
    seed = None if seed is None else check_integer(seed, "seed", 0)
    placed = window is not None or subject is not None
    _, window = check_window(size, window)
    if subject is None:
        h = procedural_microstructure(size, texel_um, seed=0 if seed is None else seed, window=window)
        attrs = {"source": "facestats procedural microstructure (REGION_DEFAULTS, one region)"}
    else:
        with facestats.open_store(store) as st:
            ds = st.subject(subject, exclude=["micro_normal"])  # not used by the microstructure
        _check_subject_scale(ds, subject, size, texel_um, window)
        h = subject_microstructure(ds, size, texel_um, seed=seed, window=window)
        attrs = {"source": f"facestats procedural microstructure of subject {subject}"}
    attrs["texel_um"] = f"{texel_um:g}"
    if placed:
        attrs["map_shape"], attrs["window"] = json.dumps([size, size]), json.dumps(list(window))
    with OutputSet(path.parent) as files:
        try:
            write_displacement(files.path(path.name), h, attributes=attrs)
        except RuntimeError as exc:  # OpenEXR reports a failed write so
            raise FacestatsError(f"cannot write out {str(path)!r}: {exc}") from None
    return os.fspath(files.written[0])
