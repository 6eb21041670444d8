"""Hardened XML: what every citylod reader of XML (CityGML, its appearances, KML) checks before parsing.

The parsers themselves run with entity resolution, network access and DTD loading off; this check refuses a
document whose DOCTYPE declares entities or names an external DTD before any parser sees it.
"""

from __future__ import annotations

import re
from pathlib import Path

from citylod.core.errors import InputError

_PROLOG_LIMIT = 1 << 20
_ENTITY_RE = re.compile(rb"<!ENTITY", re.IGNORECASE)
_DOCTYPE_RE = re.compile(rb"<!DOCTYPE", re.IGNORECASE)
_EXTERNAL_RE = re.compile(rb"<!DOCTYPE\s+[^\s\[>]+\s+(SYSTEM|PUBLIC)\b", re.IGNORECASE)


def check_xml_prolog(path: Path) -> None:
    """Refuse a DOCTYPE that declares entities or names an external DTD (entity bombs, XXE).

    A DOCTYPE can only stand in the prolog, and ``<!ENTITY`` cannot appear literally in element content
    ('<' must be escaped there), so a search of the first megabyte is enough. UTF-16 files are read with
    their zero bytes removed, which keeps ASCII markup readable.
    """
    with open(path, "rb") as fh:
        head = fh.read(_PROLOG_LIMIT).replace(b"\x00", b"")
    doctype = _DOCTYPE_RE.search(head)
    if doctype is None:
        return
    if _ENTITY_RE.search(head, doctype.start()) or _EXTERNAL_RE.search(head, doctype.start()):
        raise InputError("refused: the XML declares entities or an external DTD (possible entity-expansion "
                         "or external-entity attack)", path)
