"""The lab's XML files (model FORMATS §1, histograms §4): bounded, safe parsing and the
attribute and number syntax both write.

Files that users upload are parsed with defusedxml (no DTDs or entities) and refused
while they are read once they pass a limit below, so a hostile file costs bounded time
and memory. Numbers are C-locale decimals both ways (``core._files.decimal`` and ``parse_decimal``,
which the CSV files share).
"""

from __future__ import annotations

from pathlib import Path
from xml.etree.ElementTree import Element, TreeBuilder

import defusedxml.ElementTree as SafeET
from defusedxml import DefusedXmlException

from core._files import read_bounded

__all__ = [
    "MAX_ATTRIBUTE_CHARS", "MAX_XML_ATTRIBUTES", "MAX_XML_BYTES", "MAX_XML_DEPTH", "MAX_XML_ELEMENTS",
    "attribute", "parse",
]

# Limits on XML that users upload (model files and histogram files). Real files are far
# below them: a lab's model has tens of joints and takes a few kB; histograms of 100 DOFs
# at 360 bins take about 1 MB. They bound what a hostile file can cost (time and memory of
# the parse, size of error messages and of output column names). Read when a file is
# parsed, so a service may lower them.
MAX_XML_BYTES = 16 * 2**20  # bytes of a file or bytes object; characters of a str
MAX_XML_DEPTH = 16  # a model nests three deep (model > joint > dof)
MAX_XML_ELEMENTS = 100_000  # a 1000-joint model with three dofs per joint has ~7000
MAX_XML_ATTRIBUTES = 200_000  # in the whole file; a 1000-joint model has ~25,000
MAX_ATTRIBUTE_CHARS = 1024  # names, and numbers as core._files.decimal writes them (1e-300 takes 302)


def parse(source: str | bytes | Path, what: str, error: type[ValueError]) -> Element:
    """The root element of ``source`` (text, bytes or a path), refusing DTDs, entities and
    anything over the limits with ``error``; ``what`` names the file ("model file")."""
    data = read_bounded(source, MAX_XML_BYTES, what, error)
    try:
        _check_attribute_count(data, error)
        parser = SafeET.DefusedXMLParser(target=_BoundedTreeBuilder(error), forbid_dtd=True)
        parser.feed(data)
        return parser.close()
    except DefusedXmlException as exc:
        raise error(f"refused unsafe XML ({type(exc).__name__}): DTDs and entities are not allowed") from exc
    except SafeET.ParseError as exc:
        raise error(f"not well-formed XML: {exc}") from exc


def _check_attribute_count(data: str | bytes, error: type[ValueError]) -> None:
    """Refuse more than :data:`MAX_XML_ATTRIBUTES` attributes before parsing.

    expat hands an element's attributes over all at once: a million of them on one
    element cost seconds and hundreds of MB before any callback could object. Every
    attribute has one '=', so counting them (C speed) bounds the attributes from above.
    """
    equals = data.count(b"=" if isinstance(data, bytes) else "=")
    if equals > MAX_XML_ATTRIBUTES:
        raise error(f"more than {MAX_XML_ATTRIBUTES} attributes ({equals} '=' signs; MAX_XML_ATTRIBUTES)")


class _BoundedTreeBuilder(TreeBuilder):
    """A TreeBuilder that refuses depth, element count and lengths beyond the ``MAX_XML_*``
    limits while the file is read: expat is not recursive, but a tree a million elements
    deep or wide costs memory and time in every later walk."""

    def __init__(self, error: type[ValueError]) -> None:
        super().__init__()
        self._depth = self._elements = 0
        self._error = error

    def start(self, tag: str, attrs: dict[str, str]) -> Element:
        self._depth += 1
        self._elements += 1
        if self._depth > MAX_XML_DEPTH:
            raise self._error(f"elements are nested more than {MAX_XML_DEPTH} deep (MAX_XML_DEPTH)")
        if self._elements > MAX_XML_ELEMENTS:
            raise self._error(f"more than {MAX_XML_ELEMENTS} elements (MAX_XML_ELEMENTS)")
        _check_lengths(tag, attrs, self._error)
        return super().start(tag, attrs)

    def end(self, tag: str) -> Element:
        self._depth -= 1
        return super().end(tag)


def _check_lengths(tag: str, attrs: dict[str, str], error: type[ValueError]) -> None:
    """Refuse tag names, attribute names and values longer than :data:`MAX_ATTRIBUTE_CHARS`."""
    if len(tag) > MAX_ATTRIBUTE_CHARS:
        raise error(f"an element name is {len(tag)} characters long; at most {MAX_ATTRIBUTE_CHARS} "
                    "are allowed (MAX_ATTRIBUTE_CHARS)")
    for key, value in attrs.items():
        longest = max(len(key), len(value))
        if longest > MAX_ATTRIBUTE_CHARS:
            raise error(f"<{tag}> attribute {key[:40]!r} is {longest} characters long; at most "
                        f"{MAX_ATTRIBUTE_CHARS} are allowed (MAX_ATTRIBUTE_CHARS)")


def attribute(text: str) -> str:
    """Text for a double-quoted attribute; tab, LF, CR as references (raw ones would read back as spaces)."""
    return (
        text.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;").replace(">", "&gt;")
        .replace("\t", "&#9;").replace("\n", "&#10;").replace("\r", "&#13;")
    )
