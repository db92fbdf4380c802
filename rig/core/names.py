"""The one rule for names (plan, station and device names) and the names derived from them.

A config name is 1 to 64 ASCII characters from `A-Z a-z 0-9 _ - .`, starting with a letter or a
digit: it is used as it is in file names (`<plan>-<stamp>.session`, `<session>.<dut>.<model>.yaml`),
so it can hold no path separator, no `..` lead, no space, quote or control character.

Names from elsewhere (a calibration file's `source.dut`, `rig export-cal --name`, an old session) may
hold anything; the transformations below turn any string into a safe file stem, C identifier or
header guard. They keep ASCII letters and digits, turn other ASCII characters into `_` and spell
every other character as `uXXXX`, so names that differ only in non-ASCII letters stay apart.
Where several names meet (the devices of a station, the DUTs of a report) `check_unique` refuses two
that map to the same file stem or C symbol (compared case-blind: some file systems are).

    SafeName                      # pydantic type for every config `name` field
    file_stem("mag ä/1")          # 'mag_u00e4_1'
    c_identifier("mag cal")       # 'mag_cal';  header_guard("mag cal") -> 'MAGRIG_MAG_CAL_H'
    check_unique(["m0", "M0"])    # ValueError: 'm0' and 'M0' give the same file name 'm0'
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable
from typing import Annotated

from pydantic import AfterValidator, StrictStr

MAX_NAME_LENGTH = 64
MAX_C_IDENTIFIER = 63  # significant initial characters of an internal identifier in C99
MAX_FILE_STEM = 100
NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")
NAME_RULE = f"1-{MAX_NAME_LENGTH} characters A-Z a-z 0-9 _ - ., starting with a letter or digit"


def check_name(name: str) -> str:
    """`name` if it follows the rule, else ValueError saying what is wrong."""
    if not isinstance(name, str):
        raise ValueError(f"a name must be text, got {name!r}")
    if len(name) > MAX_NAME_LENGTH:
        raise ValueError(f"{_show(name)} is {len(name)} characters long; at most {MAX_NAME_LENGTH}")
    if not NAME_RE.fullmatch(name):
        bad = next((c for c in name if not re.fullmatch(r"[A-Za-z0-9_.-]", c)), None)
        what = f"character {bad!r} is not allowed" if bad is not None else "a name must not start with . or -"
        raise ValueError(f"{_show(name)}: {what} (names: {NAME_RULE})")
    return name


SafeName = Annotated[StrictStr, AfterValidator(check_name)]


def _show(name: str, limit: int = 40) -> str:
    """A name for an error message: repr (no control characters leak), cut short."""
    return repr(name if len(name) <= limit else name[:limit] + "...")


def _spell(name: str, keep: str) -> str:
    """ASCII letters, digits and `keep` stay; other ASCII -> '_'; anything else -> '_uXXXX_'."""
    out = []
    for ch in name:
        if ch.isascii() and (ch.isalnum() or ch in keep):
            out.append(ch)
        elif ch.isascii():
            out.append("_")
        else:
            out.append(f"_u{ord(ch):04x}_")
    return "".join(out)


def _bounded(text: str, name: str, limit: int) -> str:
    """Long results keep their start plus a hash of the whole name, so they stay apart."""
    if len(text) <= limit:
        return text
    return f"{text[:limit - 9]}_{hashlib.sha256(name.encode('utf-8', 'surrogatepass')).hexdigest()[:8]}"


def file_stem(name: str) -> str:
    """A file-name part from any string: no separator, no leading dot or dash, never empty. A name
    that follows the rule is its own file stem."""
    stem = _spell(name, "_.-").lstrip(".-")
    return _bounded(stem, name, MAX_FILE_STEM) or "unnamed"


def c_identifier(name: str) -> str:
    """A C identifier from any string: lower-case letters, digits, single underscores; never starts
    with a digit or an underscore; short enough that `<ident>_apply` and `MAGRIG_<IDENT>_H` stay
    within C99's 63 significant characters."""
    ident = re.sub(r"_+", "_", _spell(name, "_")).strip("_").lower() or "cal"
    ident = f"cal_{ident}" if ident[0].isdigit() else ident
    return _bounded(ident, name, MAX_C_IDENTIFIER - len("MAGRIG__H"))


def header_guard(name: str) -> str:
    return f"MAGRIG_{c_identifier(name).upper()}_H"


def collision(names: Iterable[str]) -> tuple[int, str] | None:
    """(index, what is wrong) for the first name that gives the same file name or C symbol as an
    earlier one (compared case-blind: some file systems are), else None."""
    names = list(names)
    for what, transform in (("file name", file_stem), ("C symbol", c_identifier)):
        seen: dict[str, str] = {}
        for i, name in enumerate(names):
            key = transform(name).casefold()
            if key in seen and seen[key] != name:
                return i, (f"{_show(seen[key])} and {_show(name)} give the same {what} "
                           f"{transform(name)!r}; rename one")
            seen[key] = name
    return None


def check_unique(names: Iterable[str]) -> None:
    """ValueError naming both when two names give the same file name or C symbol."""
    problem = collision(names)
    if problem:
        raise ValueError(problem[1])
