"""YAML files validated by pydantic models, with errors that name the file, the key path and the line.

    load_model(Plan, "plan.yaml")  ->  Plan
    ConfigError("plan.yaml: temperatures.steps[2].stability.band_c: must be > 0 (line 14)")

The line numbers come from the nodes `yaml.compose` builds (their start marks); the values come from
`yaml.safe_load` of the same text. Unknown keys are rejected by the models (extra="forbid").
"""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import pydantic
import yaml

from rig.errors import ConfigError

M = TypeVar("M", bound=pydantic.BaseModel)
KeyPath = tuple[str | int, ...]


class KeyPathError(ValueError):
    """Raised inside a model validator to blame a key below the model, e.g. ("duts", 1, "temp_source")."""

    def __init__(self, path: KeyPath, message: str):
        super().__init__(message)
        self.path = tuple(path)
        self.message = message


def read_text(path: str | Path) -> str:
    try:
        return Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from None


def parse(text: str, source: str) -> tuple[object, dict[KeyPath, int]]:
    """The data of a YAML document and the 1-based line of every key path in it."""
    try:
        data = yaml.safe_load(text)
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        line = f" (line {exc.problem_mark.line + 1})" if exc.problem_mark else ""
        raise ConfigError(f"{source}: not valid YAML: {exc.problem}{line}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: not valid YAML: {exc}") from None
    lines: dict[KeyPath, int] = {}
    if node is not None:
        try:
            _collect_lines(node, (), lines)
        except _DuplicateKey as dup:
            raise ConfigError(f"{source}: {format_path(dup.path)}: key given twice "
                              f"(lines {dup.first} and {dup.second})") from None
    return data, lines


class _DuplicateKey(Exception):
    def __init__(self, path: KeyPath, first: int, second: int):
        self.path, self.first, self.second = path, first, second


def _collect_lines(node: yaml.Node, path: KeyPath, lines: dict[KeyPath, int]) -> None:
    lines.setdefault(path, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            key_path = (*path, str(key_node.value))
            if key_path in lines:
                raise _DuplicateKey(key_path, lines[key_path], key_node.start_mark.line + 1)
            lines[key_path] = key_node.start_mark.line + 1
            _collect_lines(value_node, key_path, lines)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _collect_lines(item, (*path, i), lines)


def format_path(path: KeyPath) -> str:
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _data_path(data: object, loc: tuple) -> tuple[KeyPath, bool]:
    """Map a pydantic error location onto the document: drop union tags and validator names that are
    not keys of the data. Returns the path and whether it ends at an existing node."""
    path: list[str | int] = []
    here = data
    for i, part in enumerate(loc):
        if isinstance(here, dict) and str(part) in {str(k) for k in here}:
            key = next(k for k in here if str(k) == str(part))
            path.append(str(key))
            here = here[key]
        elif isinstance(here, list) and isinstance(part, int) and 0 <= part < len(here):
            path.append(part)
            here = here[part]
        elif i == len(loc) - 1 and isinstance(part, str) and isinstance(here, dict):
            path.append(part)  # a missing key: name it, the line is its parent's
            return tuple(path), False
    return tuple(path), True


_MESSAGES = {
    "greater_than": "must be > {gt}",
    "greater_than_equal": "must be >= {ge}",
    "less_than": "must be < {lt}",
    "less_than_equal": "must be <= {le}",
    "extra_forbidden": "unknown key",
    "missing": "required key is missing",
    "too_short": "needs at least {min_length} item(s)",
    "too_long": "takes at most {max_length} item(s)",
    "union_tag_invalid": "{tag!r} is not one of {expected_tags}",
    "union_tag_not_found": "required key {discriminator} is missing",
    "model_type": "expected a mapping of keys, got {input!r}",
    "model_attributes_type": "expected a mapping of keys, got {input!r}",
    "dict_type": "expected a mapping of keys, got {input!r}",
}


def _message(err: dict) -> str:
    template = _MESSAGES.get(err["type"])
    if template:
        try:
            ctx = {k: f"{v:g}" if isinstance(v, float) else v for k, v in err.get("ctx", {}).items()}
            return template.format(input=err.get("input"), **ctx)
        except (KeyError, IndexError):
            pass
    msg = err["msg"]
    for prefix in ("Value error, ", "Assertion failed, "):
        msg = msg.removeprefix(prefix)
    return msg[:1].lower() + msg[1:]


def error_from_validation(exc: pydantic.ValidationError, data: object, lines: dict[KeyPath, int],
                          source: str) -> ConfigError:
    """One-line ConfigError for the first problem, saying how many more there are. Unknown keys come
    first: a misspelt key also makes the real one "missing", and the misspelling is the news."""
    errors = sorted(exc.errors(), key=lambda e: e["type"] != "extra_forbidden")
    first = errors[0]
    loc = tuple(first["loc"])
    cause = first.get("ctx", {}).get("error")
    if isinstance(cause, KeyPathError):
        loc, first = loc + cause.path, {"type": "blame", "msg": cause.message}
    elif first["type"] == "union_tag_invalid":
        loc += (first["ctx"]["discriminator"].strip("'"),)  # blame the `kind:` line itself
    path, exists = _data_path(data, loc)
    line_path = path if exists else path[:-1]
    line = lines.get(line_path)
    while line is None and line_path:
        line_path = line_path[:-1]
        line = lines.get(line_path)
    where = f" (line {line})" if line else ""
    more = f" [and {len(errors) - 1} more problem(s)]" if len(errors) > 1 else ""
    return ConfigError(f"{source}: {format_path(path)}: {_message(first)}{where}{more}")


def load_model(model: type[M], path: str | Path, text: str | None = None) -> M:
    """Read `path` (or use `text`, naming it `path`) and validate it as `model`."""
    source = str(path)
    text = read_text(path) if text is None else text
    data, lines = parse(text, source)
    if data is None:
        raise ConfigError(f"{source}: the file is empty")
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of keys at the top level (line 1)")
    try:
        return model.model_validate(data)
    except pydantic.ValidationError as exc:
        raise error_from_validation(exc, data, lines, source) from None
