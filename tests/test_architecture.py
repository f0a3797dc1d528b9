"""The layout keeps its shape: no import cycles, no oversized modules, analysis never imports the fakes.

Imports are read with ``ast`` (including imports inside functions, which is where cycles hide;
``if TYPE_CHECKING:`` blocks are not imports at run time and are skipped). ``benchmarks/`` is part of the
graph. Importing ``a.b.c`` runs ``a/b/__init__.py`` first, so every import also reaches the packages above
its target (except the importing module's own ancestors, which always run before it): a package whose
``__init__`` imports a module that imports the package back through a sibling is a cycle too.
"""

import ast
from pathlib import Path

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


MOVE_HOOKS = ("_prepare_move", "_start_move", "_move_status")
MOVE_CODE_MAX_LINES = 60


def family_imports(tree: ast.AST, package: str, stems: set[str]) -> tuple[dict[str, str], dict[str, tuple[str, str]]]:
    """What a family module imports from its own siblings: {alias: module stem} for modules
    (``from payload_agent.drivers.fam import motion``, ``... import objects as obj``, ``from . import x``,
    ``import payload_agent.drivers.fam.x as y``) and {alias: (module stem, name)} for names
    (``from .states import abort_text``, ``from payload_agent.drivers.fam.states import refusal as r``)."""
    modules: dict[str, str] = {}
    names: dict[str, tuple[str, str]] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                head, _, stem = a.name.rpartition(".")
                if head == package and stem in stems and a.asname:
                    modules[a.asname] = stem
        elif isinstance(node, ast.ImportFrom):
            source = (package + (f".{node.module}" if node.module else "")) if node.level == 1 else node.module or ""
            for a in node.names:
                if source == package and a.name in stems:
                    modules[a.asname or a.name] = a.name
                elif source.startswith(package + ".") and (stem := source[len(package) + 1:]) in stems:
                    names[a.asname or a.name] = (stem, a.name)
    return modules, names


def move_code(folder: Path, package: str | None = None) -> tuple[int, list[str]]:
    """A family's move code: its driver's move hooks and every function, method and class of the family's
    modules that only they reach (``self.x`` / ``drv.x`` on the driver and its family mixins, a module-level
    name of the same module, a name imported from a sibling module, ``module.x`` of a family module under
    any alias). A helper other driver methods reach too (connection, state, stop, capabilities) is shared
    infrastructure, not move code. Code lines only: no blank lines, comments or docstrings. Returns (lines,
    the names counted, as ``module.name`` or ``self.method``)."""
    package = package or f"payload_agent.drivers.{folder.name}"
    modules = {p.stem: (ast.parse(src := p.read_text(encoding="utf-8")), src.splitlines())
               for p in sorted(folder.glob("*.py"))}
    imports = {m: family_imports(t, package, set(modules)) for m, (t, _) in modules.items()}
    classes = {n.name: (n, m) for m, (t, _) in modules.items() for n in t.body if isinstance(n, ast.ClassDef)}
    driver = next(n for n in modules["driver"][0].body if isinstance(n, ast.ClassDef) and n.name.endswith("Driver"))
    nodes = {(m, n.name): (n, m) for m, (t, _) in modules.items() for n in t.body
             if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
    for cls, m in [*(classes[b.id] for b in driver.bases if isinstance(b, ast.Name) and b.id in classes),
                   (driver, "driver")]:
        nodes.update({("self", f.name): (f, m) for f in cls.body if isinstance(f, ast.FunctionDef)})

    def refs(key):
        node, mod = nodes[key]
        sibling_modules, sibling_names = imports[mod]
        for n in ast.walk(node):
            if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name):
                owner = "self" if n.value.id in ("self", "drv") else sibling_modules.get(n.value.id)
                if (owner, n.attr) in nodes and n.attr not in MOVE_HOOKS:
                    yield owner, n.attr
            elif isinstance(n, ast.Name):
                if (mod, n.id) in nodes:
                    yield mod, n.id
                elif sibling_names.get(n.id) in nodes:
                    yield sibling_names[n.id]

    def reach(roots):
        seen, todo = set(), list(roots)
        while todo:
            if (k := todo.pop()) not in seen:
                seen.add(k)
                todo.extend(refs(k))
        return seen

    def code_lines(node, lines):
        doc = {i for n in ast.walk(node) if isinstance(n, (ast.FunctionDef, ast.ClassDef))
               and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)
               for i in range(n.body[0].lineno, n.body[0].end_lineno + 1)}
        return sum(1 for i in range(node.lineno, node.end_lineno + 1)
                   if i not in doc and lines[i - 1].strip() and not lines[i - 1].strip().startswith("#"))

    hooks = [("self", h) for h in MOVE_HOOKS if ("self", h) in nodes]
    others = [k for k in nodes if k[0] == "self" and k[1] not in MOVE_HOOKS and k[1] != "__init__"
              and (not k[1].startswith("_") or k[1] in DRIVER_HOOKS)]
    own = reach(hooks) - reach(others)
    return (sum(code_lines(nodes[k][0], modules[nodes[k][1]][1]) for k in own),
            sorted(f"{m}.{n}" for m, n in own))


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
