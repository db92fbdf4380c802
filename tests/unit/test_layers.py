"""The layers hold: calib imports neither rig nor drivers, and its own imports point one way; drivers
import no rig, only the simulated bench (rig/devices/simulated/) imports drivers.sim; nothing that plans,
decides or states a result reads the simulator's truth (a station's `sim:`, the simulated bench, drivers.sim)
outside the simulated bench and rig/config/ (which states it); rig's folders import downwards only, in the
declared order; nothing in rig/ asks which concrete device or field source it holds, nor, outside
rig/fieldsources/, which kind of field source it is."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from drivers import registry
from drivers.base import Device
from rig.fieldsources.base import FieldSourceConfig

REPO = Path(__file__).resolve().parents[2]
# rig's folders from the bottom up; a folder imports only from its own and from lower tiers (folders on one
# tier know nothing of each other). rig/__init__.py (the version) sits below all, rig/__main__.py on top.
RIG_TIERS = ("core", "session fieldsources", "config", "devices engine", "reference", "budget commission",
             "analysis", "planning", "schedules", "run", "report fleet", "web", "cli")
# calib's modules and folders from the bottom up, as rig's: a module imports only from its own folder and
# from lower tiers. calib/__init__.py (the package's face: fit, Calibration, Dataset) sits on top.
CALIB_TIERS = ("errors compiled dataset", "stats", "equations", "calibration",
               "io commissioning synthetic checks", "models", "fitting thermal", "design uncertainty")
# drivers from the bottom up: transports below the device vocabulary, the registry above it, one module per
# device family, and the simulators on top (their world, their wires, then the simulated devices).
DRIVERS_TIERS = ("errors clock", "steps", "transports", "base", "registry",
                 "serialmag_protocol", "chamber coils turntable mmc5983ma hmc5883l tmp117 serialmag tca9548a",
                 "watlow busscan",
                 "sim.world sim.transports", "sim.devices")
MAX_MODULE_LINES = 500  # a module is split where its meanings part, long before this
SIMULATED_BENCH = "rig/devices/simulated/"  # the one production folder that may import drivers.sim
# where a station's `sim:` may be read: the simulated bench builds the world from it, rig/config/ states it
TRUTH_FOLDERS = (SIMULATED_BENCH, "rig/config/")
# the device builders hand a station with simulated devices to the simulated bench, reading nothing of it
BENCH_BUILDERS = ("rig/devices/build.py", "rig/devices/scan.py")
TRUTH_MODULES = ("rig.devices.simulated", "drivers.sim")


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


def package_graph(package: str) -> dict[str, set[str]]:
    """A package's modules -> the modules of the same package their import statements name (`from calib
    import x` names the package, whose __init__ names calib.fitting and the rest: a module doing so closes
    a circle)."""
    modules = {".".join(p.relative_to(REPO).with_suffix("").parts).removesuffix(".__init__"): p
               for p in sources(package)}
    # a folder whose __init__ imports nothing (a docstring) is a name, not a room: `from drivers import
    # registry` names drivers.registry alone
    names_only = {m for m, p in modules.items() if p.name == "__init__.py" and not imported_modules(p)}
    graph = {}
    for name, path in modules.items():
        if name in names_only:
            continue
        named = set()
        for m in imported_modules(path):
            while m and m not in modules:
                m = m.rpartition(".")[0]
            if m and m != name and m not in names_only:
                named.add(m)
        graph[name] = named
    return graph


def circle_in(graph: dict[str, set[str]]) -> list[str] | None:
    done, path = set(), []

    def visit(module: str) -> list[str] | None:
        if module in path:
            return path[path.index(module):] + [module]
        if module in done:
            return None
        path.append(module)
        for dep in sorted(graph[module]):
            if found := visit(dep):
                return found
        path.pop()
        done.add(module)
        return None

    return next((c for m in sorted(graph) if (c := visit(m))), None)


@pytest.mark.parametrize("package", ["calib", "drivers"])
def test_imports_point_one_way_within(package):
    graph = package_graph(package)
    assert circle_in(graph) is None
    assert {"calib.calibration", "calib.models.registry", "calib.equations"} <= set(package_graph("calib"))


