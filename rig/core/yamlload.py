"""YAML files validated by pydantic models, with errors that name the file, the key path and the line.

    load_model(Plan, "plan.yaml")  ->  Plan
    ConfigError("plan.yaml: temperatures.steps[2].stability.band_c: must be > 0 (line 14)")

Every problem of a file is listed, one line each, in the order of the file; an unknown key close to a
known one adds "did you mean 'samples_per_point'?".

The line numbers come from the nodes `yaml.compose` builds (their start marks); the values come from
the same composed nodes. Unknown keys are rejected by the models (extra="forbid").

Hostile files are refused before they cost anything: files over MAX_CONFIG_BYTES, YAML aliases (a
config never needs them, and they make "billion laughs" bombs), nesting deeper than MAX_DEPTH, and
inf/NaN anywhere (written `.inf` or as text "nan"). The models state the name rule (rig/core/names.py
SafeName) and the number types (rig/core/numbers.py) on their fields; the station model checks that device
names stay distinct after transformation (file names, C symbols).
"""

from __future__ import annotations

import difflib
import math
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import pydantic
import yaml

from drivers.registry import KeyPathError  # noqa: F401 - the models raise it, from here or drivers
from rig.core.errors import ConfigError

M = TypeVar("M", bound=pydantic.BaseModel)
KeyPath = tuple[str | int, ...]
MAX_CONFIG_BYTES = 1 << 20  # the largest shipped config is a few kB
MAX_DEPTH = 32


def read_text(path: str | Path, max_bytes: int = MAX_CONFIG_BYTES) -> str:
    """The text of a config file; one line naming it when it is missing, a folder, too big or unreadable."""
    p = Path(path)
    try:
        if p.is_dir():
            raise ConfigError(f"{path}: is a folder, not a file")
        size = p.stat().st_size
        if size > max_bytes:
            raise ConfigError(f"{path}: {size} bytes is too big for a config file (at most {max_bytes})")
        with p.open("rb") as f:
            data = f.read(max_bytes + 1)  # a pipe or device reports no size: never read more than this
        if len(data) > max_bytes:
            raise ConfigError(f"{path}: too big for a config file (at most {max_bytes} bytes)")
        return data.decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: cannot read: not UTF-8 text (byte {exc.start})") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from None


class _ConfigLoader(yaml.SafeLoader):
    """SafeLoader that composes an alias, or a subtree nested deeper than MAX_DEPTH, as a null
    placeholder and remembers the first such problem: the document is then refused naming the key."""

    depth = 0
    problem: tuple[str, yaml.Mark] | None = None

    def _placeholder(self, message: str, mark: yaml.Mark) -> yaml.Node:
        if self.problem is None:
            self.problem = (message, mark)
        return yaml.ScalarNode("tag:yaml.org,2002:null", "", mark, mark)

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            self.get_event()
            return self._placeholder("YAML aliases (*name) are not allowed in a config; write the value out",
                                     event.start_mark)
        if self.depth >= MAX_DEPTH:
            self._skip_node()
            return self._placeholder(f"nested more than {MAX_DEPTH} levels deep", event.start_mark)
        self.depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1

    def _skip_node(self) -> None:
        """Consume one node's events without building it (iteratively: no recursion to exhaust)."""
        open_ = 0
        while True:
            event = self.get_event()
            if isinstance(event, yaml.SequenceStartEvent | yaml.MappingStartEvent):
                open_ += 1
            elif isinstance(event, yaml.SequenceEndEvent | yaml.MappingEndEvent):
                open_ -= 1
            if open_ == 0:
                return


