"""Compile an exported C header with the system C compiler and run its apply function on samples."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from rig.report.exports import c_identifier

DRIVER_C = """
#include <stdio.h>
#include "{header}"
int main(void) {{
    double h[3], t, b[3];
    while (scanf("%lf %lf %lf %lf", &h[0], &h[1], &h[2], &t) == 4) {{
        {ident}_apply(h, t, b);
        printf("%.17g %.17g %.17g\\n", b[0], b[1], b[2]);
    }}
    return 0;
}}
"""


def c_compiler() -> str:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler on this machine")
    return cc


def run_header(
    header_text: str, name: str, h_nt: np.ndarray, temp_c: np.ndarray, workdir: Path, std: str = "c99"
) -> np.ndarray:
    """Field the header's apply function computes for each row of (h_nt, temp_c), compiled as `std`
    (c99 or c89) with every warning an error."""
    cc = c_compiler()
    header = workdir / f"{c_identifier(name)}.h"
    header.write_text(header_text)
    source = workdir / "driver.c"
    source.write_text(DRIVER_C.format(header=header.name, ident=c_identifier(name)))
    exe = workdir / f"driver-{std}"
    done = subprocess.run(
        [cc, f"-std={std}", "-Wall", "-Wextra", "-Werror", "-pedantic", "-o", str(exe), str(source)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    stdin = "\n".join(
        f"{a!r} {b!r} {c!r} {t!r}" for (a, b, c), t in zip(h_nt.tolist(), temp_c.tolist(), strict=True)
    )
    out = subprocess.run([str(exe)], input=stdin, check=True, capture_output=True, text=True).stdout
    return np.array([[float(v) for v in line.split()] for line in out.splitlines()])


def max_relative_error(got: np.ndarray, want: np.ndarray) -> float:
    """Largest per-sample |got - want| / |want| over the rows."""
    return float(np.max(np.linalg.norm(got - want, axis=1) / np.linalg.norm(want, axis=1)))
