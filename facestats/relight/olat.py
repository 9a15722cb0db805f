"""One-light-at-a-time (OLAT) and photometric-stereo folders read as reflectance fields.

One job: turn a folder of images, each lit by one known distant light, into a
reflectance field (:func:`facestats.relight.field.make_field`): each image divided by its
light's RGB intensity, in linear radiometry.  Two layouts:

**DiLiGenT** (Shi et al. 2016): ``filenames.txt`` (one image per line),
``light_directions.txt`` (one unit vector per line, same order),
optional ``light_intensities.txt`` (RGB per line), ``mask.png`` and ground-truth
normals (``Normal_gt.mat`` variable ``Normal_gt``, ``normal.txt`` with one vector
per pixel in row-major order, or ``normals.npy``).  DiLiGenT's frame — x right,
y up, z towards the camera — is facestats's world frame seen by the frontal
camera, so directions and normals are used as given, and every pixel's view is
+z (:data:`DILIGENT_VIEW`, the orthographic approximation; the separation of
:func:`facestats.relight.separate.separate_field` needs a view).

**facestats OLAT manifest** (``olat.json``, for light stages)::

    {
      "format": "facestats-olat/1",
      "encoding": "srgb",                     # 8-bit images: "srgb" (default) or "linear"
      "mask": "mask.png",                     # optional
      "view": [0, 0, 1],                      # optional: unit vector to the camera
      "frames": [
        {"file": "l000.exr", "direction": [0.1, 0.9, 0.4], "intensity": [1, 0.97, 0.92]},
        {"file": "l001.exr", "phi_deg": 2.8, "theta_deg": -177.2},
        {"file": "full.png", "kind": "full_on"},
        {"file": "track.png", "kind": "tracking"}
      ]
    }

A frame is a light image (``"kind": "olat"``, the default) or an auxiliary
frame (``"full_on"``, ``"tracking"``, anything else) that is skipped and listed
in the field's ``skipped_frames`` attribute.  A light is given by ``direction``
(world frame of :mod:`facestats.model.sphere`, towards the light) or by
Debevec's angles ``phi_deg`` (polar from +y) and ``theta_deg`` (azimuth from −z
towards +x).  When the lights are exactly a lat-long light stage in row-major
order the field is a grid field (``light_phi``, ``light_theta``); otherwise a
list field with spherical-Voronoi solid angles.

Images: 16-bit PNG/TIFF and HDR files are linear; 8-bit images are decoded from
sRGB unless the encoding says linear (:func:`facestats.io.images.read_image`).
Errors name the file, the field and the value: a light list whose length
differs from the images, images of different sizes, missing files, bad
directions.
"""

from __future__ import annotations

import json
import os
import pathlib
import warnings

import numpy as np

from facestats.core.validate import as_float, check_choice, json_numbers
from facestats.errors import FacestatsWarning, FormatError, ValidationError
from facestats.io.images import INTEGER_EXTENSIONS, read_image, read_integer_image
from facestats.model.sphere import direction_from_angles, latlong_directions
from facestats.relight.field import make_field

__all__ = ["MANIFEST_NAME", "read_olat_folder", "write_olat_manifest", "read_ground_truth_normals"]

MANIFEST_NAME = "olat.json"
_GRID_TOL = 1e-6


def _read_rows(path: pathlib.Path, width: int, what: str) -> np.ndarray:
    """Rows of ``width`` finite numbers from a text file (``what`` names its contents in messages)."""
    if not path.is_file():
        raise ValidationError(f"{what} file {str(path)!r} does not exist")
    try:
        a = np.loadtxt(path, ndmin=2, dtype=np.float64, encoding="utf-8")
    except (ValueError, UnicodeDecodeError) as exc:
        raise FormatError(f"{str(path)!r}: cannot read numbers: {exc}") from None
    if a.shape[1] != width:
        raise FormatError(f"{str(path)!r}: each line must hold {width} numbers, got {a.shape[1]}")
    if not np.all(np.isfinite(a)):
        row = int(np.flatnonzero(~np.isfinite(a).all(1))[0])
        raise ValidationError(f"{str(path)!r}: {what} must be finite, got {a[row].tolist()} on line {row + 1}")
    return a


