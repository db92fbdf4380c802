"""The measurand a calibration file states beside its equation (calib/calibration.py, format version 3):
how h was read (`reading`), the thermometer that gave tau (`tau_source`), the frames of B and h (`frame`)
and what the reference field rests on (`reference_chain`); `indexing` is calib's (calib/equations.py).

    measurand = SessionMeasurand.of(reader, station)     # once per session (rig/analysis/sessionfit.py)
    measurand.state(cal, dut, lag)                        # a session's calibration of one DUT
    state_csv(cal, ds)                                    # a calibration refitted from a CSV

A session's come from what it recorded of its devices (each one's describe() snapshot: identity, the
driver's settings, how its read() makes h), its recorded station (which thermometer is each DUT's
`temp_source`, where that sits) and its reference chain snapshot; never from the station's `sim:`, the
simulator's truth. A CSV's come from what its reading stated (the raw unit, the columns): a CSV has no
device, no reading mode and no reference chain, and its calibration says so.
"""

from __future__ import annotations

import json
from dataclasses import dataclass

H_FRAME = {"name": "sensor", "text": "the DUT's axes as its driver reports them (x, y, z)"}
SCALAR_B_FRAME = {"name": "sensor_aligned",
                  "text": "a frame aligned with h: B's x along h's x, B's y in h's x-y plane (A "
                          "upper-triangular); the true frame up to one rotation, which a |B|-only fit cannot "
                          "see"}
# describe() keys that name the device or its link rather than the driver's settings
IDENTITY_KEYS = frozenset({"name", "kind", "model", "product_id", "serial_number", "firmware", "reading",
                           "address", "port", "link", "device_id", "shared_line", "baudrate"})
NO_CHAIN_CSV = "none: refitted from a CSV's"
# how a ramp's lag correction made tau from the thermometer's reading T_m (calib/thermal/lag.py), in words
LAG_MODELS = {"element_lags": "element_lags: dT_e/dt = (T_m - T_e) / lag_corrected_s, tau = T_e",
              "sensor_lags": "sensor_lags: tau = T_m + lag_corrected_s * dT_m/dt"}


def frame(model: str, b_text: str, b_name: str = "station") -> dict:
    """`frame`: B in the frame the reference was stated in (a scalar fit's B is sensor-aligned), h in the
    DUT's own axes."""
    b = dict(SCALAR_B_FRAME) if model == "scalar" else {"name": b_name, "text": b_text}
    return {"B": b, "h": dict(H_FRAME)}


