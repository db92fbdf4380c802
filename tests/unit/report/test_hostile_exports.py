"""Hostile text in a calibration file cannot get out of the C header's comments, strings and names:
the header still compiles with -Wall -Wextra -Werror -pedantic and computes the same field."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

import calib
from calib import synthetic
from calib.io import calfile
from rig.cli import main
from rig.core.names import c_identifier, header_guard
from tests.unit.report.ccheck import max_relative_error, run_header

HOSTILE = [
    "*/ #include <stdlib.h> /*",
    "1.0\n#include <evil.h>\n#define x 1",
    "back\\slash\\",
    "??/ trigraph ??=",
    "ünïcödé ✓",
    "nul\x00byte",
    "// line comment \r\n */ int x; /*",
    '"quoted" \\" */',
]


@pytest.fixture(scope="module")
def fitted():
    ds, _ = synthetic.t24_dataset(np.random.default_rng(11), samples_per_point=2)
    return calib.fit(ds, "t24")


@pytest.mark.parametrize("text", HOSTILE)
def test_hostile_strings_stay_inside_the_comment(text, fitted, tmp_path, capsys):
    fitted.software_version = text
    fitted.created_utc = text
    fitted.source["sha256"] = text
    fitted.source["dut"] = text
    path = tmp_path / "cal.yaml"
    calfile.save(fitted, path)
    header = tmp_path / "out.h"
    assert main(["export-cal", str(path), "--format", "c-header", "-o", str(header)]) == 0
    capsys.readouterr()
    source = header.read_text()
    assert source.isascii() and "\x00" not in source and "\r" not in source
    directives = [line.split()[0] for line in source.splitlines() if line.startswith("#")]
    assert set(directives) <= {"#ifndef", "#define", "#endif", "#if", "#elif", "#else"}  # no #include
    comment = source[: source.index("*/") + 2]  # the first comment must end where the export ends it
    assert comment.rstrip().endswith(" */") and source.index("*/") > source.index("source sha256")
    h = np.random.default_rng(1).normal(0, 40_000, (20, 3))
    t = np.linspace(-20, 60, 20)
    from_c = run_header(source, text, h, t, tmp_path)
    assert max_relative_error(from_c, fitted.apply(h, t)) < 1e-9


def test_names_differing_only_in_non_ascii_give_different_headers(fitted, tmp_path, capsys):
    path = tmp_path / "cal.yaml"
    calfile.save(fitted, path)
    texts = []
    for name in ("mag_ä", "mag_ö"):
        assert main(["export-cal", str(path), "--format", "c-header", "--name", name]) == 0
        texts.append(capsys.readouterr().out)
    assert header_guard("mag_ä") != header_guard("mag_ö")
    for name, text in zip(("mag_ä", "mag_ö"), texts, strict=True):
        assert f"#ifndef {header_guard(name)}" in text and f"void {c_identifier(name)}_apply(" in text


@pytest.mark.parametrize("fmt", ["json", "csv"])
def test_json_and_csv_carry_hostile_text_escaped(fmt, fitted, tmp_path, capsys):
    fitted.software_version = HOSTILE[1]
    fitted.source["dut"] = HOSTILE[0]
    fitted.source["note"] = {"k\n": HOSTILE[5]}
    path = tmp_path / "cal.yaml"
    calfile.save(fitted, path)
    assert main(["export-cal", str(path), "--format", fmt]) == 0
    out = capsys.readouterr().out
    if fmt == "json":
        doc = json.loads(out)
        assert doc["fitted_with"] == f"magrig {HOSTILE[1]}" and doc["source"]["note"] == {"k\n": HOSTILE[5]}
        assert out.isascii()
    else:  # the measurand in `#` lines above the header, each on one line whatever its text held
        lines = out.splitlines()
        comments = [line for line in lines if line.startswith("# ")]
        assert lines[: len(comments)] == comments and any("NO COMMISSIONED REFERENCE" in c or
                                                         "reference chain" in c for c in comments)
        rows = list(csv.reader(io.StringIO("\n".join(lines[len(comments):]))))
        assert rows[0] == ["parameter", "value", "std_error", "expanded_uncertainty"]
        assert all(len(r) == 4 for r in rows)


def test_an_alias_bomb_calibration_is_one_line(tmp_path, capsys):
    path = tmp_path / "bomb.yaml"
    lines = ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 9)]
    path.write_text("\n".join(lines) + "\nformat: magrig-calibration\nmodel: t24\nparams: *a8\n")
    assert main(["export-cal", str(path), "--format", "json"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(path) in err and "aliases" in err and "line 2" in err
