"""Apply a magrig calibration file to raw readings using nothing but what the file states: how firmware or
another tool can act on the file without magrig (no import of magrig; plain Python, PyYAML for the
file).

    python examples/apply_from_file.py CAL.yaml DATA.csv -o OUT.csv

DATA.csv has hx,hy,hz (h in the file's `reading.raw_unit`) and, where the equation uses tau, temp (the
temperature in degC from the thermometer `tau_source` names). OUT.csv gets bx,by,bz: B in the frame
`frame.B` names. Read from the file, and only these keys:

- `equation`: which of the four equations below to evaluate; any other text is refused.
- `tau`: `absolute_c` (tau is temp as it is) or `not_used`; `tau_0_c` where the equation subtracts it.
- `reading`: the unit h must be in (`raw_unit`) and how h was made (`mode`); `frame`: what B and h are.
- `indexing`: the file states its matrices [row][column], zero-based, row = output axis of B; refused
  otherwise, since the arrays below are read that way.
- `params`: the parameters, by the names the equation uses.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys

import yaml

T24 = "B = (S + tau K) h + b_nt + tau kb_nt_per_c"
T36 = "B = (S + tau K + tau^2 K2) h + b_nt + tau kb_nt_per_c + tau^2 kb2_nt_per_c2"
P12 = ("B = inv(Q P) (h - h0_nt); Q = diag(k); P rows (1, 0, 0), (sin e1, cos e1, 0), "
       "(sin e2 cos e3, sin e3, cos e2 cos e3); (e1, e2, e3) = angles_deg")
SCALAR = "B = A (h - c_nt)"
SCALAR_T = "B = (A + (tau - tau_0_c) KA_per_c) (h - c_nt - (tau - tau_0_c) kc_nt_per_c)"
INDEXING = "M[row][column], zero-based; row = output axis of B"


def mat_vec(m, v):
    """(m v) for a 3x3 m given as rows (row = output axis) and a 3-vector v."""
    return [m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2] for i in range(3)]


def plus(*terms):
    return [sum(t[i] for t in terms) for i in range(3)]


def scaled(a, v):
    return [a * x for x in v]


def mat_sum(*terms):
    """Sum of (factor, matrix) terms."""
    return [[sum(f * m[i][j] for f, m in terms) for j in range(3)] for i in range(3)]


def p12_field(p, h):
    """B = inv(Q P) (h - h0): Q P is lower-triangular, so B comes by forward substitution."""
    e1, e2, e3 = (math.radians(a) for a in p["angles_deg"])
    rows = [[1.0, 0.0, 0.0], [math.sin(e1), math.cos(e1), 0.0],
            [math.sin(e2) * math.cos(e3), math.sin(e3), math.cos(e2) * math.cos(e3)]]
    m = [[p["k"][i] * rows[i][j] for j in range(3)] for i in range(3)]
    r = [h[i] - p["h0_nt"][i] for i in range(3)]
    b = [0.0, 0.0, 0.0]
    for i in range(3):
        b[i] = (r[i] - sum(m[i][j] * b[j] for j in range(i))) / m[i][i]
    return b


def field(cal: dict, h, temp):
    """B (nT) of one raw reading h at temperature temp, as the file's equation says."""
    eq, p = cal["equation"], cal["params"]
    tau = None
    if cal["tau"] == "absolute_c":
        if temp is None:
            raise SystemExit("the equation uses tau: the data needs a temp column")
        tau = temp - cal.get("tau_0_c", 0.0) if "tau_0_c" in eq else temp
    if eq == T24:
        m = mat_sum((1.0, p["S"]), (tau, p["K"]))
        return plus(mat_vec(m, h), p["b_nt"], scaled(tau, p["kb_nt_per_c"]))
    if eq == T36:
        m = mat_sum((1.0, p["S"]), (tau, p["K"]), (tau * tau, p["K2"]))
        return plus(mat_vec(m, h), p["b_nt"], scaled(tau, p["kb_nt_per_c"]),
                    scaled(tau * tau, p["kb2_nt_per_c2"]))
    if eq == P12:
        return p12_field(p, h)
    if eq == SCALAR:
        return mat_vec(p["A"], [h[i] - p["c_nt"][i] for i in range(3)])
    if eq == SCALAR_T:
        v = [h[i] - p["c_nt"][i] - tau * p["kc_nt_per_c"][i] for i in range(3)]
        return mat_vec(mat_sum((1.0, p["A"]), (tau, p["KA_per_c"])), v)
    raise SystemExit(f"unknown equation {eq!r}: this script applies only the four magrig states")


def load(path: str) -> dict:
    with open(path, encoding="utf-8") as f:
        cal = json.load(f) if path.lower().endswith(".json") else yaml.safe_load(f)
    indexing = (cal.get("indexing") or {}).get("matrices", "")
    if not indexing.startswith(INDEXING):
        raise SystemExit(f"{path}: states no indexing {INDEXING!r} (format version 3): its arrays cannot be "
                         "read")
    return cal


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("calibration")
    ap.add_argument("data")
    ap.add_argument("-o", "--output", required=True)
    args = ap.parse_args(argv)
    cal = load(args.calibration)
    reading, frame = cal.get("reading") or {}, cal.get("frame") or {}
    print(f"h in {reading.get('raw_unit')} ({reading.get('mode')}); B in the frame "
          f"{(frame.get('B') or {}).get('name')}", file=sys.stderr)
    with open(args.data, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    with open(args.output, "w", newline="", encoding="utf-8") as f:
        out = csv.writer(f)
        out.writerow(["bx", "by", "bz"])
        for row in rows:
            h = [float(row["hx"]), float(row["hy"]), float(row["hz"])]
            temp = float(row["temp"]) if row.get("temp") not in (None, "") else None
            out.writerow([repr(x) for x in field(cal, h, temp)])
    return 0


if __name__ == "__main__":
    sys.exit(main())