@dataclass
class SessionMeasurand:
    station: object | None  # the recorded station, with the commissioning its run used; None: unreadable
    snapshots: dict[str, dict]  # device name: its describe() as the run recorded it

    @classmethod
    def of(cls, reader, station) -> SessionMeasurand:
        """What `reader` (a rig.session.reader.SessionReader, or the fleet's copy of its tables) recorded of
        the station's DUTs and thermometers."""
        names = [] if station is None else [d.name for d in (*station.duts, *station.temperature_sensors)]
        snapshots = {name: snap for name in names if isinstance(snap := reader.snapshot(name), dict)}
        return cls(station, snapshots)

    def state(self, cal, dut: str, lag: dict | None = None) -> None:
        """The calibration's measurand keys, for DUT `dut`; `lag` the thermal lag a moving schedule's fit
        corrected tau for (rig/analysis/lagfit.py), if any."""
        cal.reading = self.reading(dut)
        cal.tau_source = self.tau_source(dut, lag)
        source = None if self.station is None else self.station.field_source
        unknown = "not known: the session's recorded station cannot be read"
        cal.frame = frame(cal.model, unknown if source is None
                          else f"{source.frame_text} (station {self.station.name})")
        cal.reference_chain = self.reference_chain()

    def _dut(self, dut: str):
        return None if self.station is None else next((d for d in self.station.duts if d.name == dut), None)

    def _device(self, name: str, device_type: str | None) -> dict:
        snap = self.snapshots.get(name, {})
        return {"name": name, "type": device_type, "model": snap.get("model"),
                "serial": snap.get("serial_number"), "product_id": snap.get("product_id"),
                **({"firmware": snap["firmware"]} if snap.get("firmware") else {})}

    def reading(self, dut: str) -> dict:
        """`reading`: the DUT's identity and how its driver made h, as the session recorded its describe();
        a session recorded before drivers described their reading says what it knows (their set_reset)."""
        config = self._dut(dut)
        snap = self.snapshots.get(dut, {})
        described = snap.get("reading") if isinstance(snap.get("reading"), dict) else legacy_reading(snap)
        return {"device": self._device(dut, None if config is None else config.type),
                "mode": described["mode"], "mode_text": described["mode_text"],
                "raw_unit": described.get("raw_unit", "nT"), "conversion": described.get("conversion"),
                "settings": {k: v for k, v in snap.items() if k not in IDENTITY_KEYS},
                "samples_averaged": 1}

    def tau_source(self, dut: str, lag: dict | None) -> dict:
        """`tau_source`: the DUT's `temp_source` in the recorded station (a thermometer beside it, or the
        chip's own), and the lag correction a moving schedule's fit applied to it."""
        corrected = lag.get("tau_s") if isinstance(lag, dict) and lag.get("applied") else None
        direction = None if corrected is None else lag.get("direction")
        how = {} if corrected is None else {"lag_model": LAG_MODELS.get(direction, direction)}
        config = self._dut(dut)
        if config is None:
            return {"device": None, "place": "not known: the session's recorded station cannot be read",
                    "unit": "degC", "lag_corrected_s": corrected, **how}
        if config.temp_source == "self":
            device, place = self._device(dut, config.type), f"the DUT's own die sensor ({dut})"
        else:
            sensor = next(s for s in self.station.temperature_sensors if s.name == config.temp_source)
            device, place = self._device(sensor.name, sensor.type), f"beside {sensor.beside}"
        accuracy = self.snapshots.get(device["name"], {}).get("accuracy_c")
        return {"device": device, "place": place, "unit": "degC",
                **({"accuracy_c": config.temp_accuracy_c or accuracy} if config.temp_accuracy_c or accuracy
                   else {}),
                "lag_corrected_s": corrected, **how}

    def reference_chain(self) -> dict:
        if self.station is None:
            return {"traceable": False, "text": "not known: the session's recorded station cannot be read"}
        names = [r.name for r in self.station.reference_magnetometers]
        return self.station.field_source.reference_chain_statement(names)


def legacy_reading(snap: dict) -> dict:
    """What a snapshot from before drivers described their reading says of it: its `set_reset` (True or
    "pulse": a SET/RESET pair; "off": SET once; False or "auto": single readings); no conversion."""
    flag = snap.get("set_reset")
    mode = {True: "set_reset_pair", "pulse": "set_reset_pair", "off": "set_only", False: "single",
            "auto": "single"}.get(flag, "not_stated") if isinstance(flag, bool | str) else "not_stated"
    said = "not recorded" if flag is None else f"set_reset = {flag}"
    return {"mode": mode, "raw_unit": "nT", "conversion": None,
            "mode_text": f"as the session recorded the driver ({said}); its driver did not yet describe "
                         "its reading or its conversion from codes"}


