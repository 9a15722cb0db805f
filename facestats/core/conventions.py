"""Vocabulary shared across facestats: channels, regions, sites, conditions, skin types, genders.

Names follow Weyrich et al. 2006 and docs/architecture.md: Fitzpatrick skin types are the
integers 1-6 inside the library and Roman numerals at the boundary (the paper
groups I and II); face regions keep the numbering of Weyrich Fig. 15, which the
published MERL/ETH data files use.
"""

from __future__ import annotations

import re

from facestats.errors import ValidationError

__all__ = [
    "CHANNELS",
    "COMPONENTS",
    "REGIONS",
    "REGION_IDS",
    "SITES",
    "CONDITIONS",
    "GENDERS",
    "ROMAN",
    "AGE_GROUPS",
    "parse_skin_type",
    "skin_type_roman",
    "skin_type_label",
    "parse_gender",
    "parse_region",
    "parse_condition",
    "parse_age",
    "age_group",
    "DEFAULT_SEED",
    "DEFAULT_MAP_SIZE",
    "DEFAULT_STORE",
    "DEFAULT_EMULATED_SUBJECT",
    "TEXTURE_SAMPLE",
    "FLAG_BITS",
]

#: Colour channels (linear RGB).
CHANNELS = ("R", "G", "B")
#: Labels of the ``component`` dimension of vector maps (normals): x, y, z of the facestats world frame.
COMPONENTS = ("x", "y", "z")

#: Face regions of Weyrich et al. 2006 Fig. 15 (left).  The text names all but
#: region 5; facestats places it below the eyes, between eyelids and cheeks
#: (an assumption, see ``facestats.face.geometry``).
REGIONS = {
    1: "mustache",
    2: "forehead",
    3: "eyebrows",
    4: "eyelids",
    5: "under-eye",
    6: "nose",
    7: "cheeks",
    8: "lips",
    9: "chin",
    10: "beard",
}
REGION_IDS = tuple(REGIONS)

#: Contact-sensor measurement sites (Weyrich et al. 2006 §5.4).
SITES = ("cheek", "forehead", "neck")

#: External conditions of the one subject measured seven times (§7).
CONDITIONS = ("normal", "cold", "hot", "sweaty", "makeup", "lotion", "powder")

#: Provenance ``source`` (and index column ``source``) of subjects written by an edit: not measurements, so left
#: out of population statistics and of edit target subsets.
EDIT_SOURCE = "facestats.edit"

GENDERS = ("M", "F")

ROMAN = {1: "I", 2: "II", 3: "III", 4: "IV", 5: "V", 6: "VI"}
_FROM_ROMAN = {v: k for k, v in ROMAN.items()}

#: Age groups of §7: (label, min age, max age) inclusive.
AGE_GROUPS = (("20s", 0, 29), ("30s", 30, 39), ("40s", 40, 49), ("50s+", 50, 200))

#: Decimal numbers as typed on the command line: ASCII digits only.  ``str.isdigit`` and
#: ``int`` accept superscripts ('²') or other scripts' digits ('٣'), which no user means.
_ASCII_INT = re.compile(r"[0-9]{1,9}")


def _ascii_int(text: str):
    """``int(text)`` if ``text`` is 1-9 ASCII digits (matched in full), else None."""
    return int(text) if _ASCII_INT.fullmatch(text) else None


def _is_boolean(value) -> bool:
    """Whether ``value`` is a Python or numpy boolean (``int(True)`` is 1: a flag is no number here).

    Duck-typed on the numpy dtype kind, so that this module does not import numpy.
    """
    return isinstance(value, bool) or getattr(getattr(value, "dtype", None), "kind", None) == "b"


def parse_skin_type(value) -> int:
    """Fitzpatrick skin type as an int 1-6 from ``3``, ``"3"``, ``"III"`` or ``"iii"``.

    Parameters
    ----------
    value : int, float or str
        An integral number 1-6 (``3.0`` passes; a boolean does not), its ASCII digits, or a Roman numeral I-VI (any
        case, stripped).

    Returns
    -------
    int
        The skin type, 1-6.

    Raises
    ------
    ValidationError
        Anything else (also ``True``/``False``).
    """
    if _is_boolean(value):
        raise ValidationError(f"skin type must be I-VI or 1-6, got the boolean {value!r}")
    if isinstance(value, str):
        v = value.strip().upper()
        if v in _FROM_ROMAN:
            return _FROM_ROMAN[v]
        if _ascii_int(v) is None:
            raise ValidationError(f"skin type must be I-VI or 1-6, got {value!r}")
        value = _ascii_int(v)
    try:
        iv = int(value)
    except (TypeError, ValueError, OverflowError):
        raise ValidationError(f"skin type must be I-VI or 1-6, got {value!r}") from None
    if iv != value or iv not in ROMAN:
        raise ValidationError(f"skin type must be I-VI or 1-6, got {value!r}")
    return iv


