"""A correction the data were given before the fit, estimated from the same data: its share of a budget.

A DUT's thermal hysteresis is corrected in its readings before any model is fitted (rig/reference/
hysteresis.py): the fit sees, in effect, the references less d_n c, d_n the thermal direction of each
sample and c_i = m_i . ref_i per axis, a linear estimate from the references themselves. A source that
changes the references by a then changes c as well, and the parameters move by J (a - d c(a)), not J a:
an offset of one temperature step, say, is partly taken for a hysteresis and corrected away. The noise
moves c too: Var(c_i) = sigma_i^2 |m_i|^2 (for T24 that term and the plain fit's statistics are
uncorrelated, their sum the joint fit's, exactly).

    lin = Corrected(linearised(ds, cal), DataCorrection(direction, maps, variance))
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.uncertainty.rowgroups import RowGroups


@dataclass
class DataCorrection:
    direction: np.ndarray  # (N,) the correction's pattern over the rows (the thermal direction)
    maps: np.ndarray  # (3,N) c_i = maps[i] . ref[:, i]
    variance: np.ndarray  # (3,) the estimate's variance from the readings' noise

    def response(self, a_ref) -> np.ndarray:
        """(3,Q): how c moves with each input quantity of a source that changes the references by a_ref."""
        if isinstance(a_ref, RowGroups):
            return np.einsum("gi,giq->iq", a_ref.sums(self.maps.T), a_ref.per_group)
        return np.einsum("in,niq->iq", self.maps, np.asarray(a_ref, float))

    def shifts(self) -> np.ndarray:
        """(N,3,3): the references' change for a unit c on each axis."""
        return np.asarray(self.direction, float)[:, None, None] * np.eye(3)[None]


class Corrected:
    """A model's linearisation (calib/uncertainty/linearise.py) of data given a `DataCorrection`: its
    reference Jacobians take the correction's response along, its statistics the estimate's noise."""

    def __init__(self, lin, correction: DataCorrection):
        self.plain, self.correction = lin, correction
        self.shift = lin.ref_jacobian(correction.shifts())  # (P,3): the parameters per unit c

    def __getattr__(self, name: str):
        if name == "plain":  # not yet set (a copy made without __init__): no endless lookup
            raise AttributeError(name)
        return getattr(self.plain, name)

    def ref_jacobian(self, a_ref) -> np.ndarray:
        return self.plain.ref_jacobian(a_ref) - self.shift @ self.correction.response(a_ref)

    def statistical_covariance(self) -> np.ndarray:
        own = (self.shift * np.asarray(self.correction.variance, float)) @ self.shift.T
        return self.plain.statistical_covariance() + own
