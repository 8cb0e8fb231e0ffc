"""Program names: the rules a sent program must meet, and what a received one is called.

Rules by :class:`~opendnc.tape.profiles.Naming` (docs/tape.md#names):

* O-numbers: ``O`` and 1..``o_digits`` digits on the first program line (``O0001 (PART)``);
  a received program is stored as ``O0001.nc``;
* Fanuc 30i: an O-number or a name of up to 32 characters in ``<...>``;
* Okuma: ``$NAME.MIN`` before the ``%``: a letter and up to 15 letters or digits, an
  extension of up to 3; the name comes from the file name when sending;
* Siemens: ``%_N_NAME_MPF`` (or ``_SPF``), NAME up to 24 of ``0-9 A-Z a-z _``; from the
  file name when the file has no header; received as ``NAME.MPF``;
* Fagor: the header's comment (``%comment,MX,``, up to 20 characters) names the file.

A received name breaking these rules (an O-number with more digits than the profile's, an
Okuma, Sinumerik or Fagor name too long) is damage, not a name: :class:`TapeNameError`,
raised before any path is made of it (a block of 4096 characters is no file name the OS
takes).
"""

from __future__ import annotations

import re
from pathlib import Path

from opendnc.errors import InputError
from opendnc.tape.errors import TapeNameError
from opendnc.tape.profiles import Naming, Profile

_O_LINE = re.compile(r"^\s*O(\d+)")
_ANGLE = re.compile(r"^\s*<([^<>]{1,32})>")
_SIEMENS_HEAD = re.compile(r"^%(?:_N_)?([0-9A-Za-z_]+?)_(MPF|SPF)\s*$")
SIEMENS_MAX = 24  # characters of a Sinumerik program name (S-HMI, S-ONE)
FAGOR_MAX = 20  # characters of a Fagor header comment (FAG)
_SIEMENS_NAME = re.compile(rf"^[0-9A-Za-z_]{{1,{SIEMENS_MAX}}}$")
_OKUMA_NAME = re.compile(r"^[A-Z][A-Z0-9]{0,15}$")
_OKUMA_HEAD = re.compile(r"^\$([A-Z][A-Z0-9]{0,15})(?:\.([A-Z]{1,3}))?")
_SAFE = re.compile(r"[^0-9A-Za-z_.-]+")


def o_number(lines: list[str], digits: int) -> str | None:
    """``O1234`` from the first line that starts with an O-number, checking its length."""
    for text in lines:
        match = _O_LINE.match(text)
        if match:
            if len(match.group(1)) > digits:
                raise InputError(
                    f"O{match.group(1)} has more than {digits} digits, more than the control takes"
                )
            return "O" + match.group(1)
    return None


def okuma_name(path: Path) -> str:
    """``$`` header name for ``path``: its stem, upper case, which must follow Okuma's rule."""
    stem = path.stem.upper()
    if not _OKUMA_NAME.match(stem):
        raise InputError(
            f"{path.name}: an Okuma file name is a letter and up to 15 letters or digits"
        )
    return f"{stem}.MIN"


def siemens_name(path: Path) -> str:
    """The Siemens program name for ``path`` (its stem), checked."""
    stem = path.stem
    if not _SIEMENS_NAME.match(stem):
        raise InputError(
            f"{path.name}: a Sinumerik name is up to 24 of 0-9 A-Z a-z _ ({stem!r} is not)"
        )
    return stem


def check_send_name(profile: Profile, head: list[str], path: Path) -> None:
    """Refuse a program the control would not take under its name (before any byte goes)."""
    if profile.naming is Naming.O_NUMBER:
        if o_number(head, profile.o_digits) is None:
            raise InputError(
                f"{path.name}: no O-number line (O and up to {profile.o_digits} digits)"
            )
    elif profile.naming is Naming.FANUC_30I:
        if (
            not any(_ANGLE.match(text) for text in head)
            and o_number(head, profile.o_digits) is None
        ):
            raise InputError(f"{path.name}: no O-number line and no <NAME> line")
    elif profile.naming is Naming.OKUMA:
        okuma_name(path)
    elif profile.naming is Naming.SIEMENS:
        first = next((text.strip() for text in head if text.strip()), "")
        if not (first.startswith("%") and first != "%"):
            siemens_name(path)


def received_name(profile: Profile, label: list[str], program: list[str]) -> str | None:
    """The file name for a received program, or ``None`` when it carries no name."""
    if profile.naming in (Naming.O_NUMBER, Naming.FANUC_30I):
        for text in program[:3]:
            match = _O_LINE.match(text) or _ANGLE.match(text)
            if match:
                name = match.group(1)
                if match.re is not _O_LINE:
                    return _safe(name) + ".nc"
                if len(name) > profile.o_digits:
                    raise TapeNameError(
                        f"O{name}", f"an O-number has up to {profile.o_digits} digits here"
                    )
                return f"O{name}.nc"
        return None
    if profile.naming is Naming.OKUMA:
        for text in label:
            match = _OKUMA_HEAD.match(text.strip())
            if match:
                if text.strip()[match.end() : match.end() + 1].isalnum():
                    # more letters than the rule takes: refused, never cut to a shorter name
                    raise TapeNameError(
                        text.strip(), "an Okuma name is up to 16 characters, its extension 3"
                    )
                return f"{match.group(1)}.{match.group(2) or 'MIN'}"
        return None
    first = program[0].strip() if program else ""
    if profile.naming is Naming.SIEMENS:
        match = _SIEMENS_HEAD.match(first)
        if match is None:
            return None
        if len(match.group(1)) > SIEMENS_MAX:
            raise TapeNameError(
                match.group(1), f"a Sinumerik name is up to {SIEMENS_MAX} characters"
            )
        return f"{match.group(1)}.{match.group(2)}"
    # Fagor: %comment,flags,
    if first.startswith("%") and "," in first:
        comment = first[1:].split(",", 1)[0].strip()
        if len(comment) > FAGOR_MAX:
            raise TapeNameError(comment, f"a Fagor header comment is up to {FAGOR_MAX} characters")
        comment = _safe(comment)
        return f"{comment}.PIM" if comment else None
    return None


def _safe(name: str) -> str:
    return _SAFE.sub("_", name).strip("._") or "program"
