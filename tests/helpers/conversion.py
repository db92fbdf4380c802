"""Evaluate the conversion a magnetometer's describe() states (`reading.conversion`, "H_nT = <expression>
per axis (...)") on one output code, so that a test can hold the words against the driver's own decoding."""

from __future__ import annotations

import re


def stated_nt(conversion: str, code: float) -> float:
    """H in nT by the stated expression, its one variable (code, counts) set to `code`."""
    expression = re.match(r"H_nT = (.+?) per axis", conversion).group(1)
    assert set(expression) <= set("0123456789.+-*/() codeunts"), expression
    return eval(expression, {"__builtins__": {}}, {"code": code, "counts": code})  # noqa: S307 - checked above