def _inside(folder, name, what):
    """``folder / name`` for a relative ``name`` that stays inside the folder (no absolute path, no ``..``): a
    listing never makes the reader open a file elsewhere."""
    parts = pathlib.PurePath(name).parts
    if pathlib.PurePath(name).is_absolute() or ".." in parts or not parts:
        raise ValidationError(
            f"{what} {name!r} must be a path inside the folder {str(folder)!r} (relative, without '..')"
        )
    return folder / name


def _load_images(folder, names, srgb):
    """Stack of images (L, H, W, 3) float32, checked for existence, values and a common size (loop over files),
    whether any 8-bit image was decoded from sRGB, and the number of clipped pixels per light (a channel at the
    top code of an integer image)."""

    stack = None
    decoded = False
    clipped = np.zeros(len(names), np.int64)
    for k, name in enumerate(names):
        p = _inside(folder, name, f"image of light {k}")
        if not p.is_file():
            raise ValidationError(f"image {str(p)!r} listed for light {k} does not exist")
        if p.suffix.lower() in INTEGER_EXTENSIONS:
            codes, bits = read_integer_image(p)
            clipped[k] = np.count_nonzero((codes[..., :3] >= 2**bits - 1).any(-1))  # (H, W, C) codes
            img = read_image(p, srgb=bool(srgb) and bits == 8)
            decoded |= bool(srgb) and bits == 8
        else:
            img = read_image(p)
            bad = ~(np.isfinite(img) & (img >= 0))  # a reflectance field holds values >= 0: say where one is not
            if bad.any():
                y, x = np.argwhere(bad.any(-1))[0]
                raise ValidationError(
                    f"image {str(p)!r} (light {k}) must hold finite values >= 0, got {img[y, x].tolist()} at "
                    f"pixel (x={x}, y={y}) (clip a dark-subtracted frame's negative noise to 0 first)"
                )
        if img.shape[2] == 1:
            img = np.repeat(img, 3, axis=2)
        img = img[..., :3]
        if stack is None:
            stack = np.empty((len(names),) + img.shape, np.float32)
        elif img.shape != stack.shape[1:]:
            raise ValidationError(
                f"image {str(p)!r} has size {img.shape[1]} x {img.shape[0]}, but {str(folder / names[0])!r} has "
                f"{stack.shape[2]} x {stack.shape[1]}: all images of a folder must have one size"
            )
        stack[k] = img
    return stack, decoded, clipped


def _intensities(values, folder):
    """The light intensities (L, 3) as float32, each a normal float32 number (neither overflowing to inf nor
    underflowing to 0, which would turn its image into zeros or infinities)."""
    it = as_float(values, f"light intensities of {str(folder)!r}", np.float32)
    tiny = float(np.finfo(np.float32).tiny)
    small = it < tiny
    if small.any():
        k = int(np.argwhere(small)[0][0])
        raise ValidationError(
            f"light intensities of {str(folder)!r} must be at least {tiny:.4g} (the smallest normal float32), got "
            f"{np.asarray(values)[k].tolist()} for light {k}"
        )
    return it


def _read_mask(path: pathlib.Path, shape):
    raw, _ = read_integer_image(path)
    m = raw[..., 0] > 0
    if m.shape != shape:
        raise ValidationError(f"mask {str(path)!r} has shape {m.shape}, images have {shape}")
    return m