def skin_type_roman(value) -> str:
    """Roman numeral of a skin type (``4`` → ``"IV"``).

    Parameters
    ----------
    value : int, float or str
        A skin type as :func:`parse_skin_type` reads it.

    Returns
    -------
    str
        ``"I"`` to ``"VI"``.

    Raises
    ------
    ValidationError
        ``value`` is not a skin type.
    """
    return ROMAN[parse_skin_type(value)]


def skin_type_label(value, grouped_i_ii=False) -> str:
    """Label of a skin type in text, figures and JSON: its Roman numeral, ``"I-II"`` for the pooled group.

    Weyrich et al. 2006 group types I and II (Table 2, Fig. 16 "II-VI"); an analysis that pools them codes
    the group as 2, which is labelled ``"I-II"``, not ``"II"``.

    Parameters
    ----------
    value : int, float or str
        A skin type as :func:`parse_skin_type` reads it.
    grouped_i_ii : bool
        Types I and II are pooled under 2.

    Returns
    -------
    str
        ``"I"`` to ``"VI"``, or ``"I-II"`` for 2 where ``grouped_i_ii``.

    Raises
    ------
    ValidationError
        ``value`` is not a skin type.
    """
    st = parse_skin_type(value)
    return "I-II" if grouped_i_ii and st == 2 else ROMAN[st]


def parse_gender(value) -> str:
    """``"M"`` or ``"F"`` from M/F, male/female (any case) or the paper's code 0 = M, 1 = F.

    Parameters
    ----------
    value : str, bytes or number
        ``"M"``, ``"male"``, ``"0"`` or 0 for M; ``"F"``, ``"female"``, ``"W"``, ``"1"`` or 1 for F (strings and
        UTF-8 bytes stripped, any case).

    Returns
    -------
    str
        ``"M"`` or ``"F"``.

    Raises
    ------
    ValidationError
        Anything else.
    """
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str):
        v = value.strip().upper()
        if v in ("M", "MALE", "0"):
            return "M"
        if v in ("F", "FEMALE", "1", "W"):
            return "F"
    else:
        try:
            if float(value) == 0:
                return "M"
            if float(value) == 1:
                return "F"
        except (TypeError, ValueError, OverflowError):
            pass
    raise ValidationError(f"gender must be M or F (or 0 = M, 1 = F), got {value!r}")


def parse_region(value) -> int:
    """Region number 1-10 from a number or a name of :data:`REGIONS` (singular accepted).

    Parameters
    ----------
    value : int, float or str
        An integral number 1-10 (not a boolean), its ASCII digits, or a region name (any case, stripped;
        ``"under-eye"`` also as ``"undereye"`` or ``"under eye"``).

    Returns
    -------
    int
        The region number of Weyrich et al. 2006 Fig. 15, 1-10.

    Raises
    ------
    ValidationError
        An unknown name, a number outside 1-10, or a boolean.
    """
    if _is_boolean(value):
        raise ValidationError(f"region must be 1-10 or a region name, got the boolean {value!r}")
    if isinstance(value, str):
        v = value.strip().lower()
        if _ascii_int(v) is not None:
            value = _ascii_int(v)
        else:
            for k, name in REGIONS.items():
                if v in (name, name.rstrip("s"), name.replace("-", ""), name.replace("-", " ")):
                    return k
            raise ValidationError(f"region must be 1-10 or one of {list(REGIONS.values())}, got {value!r}")
    try:
        iv = int(value)
    except (TypeError, ValueError, OverflowError):
        raise ValidationError(f"region must be 1-10 or a region name, got {value!r}") from None
    if iv not in REGIONS or iv != value:
        raise ValidationError(f"region must be 1-10 or a region name, got {value!r}")
    return iv


def parse_condition(value) -> str:
    """A condition name of :data:`CONDITIONS` (case-insensitive).

    Parameters
    ----------
    value : str
        The name (``str()`` of it is taken, stripped).

    Returns
    -------
    str
        The lower-case name, one of :data:`CONDITIONS`.

    Raises
    ------
    ValidationError
        Not a condition name.
    """
    v = str(value).strip().lower()
    if v not in CONDITIONS:
        raise ValidationError(f"condition must be one of {list(CONDITIONS)}, got {value!r}")
    return v


