"""`rig ...` in a world whose DUT physics costs (nearly) nothing: each DUT reads the coils' field at the
centre plus a little noise, with no DUT model, no position, no current source, no lab. Only for measuring
how much of a run's wall time the rest (drivers, register transfers, session, engine) takes, as
`demo_wall.py --free-physics` does; the calibrations it makes mean nothing.

    python bench/free_physics.py run PLAN --out DIR --no-live
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from drivers.sim import world  # noqa: E402


def _cheap_raw_nt(self, dut: str, polarity: int = 1, noisy: bool = True) -> np.ndarray:
    with self._lock:
        self._advance()
        field = self.coil_constants @ self.coil_currents_a + self.ambient_nt
        return polarity * field + self.rng.normal(0.0, 5.0, 3)


def main() -> None:
    world.World.dut_raw_nt = _cheap_raw_nt
    from rig.cli import main as rig_main

    sys.argv = ["rig", *sys.argv[1:]]
    rig_main()


if __name__ == "__main__":
    main()