def read_ground_truth_normals(folder, shape=None):
    """Ground-truth normals of a DiLiGenT-style folder (H, W, 3), or None if the folder has none.

    Parameters
    ----------
    folder : str or path-like
        The DiLiGenT-style folder; ``Normal_gt.mat`` is read first, else ``normals.npy``, else ``normal.txt``.
    shape : tuple of int, optional
        ``(H, W)`` of the images: checked against the normals, and needed to read ``normal.txt`` (one row per pixel,
        row-major), which is ignored without it.

    Returns
    -------
    ndarray of float64, shape (H, W, 3) or None
        Unit normals, (0, 0, 0) off the object, as stored.

    Raises
    ------
    FormatError
        A ``Normal_gt.mat`` without the variable ``Normal_gt``, an unreadable file, non-numeric values, or a
        ``normal.txt`` whose row count is not H·W.
    ValidationError
        Normals of another shape, or not unit length (within 1e-3) nor (0, 0, 0).
    """
    folder = pathlib.Path(os.fspath(folder))
    mat, txt, npy = folder / "Normal_gt.mat", folder / "normal.txt", folder / "normals.npy"
    if mat.is_file():
        from facestats.io.matlab import read_mat

        src = mat
        variables, _ = read_mat(mat)
        if "Normal_gt" not in variables:
            raise FormatError(f"{str(mat)!r} must hold the variable 'Normal_gt'")
        n = variables["Normal_gt"]
    elif npy.is_file():
        from facestats.io.images import read_npy

        src = npy
        n = read_npy(npy, "ground-truth normals")
    elif txt.is_file() and shape is not None:
        src = txt
        n = _read_rows(txt, 3, "ground-truth normals")
        if n.shape[0] != int(np.prod(shape)):
            raise FormatError(f"{str(txt)!r} must hold one normal per pixel ({int(np.prod(shape))}), got {n.shape[0]}")
        n = n.reshape(tuple(shape) + (3,))
    else:
        return None
    try:
        n = np.asarray(n, np.float64)
    except (TypeError, ValueError):
        raise FormatError(f"ground-truth normals {str(src)!r} must be numeric, got dtype {n.dtype}") from None
    if n.ndim != 3 or n.shape[2] != 3 or (shape is not None and n.shape[:2] != tuple(shape)):
        want = f"{tuple(shape) + (3,)}" if shape is not None else "(H, W, 3)"
        raise ValidationError(f"ground-truth normals {str(src)!r} must have shape {want}, got {n.shape}")
    length = np.linalg.norm(n, axis=-1)
    bad = ~np.isfinite(length) | ((length > 1e-6) & (np.abs(length - 1) > 1e-3))
    if bad.any():  # unit normals, or (0, 0, 0) off the object as DiLiGenT stores them
        r, c = (int(i) for i in np.argwhere(bad)[0])
        raise ValidationError(
            f"ground-truth normals {str(src)!r} must be unit vectors (or 0, 0, 0 off the object), got "
            f"{n[r, c].tolist()} (length {length[r, c]:.6g}) at pixel ({r}, {c}) and {int(bad.sum()) - 1} more"
        )
    return n


def _diligent(folder: pathlib.Path, srgb):
    names_file = folder / "filenames.txt"
    if not names_file.is_file():
        raise ValidationError(f"DiLiGenT folder {str(folder)!r} must hold filenames.txt")
    try:
        names = [ln.strip() for ln in names_file.read_text(encoding="utf-8").splitlines() if ln.strip()]
    except UnicodeDecodeError as exc:
        raise FormatError(f"{str(names_file)!r} must be UTF-8 text: {exc}") from None
    if not names:
        raise ValidationError(f"{str(names_file)!r} must list at least one image, got none")
    dirs = _read_rows(folder / "light_directions.txt", 3, "light directions")
    if dirs.shape[0] != len(names):
        raise ValidationError(
            f"{str(folder / 'light_directions.txt')!r} lists {dirs.shape[0]} lights but "
            f"{str(names_file)!r} lists {len(names)} images"
        )
    inten_file = folder / "light_intensities.txt"
    inten = _read_rows(inten_file, 3, "light intensities") if inten_file.is_file() else np.ones((len(names), 3))
    if inten.shape[0] != len(names):
        raise ValidationError(
            f"{str(inten_file)!r} lists {inten.shape[0]} intensities but there are {len(names)} images"
        )
    if np.any(inten <= 0):
        row = int(np.flatnonzero((inten <= 0).any(1))[0])
        raise ValidationError(f"{str(inten_file)!r}: light intensities must be > 0, got {inten[row].tolist()} on "
                              f"line {row + 1}")  # fmt: skip
    return {"names": names, "directions": dirs, "intensity": inten, "mask": "mask.png", "mask_required": False,
            "srgb": srgb, "view": DILIGENT_VIEW, "skipped": [], "layout": "diligent"}  # fmt: skip


