"""Calibration files: YAML by default, JSON when the name ends in .json. Round-trips exactly."""

from __future__ import annotations

import json
import os
from pathlib import Path

import yaml

from calib.atomic import atomic_write
from calib.calibration import Calibration
from calib.errors import DataError

# libyaml's emitter writes the same text as the pure-Python one, about 5x faster (64 DUTs x 3 models of
# files at the end of a campaign); the pure-Python one where PyYAML was built without libyaml
DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def save(cal: Calibration, path: str | os.PathLike) -> None:
    """Write atomically (temp file + rename), with the permissions any new file gets (umask).
    A folder that cannot be written to, or a full disk, raises DataError naming the file."""
    d = cal.to_dict()
    try:
        with atomic_write(path) as f:
            if str(path).lower().endswith(".json"):
                json.dump(d, f, indent=2)
                f.write("\n")
            else:
                yaml.dump(d, f, Dumper=DUMPER, sort_keys=False, default_flow_style=None, width=120)
    except OSError as err:
        raise DataError(f"{path}: cannot write the calibration file ({err.strerror or err})") from None


MAX_BYTES = 1 << 20  # a calibration file is a few kB


class _NoAliasLoader(yaml.SafeLoader):
    """A calibration never needs YAML aliases; refusing them stops "billion laughs" bombs."""

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            raise yaml.MarkedYAMLError(problem="YAML aliases (*name) are not allowed",
                                       problem_mark=event.start_mark)
        return super().compose_node(parent, index)


def load(path: str | os.PathLike) -> Calibration:
    """Read and validate; a missing, corrupted or foreign file raises DataError naming it and the key."""
    p = Path(path)
    try:
        if p.is_dir():
            raise DataError(f"{p}: is a folder, not a calibration file")
        with p.open("rb") as f:
            raw = f.read(MAX_BYTES + 1)
        if len(raw) > MAX_BYTES:
            raise DataError(f"{p}: too big for a calibration file (at most {MAX_BYTES} bytes)")
        text = raw.decode("utf-8")
    except FileNotFoundError:
        raise DataError(f"{p}: calibration file not found") from None
    except (OSError, UnicodeDecodeError) as err:
        raise DataError(f"{p}: cannot read calibration file ({err})") from None
    try:
        data = json.loads(text) if p.suffix.lower() == ".json" else yaml.load(text, Loader=_NoAliasLoader)
    except (json.JSONDecodeError, yaml.YAMLError, RecursionError, ValueError) as err:
        where = getattr(err, "problem_mark", None)
        line = f" line {where.line + 1}" if where is not None else f" line {getattr(err, 'lineno', '?')}"
        problem = getattr(err, "problem", None)
        raise DataError(
            f"{p}:{line}: not valid {'JSON' if p.suffix.lower() == '.json' else 'YAML'}"
            + (f": {problem}" if problem else "")
        ) from None
    return Calibration.from_dict(data, where=str(p))