def parse(text: str, source: str) -> tuple[object, dict[KeyPath, int]]:
    """The data of a YAML document and the 1-based line of every key path in it."""
    if len(text) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{source}: too big for a config (at most {MAX_CONFIG_BYTES} bytes)")
    loader = _ConfigLoader(text)
    try:
        node = loader.get_single_node()
        problem = loader.problem
        data = loader.construct_document(node) if node is not None and problem is None else None
    except yaml.MarkedYAMLError as exc:
        line = f" (line {exc.problem_mark.line + 1})" if exc.problem_mark else ""
        raise ConfigError(f"{source}: not valid YAML: {exc.problem}{line}") from None
    except (yaml.YAMLError, ValueError, OverflowError) as exc:  # e.g. a timestamp out of range
        raise ConfigError(f"{source}: not valid YAML: {exc}") from None
    finally:
        loader.dispose()
    lines: dict[KeyPath, int] = {}
    if node is not None:
        try:
            _collect_lines(node, (), lines)
        except _DuplicateKey as dup:
            raise ConfigError(f"{source}: {format_path(dup.path)}: key given twice "
                              f"(lines {dup.first} and {dup.second})") from None
    if problem is not None:
        message, mark = problem
        at = [p for p, line in lines.items() if line == mark.line + 1] or [()]
        raise ConfigError(located(source, lines, max(at, key=len), message))
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
    "int_parsing": "expected a whole number, got {input!r}",
    "int_from_float": "expected a whole number, got {input!r}",
    "float_parsing": "expected a number, got {input!r}",
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
                          source: str, model: type[pydantic.BaseModel] | None = None) -> ConfigError:
    """A ConfigError listing every problem, one line each (`FILE: key.path: what (line N)`), in the order
    of the file; an unknown key near a known one says "did you mean". A misspelt key also makes the real
    one "missing": that echo is left out, the misspelling is the news."""
    found: dict[tuple[KeyPath, str], int] = {}  # (path, message) -> line, in order of discovery
    suggested: set[KeyPath] = set()
    for err in sorted(exc.errors(), key=lambda e: e["type"] != "extra_forbidden"):
        path, message, line = _problem(err, data, lines)
        if err["type"] == "extra_forbidden" and model is not None:
            near = did_you_mean(str(path[-1]), allowed_keys(model, tuple(err["loc"][:-1])))
            if near is not None:
                message += f"; did you mean {near!r}?"
                suggested.add((*path[:-1], near))
        if err["type"] == "missing" and path in suggested:
            continue
        found.setdefault((path, message), line or 0)
    problems = sorted(found.items(), key=lambda item: item[1])
    text = "\n".join(f"{source}: {format_path(path)}: {message}" + (f" (line {line})" if line else "")
                     for (path, message), line in problems)
    return ConfigError(text)


def _problem(err: dict, data: object, lines: dict[KeyPath, int]) -> tuple[KeyPath, str, int | None]:
    """(key path in the document, message, line) of one pydantic error."""
    loc = tuple(err["loc"])
    cause = err.get("ctx", {}).get("error")
    if isinstance(cause, KeyPathError):
        loc, err = loc + cause.path, {"type": "blame", "msg": cause.message}
    elif err["type"] == "union_tag_invalid":
        loc += (err["ctx"]["discriminator"].strip("'"),)  # blame the `kind:` line itself
    path, exists = _data_path(data, loc)
    line_path = path if exists else path[:-1]
    line = lines.get(line_path)
    while line is None and line_path:
        line_path = line_path[:-1]
        line = lines.get(line_path)
    return path, _message(err), line


def did_you_mean(key: str, known: set[str]) -> str | None:
    """The known key a misspelt one most likely meant, or None."""
    close = difflib.get_close_matches(key, sorted(known), n=1, cutoff=0.75)
    return close[0] if close else None


def _members(t: Any) -> list[Any]:
    """A type with Annotated, Optional and unions unwrapped into its alternatives."""
    origin = typing.get_origin(t)
    if origin is typing.Annotated:
        return _members(typing.get_args(t)[0])
    if origin in (typing.Union, types.UnionType):
        return [m for a in typing.get_args(t) for m in _members(a)]
    return [t]


