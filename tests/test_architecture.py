"""The layout keeps its shape: no import cycles, no oversized modules, analysis never imports the fakes.

Imports are read with ``ast`` (including imports inside functions, which is where cycles hide;
``if TYPE_CHECKING:`` blocks are not imports at run time and are skipped). ``benchmarks/`` is part of the
graph. Importing ``a.b.c`` runs ``a/b/__init__.py`` first, so every import also reaches the packages above
its target (except the importing module's own ancestors, which always run before it): a package whose
``__init__`` imports a module that imports the package back through a sibling is a cycle too.
"""

import ast
from pathlib import Path

from move_code import move_code

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = {"agent": "payload_agent", "drivers": "payload_agent.drivers", "fakes": "payload_agent.fakes",
           "procedures": "payload_agent.procedures", "benchmarks": "benchmarks"}
MAX_LINES = 400  # every module of the package and the benchmarks (issue 20)
# stages that must never see a simulated controller (the registry names fakes by string only)
NO_FAKES = ("payload_agent.model", "payload_agent.configuration", "payload_agent.motion",
            "payload_agent.recording", "payload_agent.analysis", "payload_agent.solvers",
            "payload_agent.evaluation", "payload_agent.output", "payload_agent.types", "payload_agent.errors",
            "payload_agent.drivers")


