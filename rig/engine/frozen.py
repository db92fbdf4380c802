"""A temperature reading that does not move while the chamber air does is a stuck sensor, not a stable DUT.

    watch = FrozenReadings()
    problem = watch.add("tmp0", t, temp_c, air_c)   # None, or why the reading is taken for frozen

Rule: the very same value (bit for bit) for at least `min_s`, while the chamber air has moved by at least
`air_move_c` since that value first showed. A DUT lags the air by minutes, not hours: after the air has
moved two degrees, ten minutes later its temperature has moved by far more than a TMP117's 7.8 mC, and
by more than one count of a magnetometer's own coarse sensor (about 0.8 degC). Such a frozen reading is a
fault (a stuck conversion, a stale register); without this the stability detector would call it stable
as soon as its value lay in band. A sensor that froze while the air was steady is caught once the air
moves again (the next set point).
"""

from __future__ import annotations

AIR_MOVE_C = 2.0
MIN_FROZEN_S = 600.0


class FrozenReadings:
    def __init__(self, air_move_c: float = AIR_MOVE_C, min_s: float = MIN_FROZEN_S):
        self.air_move_c = air_move_c
        self.min_s = min_s
        self._since: dict[str, tuple[float, float, float]] = {}  # source -> (value, since t, air then)

    def add(self, source: str, t: float, temp_c: float, air_c: float | None) -> str | None:
        """One reading of `source` at time `t`, with the chamber air of the moment: is it frozen?"""
        if air_c is None:
            return None
        seen = self._since.get(source)
        if seen is None or seen[0] != temp_c:
            self._since[source] = (temp_c, t, air_c)
            return None
        value, since_t, air_then = seen
        if t - since_t >= self.min_s and abs(air_c - air_then) >= self.air_move_c:
            return (f"{source}: temperature frozen at {value:.4f} degC for {t - since_t:.0f} s while the "
                    f"chamber air moved from {air_then:.2f} to {air_c:.2f} degC (stuck sensor?)")
        return None
