"""The data a calibration is fitted to: raw readings plus whatever truth is known about each sample."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Dataset:
    """Samples of one device under test, aligned row by row.

    `h_nt` is the raw reading (the `h` of the models) already converted to nT; `ref_nt` is the reference
    field vector when the rig knows it, `ref_norm_nt` the known magnitude when only that is known.
    `group` labels the temperature step / point of each row for per-step statistics. `columns` carries the
    other input columns unchanged (so `rig apply` can write them back); `source` describes where the rows
    came from (path, sha256, rows_total, rows_used, rows_rejected, kind).
    """

    h_nt: np.ndarray
    temp_c: np.ndarray | None
    ref_nt: np.ndarray | None
    ref_norm_nt: np.ndarray | None = None
    group: np.ndarray | None = None
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    source: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.h_nt.shape[0])

    @property
    def n(self) -> int:
        return len(self)

    def subset(self, rows: np.ndarray | slice) -> Dataset:
        """The same dataset restricted to `rows` (a slice, index array or boolean mask)."""

        def pick(a: np.ndarray | None) -> np.ndarray | None:
            return None if a is None else a[rows]

        return Dataset(
            h_nt=self.h_nt[rows],
            temp_c=pick(self.temp_c),
            ref_nt=pick(self.ref_nt),
            ref_norm_nt=pick(self.ref_norm_nt),
            group=pick(self.group),
            columns={k: v[rows] for k, v in self.columns.items()},
            source=dict(self.source),
        )