#: The view of every pixel of a DiLiGenT folder: towards the camera along +z, the orthographic approximation the
#: layout's light directions and normals are given in (its frame: x right, y up, z towards the camera).
DILIGENT_VIEW = (0.0, 0.0, 1.0)


def _numbers(value, path, what):
    """``value`` (a JSON number or list of numbers) as float64 (:func:`json_numbers`), naming the file and field."""
    return json_numbers(value, f"{str(path)!r}: {what}")


def _unit_vector(value, path, what):
    d = _numbers(value, path, what)
    if d.shape != (3,) or abs(np.linalg.norm(d) - 1) > 1e-3:
        raise ValidationError(f"{str(path)!r}: {what} must be a unit 3-vector, got {value!r}")
    return d / np.linalg.norm(d)


def _frame_direction(fr, k, path):
    if "direction" in fr:
        return _unit_vector(fr["direction"], path, f"frame {k} ({fr['file']!r}) direction")
    if "phi_deg" in fr and "theta_deg" in fr:
        phi = _numbers(fr["phi_deg"], path, f"frame {k} ({fr['file']!r}) phi_deg")
        theta = _numbers(fr["theta_deg"], path, f"frame {k} ({fr['file']!r}) theta_deg")
        if phi.shape or theta.shape:
            raise FormatError(f"{str(path)!r}: frame {k} ({fr['file']!r}) phi_deg and theta_deg must be numbers, "
                              f"got {fr['phi_deg']!r} and {fr['theta_deg']!r}")  # fmt: skip
        return direction_from_angles(np.radians(float(phi)), np.radians(float(theta)))
    raise ValidationError(f"{str(path)!r}: frame {k} ({fr['file']!r}) needs 'direction' or 'phi_deg'+'theta_deg'")


def _frame_intensity(fr, k, path):
    it = _numbers(fr.get("intensity", [1.0, 1.0, 1.0]), path, f"frame {k} ({fr['file']!r}) intensity")
    it = np.repeat(it, 3) if it.shape == (1,) or it.ndim == 0 else it
    if it.shape != (3,) or np.any(it <= 0):
        raise ValidationError(
            f"{str(path)!r}: frame {k} ({fr['file']!r}) intensity must be 1 or 3 positive numbers, "
            f"got {fr.get('intensity')!r}"
        )
    return it


def _mask_and_view(man, path):
    """The manifest's optional mask file name and view direction (unit vector), checked."""
    mask = man.get("mask")
    if mask is not None and (not isinstance(mask, str) or not mask.strip()):
        raise FormatError(f"{str(path)!r}: mask must be a file name, got {mask!r}")
    view = man.get("view")
    return mask, None if view is None else _unit_vector(view, path, "view")


def _manifest(path: pathlib.Path, srgb):
    try:
        man = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as exc:  # (RecursionError: nesting deeper than Python's limit)
        raise FormatError(f"cannot read the OLAT manifest {str(path)!r}: {exc}") from None
    if not isinstance(man, dict):
        raise FormatError(f"{str(path)!r}: the manifest must be a JSON object, got {type(man).__name__}")
    if man.get("format", "facestats-olat/1") != "facestats-olat/1":
        raise ValidationError(f"{str(path)!r}: format must be 'facestats-olat/1', got {man.get('format')!r}")
    enc = man.get("encoding", "srgb")
    check_choice(enc, f"{path.name}: encoding", ("srgb", "linear"))
    frames = man.get("frames")
    if not isinstance(frames, list) or not frames:
        raise ValidationError(f"{str(path)!r}: 'frames' must be a non-empty list")
    mask, view = _mask_and_view(man, path)
    names, dirs, inten, skipped = [], [], [], []
    for k, fr in enumerate(frames):
        if not isinstance(fr, dict) or not isinstance(fr.get("file"), str) or not fr["file"].strip():
            raise ValidationError(f"{str(path)!r}: frame {k} must be an object with a 'file' name, got {fr!r}")
        if fr.get("kind", "olat") != "olat":
            skipped.append(fr["file"])
            continue
        names.append(fr["file"])
        dirs.append(_frame_direction(fr, k, path))
        inten.append(_frame_intensity(fr, k, path))
    if not names:
        raise ValidationError(f"{str(path)!r}: no light frame (every frame is of another kind)")
    srgb_eff = (enc == "srgb") if srgb is None else srgb
    return {"names": names, "directions": np.array(dirs), "intensity": np.array(inten), "mask": mask,
            "mask_required": mask is not None, "srgb": srgb_eff, "view": view, "skipped": skipped,
            "layout": "manifest"}  # fmt: skip


