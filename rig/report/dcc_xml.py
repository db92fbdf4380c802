"""The pieces of PTB's Digital Calibration Certificate (DCC 3.1.2, D-SI 2.1.0) the certificate's XML is
built of: elements in the `dcc:` and `si:` namespaces, localized text, rich content, D-SI quantities with
their expanded uncertainty or coverage interval, and statements. Numbers are written as Python writes a
float (repr), so that every value reads back exactly as the calibration file holds it.

The schema's order of elements is kept by each builder; a schema file to validate against is not needed
here (the tests validate every document written: tests/data/dcc/).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

DCC, SI = "https://ptb.de/dcc", "https://ptb.de/si"
SCHEMA_VERSION = "3.1.2"
LANG = "en"
ET.register_namespace("dcc", DCC)
ET.register_namespace("si", SI)


def _qname(tag: str) -> str:
    prefix, _, local = tag.partition(":")
    return f"{{{DCC if prefix == 'dcc' else SI}}}{local}"


def el(parent: ET.Element | None, tag: str, text: str | None = None, **attrs: str) -> ET.Element:
    """`dcc:name` or `si:value` under `parent` (a new root when None)."""
    node = ET.Element(_qname(tag), attrs) if parent is None else ET.SubElement(parent, _qname(tag), attrs)
    if text is not None:
        node.text = text
    return node


def text(parent: ET.Element, tag: str, content: str) -> ET.Element:
    """A dcc:textType: one dcc:content in English."""
    node = el(parent, tag)
    el(node, "dcc:content", content, lang=LANG)
    return node


def rich(parent: ET.Element, tag: str, *contents: str, name: str | None = None) -> ET.Element:
    """A dcc:richContentType: an optional name, then one dcc:content per paragraph."""
    node = el(parent, tag)
    if name is not None:
        text(node, "dcc:name", name)
    for content in contents:
        el(node, "dcc:content", content, lang=LANG)
    return node


def decimal(x: float) -> str:
    """si:decimalType: as Python writes the float (exact on reading back); a non-finite value has no
    place in a certificate."""
    x = float(x)
    if not math.isfinite(x):
        raise ValueError(f"{x!r} is not a number a certificate can state")
    return repr(x)


def coverage_factor(k: float) -> str:
    """si:kValueType: digits and a point, no exponent, >= 1."""
    out = repr(float(k))
    return out if "e" not in out else f"{float(k):.12f}"


def probability(p: float) -> str:
    """si:probabilityValueType: in [0, 1], no exponent."""
    return f"{float(p):.4f}"


def real(parent: ET.Element, label: str, value: float, unit: str) -> ET.Element:
    """si:real with its label, value and D-SI unit (an uncertainty is added by the caller)."""
    node = el(parent, "si:real")
    el(node, "si:label", label)
    el(node, "si:value", decimal(value))
    el(node, "si:unit", unit)
    return node


def expanded_unc(real_node: ET.Element, expanded: float, k: float, p: float) -> None:
    node = el(real_node, "si:expandedUnc")
    el(node, "si:uncertainty", decimal(abs(expanded)))
    el(node, "si:coverageFactor", coverage_factor(k))
    el(node, "si:coverageProbability", probability(p))
    el(node, "si:distribution", "normal")


def coverage_interval(real_node: ET.Element, standard: float, low: float, high: float, p: float,
                      kind: str) -> None:
    node = el(real_node, "si:coverageInterval")
    el(node, "si:standardUnc", decimal(abs(standard)))
    el(node, "si:intervalMin", decimal(low))
    el(node, "si:intervalMax", decimal(high))
    el(node, "si:coverageProbability", probability(p))
    el(node, "si:distribution", kind)


def quantity(parent: ET.Element, name: str, label: str, value: float, unit: str,
             description: str | None = None) -> ET.Element:
    """A dcc:quantity holding one si:real; returns the si:real (for its uncertainty)."""
    node = el(parent, "dcc:quantity")
    text(node, "dcc:name", name)
    if description:
        rich(node, "dcc:description", description)
    return real(node, label, value, unit)


def statement(parent: ET.Element, declaration: str, *, convention: str | None = None,
              traceable: bool | None = None, norms: tuple[str, ...] = (), valid: bool | None = None,
              conformity: str | None = None) -> ET.Element:
    """A dcc:statement, its elements in the schema's order."""
    node = el(parent, "dcc:statement")
    if convention is not None:
        el(node, "dcc:convention", convention)
    if traceable is not None:
        el(node, "dcc:traceable", "true" if traceable else "false")
    for norm in norms:
        el(node, "dcc:norm", norm)
    rich(node, "dcc:declaration", declaration)
    if valid is not None:
        el(node, "dcc:valid", "true" if valid else "false")
    if conformity is not None:
        el(node, "dcc:conformity", conformity)
    return node


def contact(parent: ET.Element, tag: str, name: str, email: str | None, address: str | None,
            country: str | None, strict: bool = True) -> ET.Element:
    """A dcc:contactType (name, e-mail and location required) or, with strict False, contactNotStrictType."""
    node = el(parent, tag)
    text(node, "dcc:name", name)
    if strict or email:
        el(node, "dcc:eMail", email or "not stated")
    if strict or address or country:
        location = el(node, "dcc:location")
        if country:
            el(location, "dcc:countryCode", country)
        rich(location, "dcc:further", address or "not stated")
    return node