def parse_age(value) -> tuple[int, int]:
    """An inclusive age range from ``"20s"``, ``"30s"``, ``"40s"``, ``"50s+"``, ``"MIN-MAX"`` or one age.

    Parameters
    ----------
    value : str, int, or tuple/list of two
        A group label of :data:`AGE_GROUPS` (any case; ``"50s"`` and ``"50+"`` mean ``"50s+"``), ``"MIN-MAX"`` or
        one age in years (ASCII digits or an int), or a pair ``(MIN, MAX)`` of integers or digit strings.

    Returns
    -------
    tuple of int
        ``(min, max)`` in years, inclusive, with 0 ≤ min ≤ max ≤ 200 (one age gives ``(age, age)``).

    Raises
    ------
    ValidationError
        Unreadable, or not 0 ≤ MIN ≤ MAX ≤ 200.
    """
    if isinstance(value, (tuple, list)) and len(value) == 2:
        lo, hi = (_age_number(x) for x in value)
        if lo is None or hi is None:
            raise ValidationError(f"age range must be two ages in years (MIN, MAX), got {value!r}")
    else:
        v = str(value).strip().lower()
        for label, lo_, hi_ in AGE_GROUPS:
            if v == label.lower() or (label == "50s+" and v in ("50s", "50+")):
                return lo_, hi_
        a, _, b = v.partition("-")
        lo, hi = _ascii_int(a.strip()), _ascii_int((b if _ else a).strip())
        if lo is None or hi is None:
            raise ValidationError(f"age must be 20s, 30s, 40s, 50s+, MIN-MAX or an age in years, got {value!r}")
    if not (0 <= int(lo) <= int(hi) <= 200):
        raise ValidationError(f"age range must satisfy 0 <= MIN <= MAX <= 200, got {value!r}")
    return int(lo), int(hi)


def _age_number(x):
    """An age bound: an integral number (Python or numpy, not a boolean) or ASCII digits; None otherwise."""
    if isinstance(x, str):
        return _ascii_int(x.strip())
    if _is_boolean(x):
        return None
    try:
        iv = int(x)
    except (TypeError, ValueError, OverflowError):
        return None
    return iv if iv == x else None


def age_group(age) -> str:
    """The §7 age group label of an age in years.

    Ages are whole years, as in the store's index; the groups' integer bounds leave no room for a fraction.

    Parameters
    ----------
    age : int
        Age in whole years, 0-200 (an integral number, Python or numpy; ``30.0`` passes, a boolean does not).

    Returns
    -------
    str
        A label of :data:`AGE_GROUPS`: ``"20s"`` (0-29), ``"30s"``, ``"40s"`` or ``"50s+"`` (50-200).

    Raises
    ------
    ValidationError
        Not a whole number of years (e.g. 29.5, a string or a boolean), or outside 0-200.
    """
    a = None if isinstance(age, str) else _age_number(age)
    if a is None:
        raise ValidationError(f"age must be a whole number of years (an integer 0-200), got {age!r}")
    for label, lo, hi in AGE_GROUPS:
        if lo <= a <= hi:
            return label
    raise ValidationError(f"age must be in 0-200 years, got {age!r}")


#: Seed, map size (= lumitexel grid) and face of the embedded default store (``facestats build --default``):
#: the face is one of :data:`facestats.face.named.FACES`, ``"ict"`` the face area of
#: ICT-FaceKit's neutral head (:mod:`facestats.face.ict`).
DEFAULT_SEED = 2006
DEFAULT_MAP_SIZE = 48
DEFAULT_FACE = "ict"

#: The ``--store`` value that names the embedded store, as leaving ``--store`` out does (and as
#: ``facestats emulate --store default`` takes it); a directory of that name is written ``./default``.
#: ``open_store()`` with no path opens that store.
DEFAULT_STORE = "default"
#: The subject ``facestats emulate dome|sensor`` emulates without ``--subject``, and
#: :func:`facestats.acquire.devices.lab.emulated_dome` and ``emulated_sensor`` without ``subject_id``.
DEFAULT_EMULATED_SUBJECT = "S001"
#: The ``--store`` value that names the texture sample (:mod:`facestats.pipeline.texture_sample`);
#: a directory of that name is written ``./texture-sample``.
TEXTURE_SAMPLE = "texture-sample"

#: Bit flags of the fits of a texel (the ``ts_flag`` / ``bp_flag`` maps of a subject).
FLAG_BITS = {
    "few_samples": 1,  # fewer valid samples than the fit needs
    "not_converged": 2,  # the solver hit its iteration limit
    "ill_conditioned": 4,  # JᵀJ is (near) singular or a parameter's relative standard error is too large
    "at_bound": 8,  # a parameter ended on its bound
    "filled": 16,  # value interpolated from neighbours in UV (§5.3)
    "implausible": 32,  # the lobe parameter lies outside the range skin can have (model.fitting.solver.PLAUSIBLE_LOBE)
}