def allowed_keys(model: type[pydantic.BaseModel], loc: tuple) -> set[str]:
    """The keys the mapping at `loc` (a pydantic error location) may hold: the fields (and aliases) of
    the model(s) there. Parts of `loc` that are no key (a union's tag) are passed over."""
    here: list[Any] = [model]
    for part in loc:
        step = []
        for t in (m for h in here for m in _members(h)):
            args = typing.get_args(t)
            if isinstance(t, type) and issubclass(t, pydantic.BaseModel) and part in t.model_fields:
                step.append(t.model_fields[part].annotation)
            elif typing.get_origin(t) is dict and isinstance(part, str) and len(args) == 2:
                step.append(args[1])
            elif typing.get_origin(t) in (list, tuple) and isinstance(part, int) and args:
                step.append(args[0])
        here = step or here
    out: set[str] = set()
    for t in (m for h in here for m in _members(h)):
        if isinstance(t, type) and issubclass(t, pydantic.BaseModel):
            out |= {f.alias or name for name, f in t.model_fields.items()}
    return out


def line_of(lines: dict[KeyPath, int], path: KeyPath) -> int | None:
    """The line of `path`, else of its nearest parent that has one."""
    path = tuple(path)
    while True:
        if path in lines:
            return lines[path]
        if not path:
            return None
        path = path[:-1]


def located(source: str, lines: dict[KeyPath, int], path: KeyPath, message: str) -> str:
    """`FILE: key.path: message (line N)`, the one form of every config error."""
    line = line_of(lines, path)
    return f"{source}: {format_path(path)}: {message}" + (f" (line {line})" if line else "")


def locate_in_text(source: str, text: str, path: KeyPath, message: str) -> str:
    """Like `located`, for a document already loaded once (errors found after loading: limits)."""
    try:
        _, lines = parse(text, source)
    except ConfigError:
        lines = {}
    return located(source, lines, path, message)


# --- checks before and after validation -----------------------------------------------------------
def _non_finite(value: Any) -> bool:
    if isinstance(value, float):
        return not math.isfinite(value)
    if isinstance(value, str) and len(value) <= 12:  # "nan", "-Infinity": pydantic turns these into floats
        try:
            return not math.isfinite(float(value))
        except ValueError:
            return False
    return False


def find_non_finite(data: Any, path: KeyPath = ()) -> tuple[KeyPath, Any] | None:
    """The first inf or NaN in the data, as (key path, value): no config needs one."""
    if isinstance(data, dict):
        items = ((str(k), v) for k, v in data.items())
    elif isinstance(data, list):
        items = enumerate(data)
    else:
        return (path, data) if _non_finite(data) else None
    for key, value in items:
        found = find_non_finite(value, (*path, key))
        if found:
            return found
    return None


def load_model(model: type[M], path: str | Path, text: str | None = None) -> M:
    """Read `path` (or use `text`, naming it `path`) and validate it as `model`."""
    source = str(path)
    text = read_text(path) if text is None else text
    data, lines = parse(text, source)
    if data is None:
        raise ConfigError(f"{source}: the file is empty")
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of keys at the top level (line 1)")
    bad = find_non_finite(data)
    if bad:
        raise ConfigError(located(source, lines, bad[0], f"must be a finite number, got {bad[1]!r}"))
    try:
        result = model.model_validate(data)
    except pydantic.ValidationError as exc:
        raise error_from_validation(exc, data, lines, source, model) from None
    except (ArithmeticError, ValueError, TypeError) as exc:  # a model check that met numbers it cannot use
        raise ConfigError(located(source, lines, (), f"cannot use these values: {exc}")) from None
    return result


def blamed(err: Exception, path: KeyPath, what: str, document: str = "plan") -> Exception:
    """Mark an error found after loading with the config key it is about (`document` is "plan" or
    "station"), so whoever holds the file texts can say `FILE: key.path: what (line N)`."""
    err.blame = (document, tuple(path), what)  # type: ignore[attr-defined]
    return err
