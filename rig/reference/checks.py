"""The reference chain's part of `rig check`: the commissioning the field source rests on (its age and
residual), and the coil field's non-uniformity over the DUT positions, refused where it exceeds the plan's
accuracy target (`accuracy_ppm`).

Non-uniformity at a position: the largest relative difference between the field there and at the centre
over every field direction the coils can make (rig/fieldsources/coilgeometry.py `nonuniformity`). The rig
corrects for it (each DUT's reference is the field where it sits); what the geometry, the position and
their tolerances leave uncertain is in every calibration's uncertainty budget.
"""

from __future__ import annotations

from rig.core.errors import LimitError
from rig.core.yamlload import blamed


def reference_lines(plan, station, warnings: list[str]) -> list[str]:
    """Lines for `rig check`; LimitError (blamed on the station's position_mm) above plan.accuracy_ppm."""
    source = station.field_source
    lines = []
    commissioned = source.commissioned
    if commissioned is not None:
        lines.append(commissioned.summary(source.max_age_days))
    elif source.kind == "coils":
        lines.append(f"coil matrix as declared (not commissioned): the uncertainty budget takes "
                     f"{source.constants_uncertainty_ppm:g} ppm per element; `rig commission` measures it")
    geometry = getattr(source, "geometry", None)
    stated = [(i, d) for i, d in enumerate(station.duts) if d.position_mm is not None]
    if geometry is None:
        if stated and source.kind == "coils":
            warnings.append("DUT positions are stated but field_source has no geometry: the coil field is "
                            "taken as uniform")
        return lines
    figures = [(i, d, geometry.nonuniformity_ppm(d.position_mm or (0.0, 0.0, 0.0)))
               for i, d in enumerate(station.duts)]
    lines.append("coil field non-uniformity at the DUTs (corrected; ppm of the field): "
                 + ", ".join(f"{d.name} {ppm:.0f}" for _, d, ppm in figures))
    target = plan.accuracy_ppm
    if target is not None:
        for i, d, ppm in figures:
            if ppm > target:
                what = (f"the coil field at {d.name} differs from the centre's by {ppm:.0f} ppm, more than "
                        f"the plan's accuracy_ppm {target:g}: move it towards the centre")
                raise blamed(LimitError(f"station {station.name}: duts[{i}].position_mm: {what}"),
                             ("duts", i, "position_mm"), what, document="station")
    return lines
