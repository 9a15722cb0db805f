"""Subject identifiers: the one rule every id must pass, whatever its source.

Ids name directories of the store (``subjects/<id>/``), so an id is validated
before it is used in any path: from the population index, the API, the command
line or an imported file alike.
"""

from __future__ import annotations

import re

from facestats.errors import ValidationError

__all__ = ["SUBJECT_ID_PATTERN", "MAX_SUBJECT_ID_LENGTH", "RESERVED_NAME", "check_subject_id"]

#: 1-64 letters, digits, '.', '_' or '-', starting with a letter or digit (matched in full:
#: no path separators, no '..' component, no trailing newline).
MAX_SUBJECT_ID_LENGTH = 64
SUBJECT_ID_PATTERN = re.compile(rf"[A-Za-z0-9][A-Za-z0-9._-]{{0,{MAX_SUBJECT_ID_LENGTH - 1}}}")
#: Names the rule keeps for the store itself: the Zarr group file beside the subject folders
#: (``subjects/zarr.json``) and its temporary names while it is replaced (``zarr.json.tmp-<pid>-<hex>``).
RESERVED_NAME = "zarr.json"
RESERVED_TEMP = re.compile(r"zarr\.json\.tmp-.*")


def check_subject_id(sid) -> str:
    """``sid`` as a str if it is a valid subject id, else :class:`ValidationError` naming it.

    Parameters
    ----------
    sid : object
        A candidate id (converted with ``str``).

    Returns
    -------
    str
        The id.

    Raises
    ------
    ValidationError
        If it does not match :data:`SUBJECT_ID_PATTERN` in full, or is a name the store keeps for
        itself (:data:`RESERVED_NAME`, ``zarr.json``, and its temporary names).
    """
    text = str(sid)
    if not SUBJECT_ID_PATTERN.fullmatch(text):
        raise ValidationError(
            f"subject_id must be 1-64 characters of letters, digits, '.', '_' or '-' starting with a letter "
            f"or digit, got {text[:64]!r}" + (f"... ({len(text)} characters)" if len(text) > 64 else "")
        )
    if text == RESERVED_NAME or RESERVED_TEMP.fullmatch(text):
        raise ValidationError(
            f"subject_id must not be {RESERVED_NAME!r} or one of its temporary names ({RESERVED_NAME}.tmp-…): "
            f"the store's group files are named so, beside the subject folders; got {sid!r}"
        )
    return text