def project_modules() -> dict[str, Path]:
    mods = {}
    for folder, pkg in FOLDERS.items():
        for path in (ROOT / folder).rglob("*.py"):
            rel = path.relative_to(ROOT / folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            mods[".".join([pkg, *parts])] = path
    return mods


def _runtime_imports(tree: ast.AST):
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            skip.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    for node in ast.walk(tree):
        if id(node) not in skip and isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node


def import_graph() -> dict[str, set[str]]:
    mods = project_modules()
    graph: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        is_pkg = path.name == "__init__.py"
        for node in _runtime_imports(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            else:
                base = node.module or ""
                if node.level:
                    anchor = mod.split(".") if is_pkg else mod.split(".")[:-1]
                    anchor = anchor[:len(anchor) - node.level + 1]
                    base = ".".join(anchor + ([base] if base else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            own_ancestors = {mod.rsplit(".", k)[0] for k in range(1, mod.count(".") + 1)}
            for t in targets:
                while t and t not in mods:
                    t = t.rpartition(".")[0]
                if t and t != mod:
                    graph[mod].add(t)
                    # the packages above the target run first (their __init__ is executed on the way)
                    parent = t.rpartition(".")[0]
                    while parent:
                        if parent in mods and parent != mod and parent not in own_ancestors:
                            graph[mod].add(parent)
                        parent = parent.rpartition(".")[0]
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        stack.append(n)
        for m in sorted(graph[n]):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state and (c := visit(m)):
                return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state and (c := visit(n)):
            return c
    return None


def test_no_import_cycle():
    cycle = find_cycle(import_graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_the_cycle_finder_finds_cycles():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set()}) is None


def test_no_module_over_the_size_limit():
    big = {str(p.relative_to(ROOT)): n for p in project_modules().values()
           if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_LINES}
    assert not big, f"modules over {MAX_LINES} lines: {big}"


def test_the_graph_covers_benchmarks_and_package_inits():
    graph = import_graph()
    assert "benchmarks.accuracy" in graph and "benchmarks.cases" in graph["benchmarks.accuracy"]
    # importing payload_agent.solvers.general runs payload_agent/solvers/__init__.py first
    assert "payload_agent.solvers" in graph["payload_agent.evaluation.quality"]
    assert find_cycle({"p": {"p.a"}, "p.a": {"q"}, "q": {"p"}}) == ["p", "p.a", "q", "p"]


def test_agent_stages_never_import_the_fakes():
    offenders = {m: sorted(t for t in deps if t.startswith("payload_agent.fakes"))
                 for m, deps in import_graph().items() if m.startswith(NO_FAKES)}
    assert not {m: d for m, d in offenders.items() if d}


MOTION_CALLS = {"move_joints", "_start_move", "redo_last_sweep"}
# who may call what: the gate calls the driver's move_joints; the base class calls the hook
ALLOWED = {"move_joints": {"payload_agent.motion.safety"},
           "_start_move": {"payload_agent.drivers.base"},
           "redo_last_sweep": {"payload_agent.session.phases"}}


def test_motion_is_commanded_only_through_the_safety_gate():
    """Every call that can command motion, anywhere in the agent and the drivers, is the gate's."""
    offenders = []
    for mod, path in project_modules().items():
        if mod.startswith(("payload_agent.fakes", "benchmarks")):
            continue  # the simulated controllers move their own simulated arm; benchmarks drive it offline
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in MOTION_CALLS:
                via_super = isinstance(node.func.value, ast.Call) and getattr(node.func.value.func, "id", "") == "super"
                if via_super and mod.startswith("payload_agent.drivers"):
                    continue  # a driver's override handing on to the supervised base method
                if mod not in ALLOWED[node.func.attr]:
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} calls {node.func.attr}")
    assert not offenders, "motion commanded outside the safety gate: " + "; ".join(offenders)


def test_the_configuration_knows_every_simulated_arm():
    from payload_agent.configuration.simulation import SIMULATED_ARMS
    from payload_agent.fakes.arms import SPECS

    assert set(SIMULATED_ARMS) == set(SPECS)


DRIVER_HOOKS = {"_open", "_close", "_read_sample", "_prepare_move", "_activate", "_start_move", "_move_status",
                "_stop_command", "_stop_fresh", "_command_alive"}


def base_privates() -> set[str]:
    """The private names of drivers/base.py's Driver (its attributes and methods), less the hooks a driver fills."""
    tree = ast.parse((ROOT / "drivers" / "base.py").read_text(encoding="utf-8"))
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Driver")
    names = {n.name for n in cls.body if isinstance(n, ast.FunctionDef)}
    names |= {n.attr for n in ast.walk(cls) if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)
              and n.value.id == "self"}
    return {n for n in names if n.startswith("_") and not n.startswith("__")} - DRIVER_HOOKS


def test_drivers_use_only_the_public_side_of_the_base_class():
    """A family's modules never reach into the base's privates (nor the stream's or the supervisor's): the
    template's public methods (check_supervision, command_ok, trip, wait_for_trip, supervising, ...) are the
    contract."""
    private = base_privates()
    assert "_connected" in private and "_run_move" in private  # the check sees the base's names
    offenders = []
    for path in sorted((ROOT / "drivers").glob("*/*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.Attribute) or not node.attr.startswith("_") or node.attr.startswith("__"):
                continue
            owner = node.value.attr if isinstance(node.value, ast.Attribute) else ""
            if node.attr in private or owner in ("stream", "supervisor"):
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} uses {node.attr}")
    assert not offenders, "; ".join(offenders)


MOVE_CODE_MAX_LINES = 60


def test_move_code_measure_sees_hooks_helpers_and_per_move_state():
    lines, names = move_code(ROOT / "drivers" / "elite_ec")
    assert {"self._start_move", "self._move_status", "driver._EliteMove"} <= set(names) and lines > 10
    assert "self._read_sample" not in names and "self.state" not in names  # not move code


def test_move_code_measure_follows_helpers_imported_from_sibling_modules(tmp_path):
    """A helper the move hooks import by name (or reach as ``alias.x``) from a sibling module is move code; one
    that a non-move method also reaches is not."""
    fam = tmp_path / "fam"
    fam.mkdir()
    (fam / "driver.py").write_text(
        "from payload_agent.drivers.fam.helpers import only_for_moves as check\n"
        "from payload_agent.drivers.fam import helpers as h\n"
        "from .states import shared\n"
        "class FamDriver(Driver):\n"
        "    def _start_move(self, target, speed, accel):\n"
        "        return check(target)\n"
        "    def _move_status(self):\n"
        "        return h.status_text() + shared()\n"
        "    def state(self):\n"
        "        return shared()\n", encoding="utf-8")
    (fam / "helpers.py").write_text(
        "def only_for_moves(t):\n"
        "    'docstrings do not count'\n"
        "    return deeper(t)\n"
        "def deeper(t):\n"
        "    return t\n"
        "def status_text():\n"
        "    return 'x'\n", encoding="utf-8")
    (fam / "states.py").write_text("def shared():\n    return ''\n", encoding="utf-8")
    lines, names = move_code(fam)
    assert names == ["helpers.deeper", "helpers.only_for_moves", "helpers.status_text", "self._move_status",
                     "self._start_move"]
    assert lines == 4 + 2 + 2 + 2  # the two hooks, then the three helpers (less the docstring)
    # in a real family: Elite's abort text lives in states.py
    assert "states.abort_text" in move_code(ROOT / "drivers" / "elite_ec")[1]


def test_every_drivers_move_code_is_small():
    """The base owns the move loop; a family's move code is only its protocol: under 60 lines."""
    sizes = {f.name: move_code(f) for f in sorted((ROOT / "drivers").iterdir()) if (f / "driver.py").exists()}
    assert {"elite_ec", "ur_rtde", "modbus", "canopen"} <= set(sizes)
    over = {name: (n, names) for name, (n, names) in sizes.items() if n >= MOVE_CODE_MAX_LINES}
    assert not over, f"move code not under {MOVE_CODE_MAX_LINES} lines: {over}"


def test_move_code_measure_counts_methods_of_the_familys_classes(tmp_path):
    """A method of any family class that only move code reaches counts, through a typed attribute
    (``self.watch: Watch | None``), a constructor-typed one (``self.sync = Sync()``), the driver's options, a
    local alias of a typed expression, an annotated ``drv`` parameter and an annotated return; a method the
    connection, the stream, the stop or the state report also reaches does not, nor does its class; an
    attribute the measure cannot type reaches every family method of its name from the moves, and from the
    shared code only those the moves reach by such a guess too."""
    fam = tmp_path / "fam"
    fam.mkdir()
    (fam / "driver.py").write_text(
        "from payload_agent.drivers.fam import motion\n"
        "from .parts import Watch, Sync, FamOptions\n"
        "class FamDriver(Driver):\n"
        "    options_class = FamOptions\n"
        "    def __init__(self, options, limits):\n"
        "        self.watch: Watch | None = None\n"
        "        self.sync = Sync()\n"
        "    def _open(self):\n"
        "        self.watch = Watch().start()\n"
        "        self.sync.shared_too(self.options.n)\n"
        "    def _start_move(self, target, speed, accel):\n"
        "        self.watch.confirm()\n"
        "        self.options.to_counts(target)\n"
        "        return motion.start(self)\n"
        "    def _move_status(self):\n"
        "        return mystery.untyped_only()\n"
        "    def _close(self):\n"
        "        other.confirm()\n", encoding="utf-8")  # a guess never shares what the moves reach typed
    (fam / "motion.py").write_text(
        "def start(drv: 'FamDriver'):\n"
        "    s = drv.sync\n"
        "    s.after_sync()\n"
        "    s.shared_too()\n", encoding="utf-8")
    (fam / "parts.py").write_text(
        "class Watch:\n"
        "    def start(self) -> 'Watch':\n"
        "        return self\n"
        "    def confirm(self):\n"
        "        self.deeper()\n"
        "    def deeper(self):\n"
        "        return 1\n"
        "class Sync:\n"
        "    def after_sync(self):\n"
        "        return 2\n"
        "    def shared_too(self):\n"
        "        return 3\n"
        "class FamOptions:\n"
        "    n: int = 6\n"
        "    def to_counts(self, x):\n"
        "        return x\n"
        "class Other:\n"
        "    def untyped_only(self):\n"
        "        return 4\n", encoding="utf-8")
    lines, names = move_code(fam)
    assert names == ["motion.start", "parts.FamOptions.to_counts", "parts.Other.untyped_only",
                     "parts.Sync.after_sync", "parts.Watch.confirm", "parts.Watch.deeper", "self._move_status",
                     "self._start_move"]
    assert lines == 4 + 2 + 2 + 2 + 2 + 2 + 2 + 4  # Sync, Watch and FamOptions are shared (their methods are not)


def test_move_code_measure_sees_the_shared_objects_of_the_real_families():
    """What the CANopen and Modbus moves call on the family's objects is found (the SYNC batch, the options'
    counts); the SDO liveness gate is shared with the power-up (``_activate``), the command watch with the
    payload write: neither counts."""
    _, canopen = move_code(ROOT / "drivers" / "canopen")
    assert {"bus.SyncProducer.after_next_sync", "options.CANopenOptions.to_counts", "motion.start"} <= set(canopen)
    assert "watch.SdoWatch.confirm_alive" not in canopen and "bus.SyncProducer.cancel_pending" not in canopen
    _, modbus = move_code(ROOT / "drivers" / "modbus")
    assert "command.CommandWatch.poll" not in modbus and "self._start_move" in modbus
