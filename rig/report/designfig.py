"""The figure `rig check --figure FILE.png` draws for a designed (or sequential) plan: the predicted air and
DUT temperatures, and each DUT's largest standard error over its target, against chamber time."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from calib.design.planner import Schedule
from rig.report.figures import new_figure, png_bytes


def schedule_figure(schedule: Schedule, title: str) -> Figure:
    fig = new_figure(8.0, 6.0)
    temps, errors = fig.subplots(2, 1, sharex=True)
    hours = np.concatenate([[0.0], schedule.sweep_end_s / 3600.0])
    if schedule.air_c is not None:
        temps.plot(hours[1:], schedule.air_c, color="black", lw=1.5, label="air")
    for name, element in schedule.element_c.items():
        temps.plot(hours[1:], element, lw=1, label=name)
    temps.set_ylabel("temperature (degC)")
    temps.set_title(title, fontsize=10)
    temps.legend(fontsize=8, ncol=3)
    for name, ratios in schedule.ratios.items():
        errors.plot(hours[1:], np.max(ratios, axis=1), lw=1, label=name)
    errors.axhline(1.0, color="black", ls="--", lw=1)
    errors.set_yscale("log")
    errors.set_ylabel("largest standard error / target")
    errors.set_xlabel("chamber time (h)")
    errors.legend(fontsize=8, ncol=3)
    ends = np.cumsum([leg.sweeps for leg in schedule.legs])
    for ax in (temps, errors):
        for end in ends[:-1]:
            ax.axvline(hours[end], color="grey", lw=0.5, ls=":")
    return fig


def write_schedule_figure(schedule: Schedule, title: str, path: Path) -> None:
    from calib.io.atomic import atomic_write

    data = png_bytes(schedule_figure(schedule, title))
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path, "wb") as f:
        f.write(data)
