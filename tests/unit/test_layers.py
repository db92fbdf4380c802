"""The layers hold: calib imports neither rig nor drivers, and its own imports point one way; drivers
import no rig, only rig/devices/bench.py imports drivers.sim, and nothing in rig/ asks which concrete device
or field source it holds."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from drivers import registry
from drivers.base import Device
from rig.fieldsources.base import FieldSourceConfig

REPO = Path(__file__).resolve().parents[2]
STATION_BUILDER = "rig/devices/bench.py"  # the one production module that may import drivers.sim


def sources(*folders: str) -> list[Path]:
    return sorted(p for folder in folders for p in (REPO / folder).rglob("*.py"))


def imported_modules(path: Path) -> set[str]:
    """Every module an import statement in `path` names, at any depth (function-level imports too)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out |= {f"{node.module}.{alias.name}" for alias in node.names}
    return out


def offenders(paths: list[Path], forbidden: str) -> list[str]:
    return [f"{p.relative_to(REPO)} imports {m}" for p in paths for m in sorted(imported_modules(p))
            if m == forbidden or m.startswith(forbidden + ".")]


def rel(path: Path) -> str:
    return path.relative_to(REPO).as_posix() if path.is_relative_to(REPO) else str(path)


def test_calib_and_drivers_import_no_rig():
    assert offenders(sources("calib", "drivers"), "rig") == []


def test_calib_imports_no_drivers():
    assert offenders(sources("calib"), "drivers") == []


def _calib_graph() -> dict[str, set[str]]:
    """calib's modules -> the calib modules their import statements name (`from calib import x` names the
    package, whose __init__ names calib.fitting and the rest: a module doing so closes a circle)."""
    modules = {".".join(p.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__"): p
               for p in sources("calib")}
    graph = {}
    for name, path in modules.items():
        named = set()
        for m in imported_modules(path):
            while m and m not in modules:
                m = m.rpartition(".")[0]
            if m and m != name:
                named.add(m)
        graph[name] = named
    return graph


def test_calib_imports_point_one_way():
    graph, done, path = _calib_graph(), set(), []

    def visit(module: str) -> None:
        if module in path:
            raise AssertionError("import circle: " + " -> ".join(path[path.index(module):] + [module]))
        if module in done:
            return
        path.append(module)
        for dep in sorted(graph[module]):
            visit(dep)
        path.pop()
        done.add(module)

    for module in sorted(graph):
        visit(module)
    assert {"calib.calibration", "calib.models", "calib.equations"} <= done


def test_only_the_station_builder_imports_the_simulators():
    production = [p for p in sources("rig", "drivers", "calib")
                  if not rel(p).startswith("drivers/sim/") and rel(p) != STATION_BUILDER]
    assert offenders(production, "drivers.sim") == []
    assert offenders([REPO / STATION_BUILDER], "drivers.sim")  # the rule names a module that does


def _subclasses(cls: type) -> set[type]:
    out = set(cls.__subclasses__())
    for sub in list(out):
        out |= _subclasses(sub)
    return out


def concrete_names() -> set[str]:
    """Class names of every device driver and field source (and their references)."""
    registry.specs("chamber")  # loads every driver module
    names = {c.__name__ for c in _subclasses(Device) | _subclasses(FieldSourceConfig)}
    return names | {"CoilReference", "TableReference"}


def _names_in(node: ast.AST) -> set[str]:
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name)} | {
        n.attr for n in ast.walk(node) if isinstance(n, ast.Attribute)}


def kind_questions(path: Path, concrete: set[str]) -> list[str]:
    """isinstance()/issubclass() or a `case Class(...)` on a concrete device or field-source class."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        asked: set[str] = set()
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in (
                "isinstance", "issubclass") and len(node.args) == 2:
            asked = _names_in(node.args[1]) & concrete
        elif isinstance(node, ast.MatchClass):
            asked = _names_in(node.cls) & concrete
        if asked:
            found.append(f"{rel(path)}:{node.lineno} asks for {', '.join(sorted(asked))}")
    return found


def test_the_concrete_class_list_is_real():
    names = concrete_names()
    assert {"WatlowF4T", "CoilController", "Turntable", "MMC5983MA", "TMP117", "Coils"} <= names


def test_rig_asks_no_device_or_field_source_what_kind_it_is():
    concrete = concrete_names()
    assert [q for p in sources("rig") for q in kind_questions(p, concrete)] == []


def test_the_kind_question_detector_detects(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("def f(x, y):\n"
                      "    return isinstance(x, (int, WatlowF4T)) or isinstance(y, cfg.Coils | str)\n")
    assert len(kind_questions(sample, concrete_names())) == 2
    assert kind_questions(REPO / "rig" / "core" / "yamlload.py", concrete_names()) == []  # isinstance on data is fine


@pytest.mark.parametrize("role", registry.ROLES)
def test_every_registered_device_names_an_existing_simulator(role):
    for spec in registry.specs(role):
        assert callable(spec.load_simulator()), spec.type
