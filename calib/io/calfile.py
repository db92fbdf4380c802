"""Calibration files: YAML by default, JSON when the name ends in .json. Round-trips exactly."""

from __future__ import annotations

import json
import os
from pathlib import Path

import yaml

from calib.calibration import Calibration
from calib.errors import DataError
from calib.io.atomic import atomic_write

_FLOAT_TAG, _STR_TAG = "tag:yaml.org,2002:float", "tag:yaml.org,2002:str"


def _float_text(x: float) -> str:
    """A float as PyYAML's SafeRepresenter writes it (its dot before an exponent included)."""
    if x != x:
        return ".nan"
    if x in (float("inf"), float("-inf")):
        return ".inf" if x > 0 else "-.inf"
    text = repr(x).lower()
    return text.replace("e", ".0e", 1) if "." not in text and "e" in text else text


class _Dumper(getattr(yaml, "CSafeDumper", yaml.SafeDumper)):
    """libyaml's emitter (the same text as the pure-Python one, about 5x faster; the pure-Python one where
    PyYAML was built without it), with the lists of floats that make most of a file (covariances,
    intervals) represented in one pass: the same nodes the generic path makes, and the tag of their text
    known instead of matched against every implicit resolver (the same answers: every text _float_text
    writes is a float to the resolver, and a plain scalar's default tag is str)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._float_texts: set[str] = set()

    def represent_list(self, data):
        if not data or not all(type(x) is float for x in data):
            return super().represent_list(data)
        texts = [_float_text(x) for x in data]
        self._float_texts.update(texts)
        flow = True if self.default_flow_style is None else self.default_flow_style  # plain scalars: flow
        return yaml.SequenceNode("tag:yaml.org,2002:seq", [yaml.ScalarNode(_FLOAT_TAG, t) for t in texts],
                                 flow_style=flow)

    def resolve(self, kind, value, implicit):
        if kind is yaml.ScalarNode and value in self._float_texts:
            return _FLOAT_TAG if implicit[0] else _STR_TAG
        return super().resolve(kind, value, implicit)


_Dumper.add_representer(list, _Dumper.represent_list)  # 64 DUTs x 3 models of files after a campaign


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
                yaml.dump(d, f, Dumper=_Dumper, sort_keys=False, default_flow_style=None, width=120)
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


def _parse_yaml(text: str):
    """With libyaml's parser (about 10x faster: a report reads every DUT's files) where the text has no
    "&": without an anchor no alias can refer to anything, so there is nothing to refuse. Otherwise the
    pure-Python loader that refuses aliases."""
    fast = getattr(yaml, "CSafeLoader", None)
    return yaml.load(text, Loader=fast if fast is not None and "&" not in text else _NoAliasLoader)


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
        data = json.loads(text) if p.suffix.lower() == ".json" else _parse_yaml(text)
    except (json.JSONDecodeError, yaml.YAMLError, RecursionError, ValueError) as err:
        where = getattr(err, "problem_mark", None)
        line = f" line {where.line + 1}" if where is not None else f" line {getattr(err, 'lineno', '?')}"
        problem = getattr(err, "problem", None)
        raise DataError(
            f"{p}:{line}: not valid {'JSON' if p.suffix.lower() == '.json' else 'YAML'}"
            + (f": {problem}" if problem else "")
        ) from None
    return Calibration.from_dict(data, where=str(p))
