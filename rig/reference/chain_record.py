"""What a run's reference fields rest on, as a session records it and a resume or a re-fit reads it back.

    snapshot = record(station)           # at the start of a run: session.record_snapshot(SNAPSHOT, ...)
    station = restore(station, snapshot)  # a resume: the same commissioning, whatever the files say now

The record holds the commissioning file's text (sealed: rig/config/commissioning_file.py), the reference
magnetometers' calibrations, the coil matrix at the centre, every DUT's position and the coil matrix
where it sits. Each point also stores the reference it was
taken with (the ambient or the table's parameters in use; rig/fieldsources/fieldmaths.py `record`), so the
reference of every sample can be recomputed under other assumptions (the uncertainty budget,
rig/budget/run_inputs.py).
"""

from __future__ import annotations

from rig.config import commissioning_file

SNAPSHOT = "reference chain"


def record(station, reference_calibrations: dict | None = None) -> dict:
    source = station.field_source
    com = source.commissioned
    positions = station.positions_mm()
    out: dict = {"commissioning": None if com is None else com.as_record(),
                 "reference_calibrations": {name: cal.to_dict()
                                            for name, cal in (reference_calibrations or {}).items()},
                 "positions_mm": {name: None if p is None else list(p) for name, p in positions.items()}}
    return out | source.chain_record(positions)


def recorded_plan_and_station(path, info: dict, snapshot: dict | None):
    """The plan and station texts a session recorded, parsed, with the commissioning its run used."""
    from rig.config import Plan, Station
    from rig.core.yamlload import load_model

    plan = load_model(Plan, f"{path} (recorded plan)", info["plan_text"])
    station = load_model(Station, f"{path} (recorded station)", info["station_text"])
    return plan, restore(station, snapshot)


def restore(station, snapshot: dict | None):
    """The station with the commissioning its run started with (a resume never re-reads the file)."""
    if not snapshot or snapshot.get("commissioning") is None:
        return station
    return commissioning_file.apply(station, commissioning_file.from_record(snapshot["commissioning"]))