def test_the_circle_detector_detects():
    assert circle_in({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert circle_in({"a": {"b"}, "b": set()}) is None


def room_of(module: str, tiers: tuple[str, ...]) -> tuple[str, int | None]:
    """(room, tier) of pkg.X.Y...: the room is "X.Y" where the tiers name it (a folder with tiers of its
    own), else "X"."""
    parts = module.split(".")[1:]
    for depth in (2, 1):
        room = ".".join(parts[:depth])
        if len(parts) >= depth and (tier := tier_of(room, tiers)) is not None:
            return room, tier
    return (parts[0] if parts else ""), None


def package_upward_imports(graph: dict[str, set[str]], tiers: tuple[str, ...]) -> list[str]:
    """`pkg.F.x imports pkg.G...` where G is not below F (or is a sibling of F on its tier)."""
    found = []
    for module, deps in sorted(graph.items()):
        mine_room, mine = room_of(module, tiers)
        if mine is None:  # the package's __init__
            continue
        for dep in sorted(deps):
            room, theirs = room_of(dep, tiers)
            if room != mine_room and (theirs is None or theirs >= mine):
                found.append(f"{module} imports {dep}")
    return found


@pytest.mark.parametrize(("package", "tiers"), [("calib", CALIB_TIERS), ("drivers", DRIVERS_TIERS)])
def test_every_module_lives_in_a_declared_tier(package, tiers):
    stray = [m for m in package_graph(package) if m != package and room_of(m, tiers)[1] is None]
    assert stray == []


@pytest.mark.parametrize(("package", "tiers"), [("calib", CALIB_TIERS), ("drivers", DRIVERS_TIERS)])
def test_imports_point_downwards_only_within(package, tiers):
    assert package_upward_imports(package_graph(package), tiers) == []


def test_the_package_upward_import_detector_detects():
    graph = {"calib.stats.robust": {"calib.models.t24", "calib.errors"},
             "calib.models.t24": {"calib.models.gram", "calib.stats.residuals"},
             "calib.io.calfile": {"calib.checks.nested"}}
    assert package_upward_imports(graph, CALIB_TIERS) == ["calib.io.calfile imports calib.checks.nested",
                                                          "calib.stats.robust imports calib.models.t24"]
    sims = {"drivers.sim.world.dutmodel": {"drivers.sim.devices.tmp117"},
            "drivers.sim.devices.tmp117": {"drivers.sim.world", "drivers.registry"}}
    assert package_upward_imports(sims, DRIVERS_TIERS) == [
        "drivers.sim.world.dutmodel imports drivers.sim.devices.tmp117"]


def test_only_the_station_builder_imports_the_simulators():
    production = [p for p in sources("rig", "drivers", "calib")
                  if not rel(p).startswith(("drivers/sim/", SIMULATED_BENCH))]
    assert offenders(production, "drivers.sim") == []
    assert offenders(sources(SIMULATED_BENCH), "drivers.sim")  # the rule names a folder that does


def _names_a_station(node: ast.AST) -> bool:
    """An expression naming a station: `station`, `self.station`, `campaign.station`, `load_station(p)`."""
    if isinstance(node, ast.Call):
        node = node.func
    name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else ""
    return "station" in name.lower()


def truth_readers(path: Path) -> list[str]:
    """Where `path` reads the simulator's truth: `<station>.sim` (or getattr(<station>, "sim")), or an
    import of the simulated bench (rig/devices/simulated/) or drivers.sim."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Attribute) and node.attr == "sim" and _names_a_station(node.value):
            found.append(f"{rel(path)}:{node.lineno} reads {ast.unparse(node)}")
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "getattr"
              and len(node.args) >= 2 and _names_a_station(node.args[0])
              and isinstance(node.args[1], ast.Constant) and node.args[1].value == "sim"):
            found.append(f"{rel(path)}:{node.lineno} reads {ast.unparse(node)}")
    for module in sorted(imported_modules(path)):
        if any(module == m or module.startswith(m + ".") for m in TRUTH_MODULES):
            found.append(f"{rel(path)} imports {module}")
    return found


def test_only_the_simulated_bench_reads_the_simulators_truth():
    readers = [p for p in sources("rig", "calib") if not rel(p).startswith(TRUTH_FOLDERS)]
    allowed = {f"{builder} imports rig.devices.simulated.bench{name}"
               for builder in BENCH_BUILDERS for name in ("", ".SimBench")}
    assert [r for p in readers for r in truth_readers(p) if r not in allowed] == []
    assert [r for p in sources(SIMULATED_BENCH) for r in truth_readers(p)]  # the rule names a folder that may


def test_the_truth_reader_detector_detects(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("from rig.devices.simulated.world import dut_truths\n"
                      "import drivers.sim.world\n"
                      "def lag(station, campaign, self):\n"
                      "    a = station.sim.duts\n"
                      "    b = campaign.station.sim.air_c + self.station.sim.seed\n"
                      "    return getattr(station, 'sim'), load_station('x').sim, transport.sim\n")
    found = truth_readers(sample)
    assert len(found) == 8, found  # two imports (three names), five reads; a transport's `sim` is its own
    assert not any("transport.sim" in f for f in found)


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
    # isinstance on data is fine
    assert kind_questions(REPO / "rig" / "core" / "yamlload.py", concrete_names()) == []


@pytest.mark.parametrize("role", registry.ROLES)
def test_every_registered_device_names_an_existing_simulator(role):
    for spec in registry.specs(role):
        assert callable(spec.load_simulator()), spec.type


def tier_of(folder: str, tiers: tuple[str, ...] = RIG_TIERS) -> int | None:
    return next((i for i, names in enumerate(tiers) if folder in names.split()), None)


def upward_imports(paths: list[Path], root: Path = REPO / "rig") -> list[str]:
    """`rig/F/x.py imports rig.G...` where G is not below F (or is a sibling of F on its tier)."""
    found = []
    for path in paths:
        parts = path.relative_to(root).parts
        if len(parts) < 2:
            continue
        mine = tier_of(parts[0])
        for module in sorted(imported_modules(path)):
            names = module.split(".")
            if names[0] != "rig" or len(names) < 2 or names[1] == parts[0]:
                continue
            theirs = tier_of(names[1])
            if theirs is not None and theirs >= mine:
                found.append(f"{'/'.join(parts)} imports {module}")
    return found


def test_every_rig_module_lives_in_a_declared_folder():
    stray = [rel(p) for p in sources("rig") if p.parent != REPO / "rig"
             and tier_of(p.relative_to(REPO / "rig").parts[0]) is None]
    top = sorted(p.name for p in (REPO / "rig").glob("*.py"))
    assert stray == [] and top == ["__init__.py", "__main__.py"]


def test_rig_folders_import_downwards_only():
    assert upward_imports(sources("rig")) == []


def test_the_upward_import_detector_detects(tmp_path):
    probes = {"core/up.py": "import rig.run.campaign\n",
              "devices/side.py": "from rig.engine import executor\n",
              "run/down.py": "from rig.core.errors import ConfigError\n"}
    for name, text in probes.items():
        (tmp_path / name).parent.mkdir(exist_ok=True)
        (tmp_path / name).write_text(text)
    found = upward_imports([tmp_path / name for name in probes], root=tmp_path)
    assert found == ["core/up.py imports rig.run.campaign", "devices/side.py imports rig.engine",
                     "devices/side.py imports rig.engine.executor"]


def field_source_kinds() -> set[str]:
    from typing import get_args

    from rig.fieldsources import KINDS

    return {k for cls in KINDS for k in get_args(cls.model_fields["kind"].annotation)}


def kind_tests(path: Path, kinds: set[str]) -> list[str]:
    """Comparisons (==, !=, in) and match cases against a field-source kind's name: the branch a
    field source's own method should take."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        named: set[str] = set()
        if isinstance(node, ast.Compare):
            for side in (node.left, *node.comparators):
                named |= {c.value for c in ast.walk(side) if isinstance(c, ast.Constant) and c.value in kinds}
        elif isinstance(node, ast.MatchValue) and isinstance(node.value, ast.Constant):
            named = {node.value.value} & kinds
        if named:
            found.append(f"{rel(path)}:{node.lineno} tests for {', '.join(sorted(named))}")
    return found


def test_nothing_outside_fieldsources_asks_which_kind_of_field_source():
    kinds = field_source_kinds()
    assert kinds >= {"coils", "turntable"}
    outside = [p for p in sources("rig") if "fieldsources" not in p.relative_to(REPO / "rig").parts]
    assert [q for p in outside for q in kind_tests(p, kinds)] == []


def test_the_kind_test_detector_detects(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("def f(source):\n"
                      "    if source.kind == 'coils' or 'turntable' in (source.kind,):\n"
                      "        return 1\n"
                      "    match source.kind:\n"
                      "        case 'turntable':\n"
                      "            return 2\n")
    assert len(kind_tests(sample, field_source_kinds())) == 3


def test_no_production_module_is_longer_than_the_limit():
    long = {rel(p): n for p in sources("rig", "drivers", "calib")
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert long == {}