def _as_grid(dirs):
    """(n_phi, n_theta) when ``dirs`` is a lat-long light stage in row-major order, else None."""

    n = dirs.shape[0]
    for n_phi in range(1, n + 1):  # every divisor (a few dozen at most)
        if n % n_phi == 0:
            n_theta = n // n_phi
            ref = latlong_directions(n_phi, n_theta).reshape(-1, 3)
            if np.allclose(ref, dirs, atol=_GRID_TOL):
                return n_phi, n_theta
    return None


def _check_distinct(dirs, names, folder):
    """Two images under one light direction make the solid angles undefined: refuse, naming both."""
    order = np.lexsort(dirs.T)
    same = np.all(np.abs(np.diff(dirs[order], axis=0)) < 1e-9, axis=1)
    if same.any():
        a, b = order[np.flatnonzero(same)[0]], order[np.flatnonzero(same)[0] + 1]
        a, b = min(a, b), max(a, b)
        raise ValidationError(
            f"light directions of {str(folder)!r} must be distinct: {names[a]!r} (light {a}) and {names[b]!r} "
            f"(light {b}) both have {np.round(dirs[a], 6).tolist()}"
        )


def read_olat_folder(path, *, srgb=None):
    """Read an OLAT / photometric-stereo folder as a reflectance field (module docstring).

    Parameters
    ----------
    path : str or path-like
        The folder: with ``olat.json`` it is read as a facestats manifest,
        otherwise as DiLiGenT (``filenames.txt``, ``light_directions.txt``, ...).
    srgb : bool, optional
        Decode 8-bit images from sRGB (default: yes for DiLiGenT 8-bit images and
        per the manifest's ``encoding``); 16-bit and HDR images are always linear.

    Returns
    -------
    xarray.Dataset
        A reflectance field: images / intensities (the raw intensities kept as the
        ``intensity`` coordinate), ``mask``, ``normal_gt`` when the folder has
        ground truth, and attributes ``source``, ``layout``, ``files``,
        ``skipped_frames`` and ``clipped_pixels`` (per light, pixels with a
        channel at the top code of an integer image: read as that code, which
        biases them low; a :class:`~facestats.errors.FacestatsWarning` says how
        many).
    """
    folder = pathlib.Path(os.fspath(path))
    if not folder.is_dir():
        raise ValidationError(f"OLAT folder {str(folder)!r} does not exist")
    man = folder / MANIFEST_NAME
    spec = _manifest(man, srgb) if man.is_file() else _diligent(folder, True if srgb is None else srgb)
    names = list(spec["names"])
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        k = [i for i, n in enumerate(names) if n == twice[0]]
        raise ValidationError(f"image {twice[0]!r} of {str(folder)!r} is listed for lights {k}: each light has its own")
    dirs = spec["directions"]
    norm = np.linalg.norm(dirs, axis=1)
    if np.any(np.abs(norm - 1) > 1e-2):
        k = int(np.argmax(np.abs(norm - 1)))
        raise ValidationError(f"light direction {k} of {str(folder)!r} must be a unit vector, got norm {norm[k]:.4g}")
    dirs = dirs / norm[:, None]
    _check_distinct(dirs, spec["names"], folder)
    mask_path = _inside(folder, spec["mask"], "mask") if spec["mask"] else None
    if spec["mask_required"] and not mask_path.is_file():
        raise ValidationError(f"mask {str(mask_path)!r} named by {str(man)!r} does not exist")
    intensity = _intensities(spec["intensity"], folder)
    stack, decoded, clipped = _load_images(folder, spec["names"], spec["srgb"])
    if clipped.any():  # §3 leaves out invalid samples; a field has no way to mark them, so say so
        k = int(np.argmax(clipped))
        warnings.warn(
            f"OLAT folder {str(folder)!r}: {int(clipped.sum())} pixel(s) in {int(np.count_nonzero(clipped))} of "
            f"{clipped.size} image(s) are clipped at the top code (most in {spec['names'][k]!r}: {int(clipped[k])}); "
            "they are read as the top code, which biases their specular and their relights low (attribute "
            "clipped_pixels)",
            FacestatsWarning,
            stacklevel=2,
        )
    values = stack / intensity[:, None, None, :]
    h, w = stack.shape[1:3]
    mask = None
    if mask_path is not None and mask_path.is_file():
        mask = _read_mask(mask_path, (h, w))
    view = None if spec["view"] is None else np.broadcast_to(spec["view"], (h, w, 3))
    grid = _as_grid(dirs)
    attrs = {"source": f"OLAT folder {folder.name}", "layout": spec["layout"], "files": list(spec["names"]),
             "skipped_frames": list(spec["skipped"]), "srgb_decoded": decoded,
             "clipped_pixels": [int(c) for c in clipped]}  # fmt: skip
    if grid is not None:
        values = values.reshape(grid + (h, w, 3))
        d_in, inten = dirs.reshape(grid + (3,)), spec["intensity"].reshape(grid + (3,))
    else:
        d_in, inten = dirs, spec["intensity"]
    ds = make_field(values, d_in, intensity=inten, mask=mask, view=view, attrs=attrs)
    if grid is not None:
        ds.attrs["layout_lights"] = "latlong"
    gt = read_ground_truth_normals(folder, (h, w)) if spec["layout"] == "diligent" else None
    if gt is not None:
        ds["normal_gt"] = (("y", "x", "component"), gt.astype(np.float32))
    return ds


