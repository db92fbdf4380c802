"""A reference sensitivity that is the same for every row of a group: a_ref[n] = per_group[index[n]].

An offset per temperature step and axis (the offset's wander), per ambient epoch, ... has Q = 3 K input
quantities over K groups: dense, its a_ref (N,3,Q) grows as N K (141k rows and 235 steps: 2.4 GB), while
all a linearised fit does with it is contract it over the rows, and a contraction of a group-constant
array is the per-group sums of what it is contracted with: sum_n M_n a_n = sum_g (sum_{n in g} M_n)
per_group[g]. So the compact form gives the same Jacobians (to rounding) at the cost of one pass over
the rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RowGroups:
    """a_ref in compact form: row n's reference changes by per_group[index[n]] @ q."""

    index: np.ndarray  # (N,) the group of each row, 0..K-1
    per_group: np.ndarray  # (K,3,Q)

    @classmethod
    def offsets(cls, index: np.ndarray, groups: int) -> RowGroups:
        """One offset per group and axis: q[3 g + i] is added to axis i of the rows of group g."""
        per_group = np.zeros((groups, 3, 3 * groups))
        for i in range(3):
            per_group[np.arange(groups), i, 3 * np.arange(groups) + i] = 1.0
        return cls(np.asarray(index, np.intp), per_group)

    @property
    def shape(self) -> tuple[int, int, int]:
        return (len(self.index), 3, self.per_group.shape[2])

    def sums(self, values: np.ndarray) -> np.ndarray:
        """(K, ...): the per-group sums of values (N, ...) over the rows (a group without rows sums to 0)."""
        values = np.asarray(values, float)
        k = len(self.per_group)
        order = np.argsort(self.index, kind="stable")
        sorted_index = self.index[order]
        starts = np.searchsorted(sorted_index, np.arange(k))
        present = starts < np.searchsorted(sorted_index, np.arange(k), side="right")
        out = np.zeros((k,) + values.shape[1:])
        if present.any():
            out[present] = np.add.reduceat(values[order], starts[present], axis=0)
        return out

    def rows_times(self, q: np.ndarray) -> np.ndarray:
        """(m,N,3): every row's reference change for m draws q (m,Q)."""
        per = np.einsum("kiq,mq->mki", self.per_group, q)  # (m,K,3)
        return per[:, self.index]

    def take(self, rows: np.ndarray) -> RowGroups:
        """The same groups for the rows `rows` alone."""
        return RowGroups(self.index[rows], self.per_group)

    def dense(self) -> np.ndarray:
        """(N,3,Q): the full array (for small data and for checks)."""
        return self.per_group[self.index]