def state_csv(cal, ds) -> None:
    """The measurand of a calibration refitted from a CSV: its raw unit and columns as read, no device, no
    reading mode, tau from its `temp` column (if any), no reference chain."""
    source = ds.source or {}
    unit, scale = source.get("raw_unit", "nT"), source.get("nt_per_raw_unit", 1.0)
    columns = source.get("column_map") or "hx,hy,hz"
    counts = source.get("counts_per_unit") or ""
    conversion = (f"h_nT = the CSV's {columns} (in {unit}{' at ' + counts if counts else ''}) * {scale:.10g}"
                  if unit != "nT" else "h_nT = the CSV's hx, hy, hz as they are (nT)")
    cal.reading = {"device": None, "mode": "not_stated",
                   "mode_text": "a CSV does not state how its readings were made (SET/RESET or not)",
                   "raw_unit": unit, "conversion": conversion,
                   "settings": {"columns": source.get("column_map") or None,
                                "counts_per_unit": counts or None},
                   "samples_averaged": None}
    has_temp = ds.temp_c is not None
    cal.tau_source = {"device": None, "place": "CSV column temp" if has_temp else "none: the CSV has no temp "
                      "column", "unit": "degC" if has_temp else None, "lag_corrected_s": None}
    what = "bx,by,bz" if ds.ref_nt is not None else "|B| (bnorm or a stated field norm)"
    cal.frame = frame(cal.model, f"the frame of the CSV's {what}", "csv")
    cal.reference_chain = {"traceable": False, "text": f"{NO_CHAIN_CSV} {what}"}


def reference_chain_words(chain: dict | None) -> str:
    """A calibration's `reference_chain` in one line, said loudest where no commissioned reference stands
    behind its field: `rig refit`'s summary, every export and the C header say it in these words."""
    if chain is None:
        return "reference chain: not stated (a calibration file from before format version 3)"
    if chain.get("traceable"):
        return f"reference chain: {chain.get('text')}"
    return (f"NO COMMISSIONED REFERENCE CHAIN: {chain.get('text')}; nothing ties this calibration's field to "
            "a calibrated reference, and its stated uncertainty covers only its budget's lines")


def measurand_rows(cal) -> list[tuple[str, str]]:
    """The measurand of a calibration as (label, words) rows, the file's own keys in plain words: what the
    report, the exports and the C header print (each says what the file does not state)."""
    rows: list[tuple[str, str]] = []
    reading = cal.reading
    if reading is not None:
        device = reading.get("device") or {}
        who = (f"{device.get('name')} ({device.get('type')}, {device.get('model')}, serial "
               f"{device.get('serial') or '-'}, product id {device.get('product_id') or '-'})" if device
               else "no device stated")
        rows += [("reading", f"{who}; mode {reading.get('mode')}: {reading.get('mode_text')}; samples "
                             f"averaged into one h: {_or_dash(reading.get('samples_averaged'))}"),
                 ("raw unit", f"h in {reading.get('raw_unit')}; "
                              f"{reading.get('conversion') or 'no conversion from codes stated'}")]
        settings = reading.get("settings") or {}
        if settings:
            rows.append(("driver settings", ", ".join(f"{k} {json.dumps(v)}" for k, v in settings.items())))
    tau = cal.tau_source
    if tau is not None:
        device = tau.get("device") or {}
        who = f"{device.get('name')} ({device.get('type')}, {device.get('model')}) " if device else ""
        lag = tau.get("lag_corrected_s")
        rows.append(("tau from", f"{who}{tau.get('place')}, {_or_dash(tau.get('unit'))}; lag corrected: "
                                 + ("none" if lag is None else f"{lag:.4g} s ({tau.get('lag_model')})")))
    if cal.frame is not None:
        for axis in ("B", "h"):
            part = cal.frame.get(axis) or {}
            rows.append((f"frame of {axis}", f"{part.get('name')}: {part.get('text')}"))
    if cal.indexing is not None:
        rows.append(("indexing", "; ".join(f"{v}" for v in cal.indexing.values())))
    rows.append(("reference chain", reference_chain_words(cal.reference_chain)))
    source = cal.source or {}
    rows.append(("source", f"{source.get('path', '-')} (sha256 {source.get('sha256') or 'not stated'})"))
    rows += [("not stated", what) for what in cal.missing_measurand()]
    return rows


def _or_dash(value) -> str:
    return "-" if value is None else str(value)