def write_olat_manifest(folder, files, directions, intensities=None, *, encoding="linear", mask=None, view=None,
                        extra_frames=None):  # fmt: skip
    """Write ``olat.json`` for images already in ``folder`` (lights in the facestats world frame).

    Parameters
    ----------
    folder : str or path-like
        The folder of the images; ``olat.json`` is written (replaced) there.
    files : sequence of str
        The light images' file names, relative to ``folder``.
    directions : array_like, shape (N, 3)
        Direction towards each file's light (world frame), written as given (the reader checks unit length).
    intensities : array_like, shape (N, 3), optional
        RGB intensity of each light (default all 1).
    encoding : {"srgb", "linear"}
        How the reader decodes 8-bit images.
    mask : str, optional
        File name of the mask image.
    view : array_like, shape (3,), optional
        Unit vector towards the camera.
    extra_frames : iterable of (str, str), optional
        ``(file, kind)`` pairs of auxiliary frames (full-on, tracking) that readers skip.

    Returns
    -------
    pathlib.Path
        The manifest written.

    Raises
    ------
    ValidationError
        ``directions`` or ``intensities`` not one 3-vector per file, or an unknown ``encoding``.
    """
    folder = pathlib.Path(os.fspath(folder))
    d = np.asarray(directions, np.float64).reshape(-1, 3)
    if len(files) != d.shape[0]:
        raise ValidationError(f"directions must hold one vector per file ({len(files)}), got {d.shape[0]}")
    it = np.ones_like(d) if intensities is None else np.asarray(intensities, np.float64).reshape(-1, 3)
    if it.shape != d.shape:
        raise ValidationError(f"intensities must hold one RGB triple per file, got shape {it.shape}")
    check_choice(encoding, "encoding", ("srgb", "linear"))
    frames = [{"file": str(f), "direction": dv.tolist(), "intensity": iv.tolist()} for f, dv, iv in zip(files, d, it)]
    frames += [{"file": str(f), "kind": str(k)} for f, k in (extra_frames or [])]
    man = {"format": "facestats-olat/1", "encoding": encoding, "frames": frames}
    if mask is not None:
        man["mask"] = str(mask)
    if view is not None:
        man["view"] = [float(x) for x in view]
    path = folder / MANIFEST_NAME
    path.write_text(json.dumps(man, indent=1))
    return path
