"""Write examples/t24_synthetic.csv: a small T24 coil campaign with known truth, for the README demo.

python bench/make_example.py && rig refit examples/t24_synthetic.csv --model t24 -o cal.yaml
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib import synthetic
from calib.io import csvio

OUT = Path(__file__).resolve().parent.parent / "examples" / "t24_synthetic.csv"


def main() -> None:
    ds, _ = synthetic.t24_dataset(np.random.default_rng(2024), samples_per_point=3)
    OUT.parent.mkdir(exist_ok=True)
    columns = {"group": ds.group, "temp": np.round(ds.temp_c, 3)}
    for i, axis in enumerate("xyz"):
        columns[f"h{axis}"] = np.round(ds.h_nt[:, i], 1)
    for i, axis in enumerate("xyz"):
        columns[f"b{axis}"] = np.round(ds.ref_nt[:, i], 1)
    csvio.write_csv(OUT, columns)
    print(f"wrote {OUT} ({len(ds)} rows)")


if __name__ == "__main__":
    main()
