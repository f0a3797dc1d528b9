"""The move-code measure of issue 20: how many lines a driver family writes only to make its moves.

Read with ``ast`` from a family folder (``drivers/<name>/``). Move code is the driver's move hooks
(``_prepare_move``, ``_start_move``, ``_move_status``) and everything of the family they reach that the rest
of the driver contract does not reach. Public helpers are not roots (making a helper public does not take it
out of the count); the optional capabilities are (Modbus's payload write shares the command watch).

What counts as reaching:

- a module-level function or class by name (same module, a name imported from a sibling module, or
  ``module.x`` of a family module under any alias); naming a class also reaches its ``__init__`` and
  ``__post_init__`` (constructing it runs them); a class counts its own lines less its methods;
- a method of any family class (the driver and its mixins as ``self.x``; any other as ``module.Class.x``)
  through an attribute whose receiver's type is resolved statically: ``self`` (the enclosing class), a
  parameter's annotation (``drv: "CANopenDriver"``; an unannotated ``drv`` is the driver), a local name
  assigned from a typed expression (also tuple assignments), an attribute of a typed object whose class
  annotates it (``self.sync: SyncProducer | None``) or assigns it from a constructor or an annotated
  function (``self.monitor = DriveMonitor(opts)``, ``SdoWatch(self).start()`` with ``-> "SdoWatch"``), the
  driver's ``options`` as its ``options_class``;
- what it cannot type is guessed by name, and never in the driver's favour: on the move side an attribute of
  an untyped receiver reaches every family method of that name; on the shared side it reaches only methods
  the move code reaches by a guess too, never one the move code reaches through a resolved receiver. A name
  clash with a shared call (``x.poll()`` somewhere in ``state()``) cannot take seen move code out of the count.

Shared infrastructure is what ``SHARED_ROOTS`` reach (the contract's non-move hooks, ``state()``,
``identify()``, the optional capabilities); a class whose methods or attributes the shared code uses is
shared, its construction with it. The driver's ``__init__`` is neither side (it builds per-move state too).

Code lines only: no blank lines, comments or docstrings.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass, field
from pathlib import Path

MOVE_HOOKS = ("_prepare_move", "_start_move", "_move_status")
# the contract's members other than the moves (hooks, state report, optional capabilities): what they reach is shared
SHARED_ROOTS = ("_open", "_close", "_read_sample", "_activate", "_stop_command", "_stop_fresh", "_command_alive",
                "state", "identify", "describe_endpoint", "capabilities", "flange_pose", "read_payload",
                "write_payload", "read_digital_input", "read_trigger", "joint_temperatures_c")

Key = tuple[str, str]  # ("self", method) for the driver and its mixins, (module stem, name or "Class.method")


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


@dataclass
class _Family:
    """The parsed family: its modules, classes, the nodes that can be counted and the types it can resolve."""

    modules: dict[str, tuple[ast.Module, list[str]]]
    imports: dict[str, tuple[dict[str, str], dict[str, tuple[str, str]]]]
    classes: dict[tuple[str, str], ast.ClassDef] = field(default_factory=dict)
    driver: tuple[str, str] = ("driver", "")
    mixins: set[tuple[str, str]] = field(default_factory=set)
    nodes: dict[Key, tuple[ast.AST, str, tuple[str, str] | None]] = field(default_factory=dict)
    attr_types: dict[tuple[str, str], dict[str, tuple[str, str]]] = field(default_factory=dict)
    external: dict[str, set[str]] = field(default_factory=dict)  # names of other modules (time, np, ...)

    def owner_key(self, cls: tuple[str, str], method: str) -> Key | None:
        """The node of ``method`` on an instance of ``cls`` (its own, else a family base's)."""
        if cls in self.mixins or cls == self.driver:
            return ("self", method) if ("self", method) in self.nodes else None
        todo = [cls]
        while todo:
            c = todo.pop()
            if (k := (c[0], f"{c[1]}.{method}")) in self.nodes:
                return k
            todo.extend(b for b in self.bases(c))
        return None

    def bases(self, cls: tuple[str, str]) -> list[tuple[str, str]]:
        return [r for b in self.classes[cls].bases if (r := self.resolve_name(cls[0], b)) in self.classes]

    def resolve_name(self, mod: str, expr: ast.AST) -> tuple[str, str] | None:
        """A family module-level name (function or class) an expression names, as (stem, name)."""
        if isinstance(expr, ast.Constant) and isinstance(expr.value, str):  # a string annotation
            try:
                expr = ast.parse(expr.value, mode="eval").body
            except SyntaxError:
                return None
        if isinstance(expr, ast.BinOp) and isinstance(expr.op, ast.BitOr):  # X | None
            return self.resolve_name(mod, expr.left) or self.resolve_name(mod, expr.right)
        if isinstance(expr, ast.Subscript) and getattr(expr.value, "id", "") == "Optional":
            return self.resolve_name(mod, expr.slice)
        sibling_modules, sibling_names = self.imports[mod]
        if isinstance(expr, ast.Name):
            if (mod, expr.id) in self.nodes or (mod, expr.id) in self.classes:
                return mod, expr.id
            return sibling_names.get(expr.id)
        if isinstance(expr, ast.Attribute) and isinstance(expr.value, ast.Name) and expr.value.id in sibling_modules:
            return sibling_modules[expr.value.id], expr.attr
        return None


def _parse(folder: Path, package: str) -> _Family:
    modules = {p.stem: (ast.parse(src := p.read_text(encoding="utf-8")), src.splitlines())
               for p in sorted(folder.glob("*.py"))}
    fam = _Family(modules, {m: family_imports(t, package, set(modules)) for m, (t, _) in modules.items()})
    fam.external = {m: {a.asname or a.name.partition(".")[0] for n in ast.walk(t) if isinstance(n, ast.Import)
                        for a in n.names} for m, (t, _) in modules.items()}
    fam.classes = {(m, n.name): n for m, (t, _) in modules.items() for n in t.body if isinstance(n, ast.ClassDef)}
    driver = next(n for n in modules["driver"][0].body if isinstance(n, ast.ClassDef) and n.name.endswith("Driver"))
    fam.driver = ("driver", driver.name)
    for (m, name), cls in fam.classes.items():
        fam.nodes[(m, name)] = (cls, m, None)
        for f in cls.body:
            if isinstance(f, ast.FunctionDef):
                fam.nodes[(m, f"{name}.{f.name}")] = (f, m, (m, name))
    for m, (t, _) in modules.items():
        fam.nodes.update({(m, n.name): (n, m, None) for n in t.body if isinstance(n, ast.FunctionDef)})
    fam.mixins = set(fam.bases(fam.driver))
    for cls in [*sorted(fam.mixins), fam.driver]:  # the driver itself is not a helper of its moves
        del fam.nodes[cls]
        for f in fam.classes[cls].body:
            if isinstance(f, ast.FunctionDef):
                del fam.nodes[(cls[0], f"{cls[1]}.{f.name}")]
                fam.nodes[("self", f.name)] = (f, cls[0], fam.driver)
    _learn_attribute_types(fam, driver)
    return fam


def _learn_attribute_types(fam: _Family, driver: ast.ClassDef) -> None:
    """``self.x``'s class for every family class, from annotations and typed assignments in its methods."""
    for cls in fam.classes:
        key = fam.driver if cls in fam.mixins else cls
        types = fam.attr_types.setdefault(key, {})
        for _ in range(2):  # an assignment may use an attribute typed by another one
            for f in fam.classes[cls].body:
                if not isinstance(f, ast.FunctionDef):
                    continue
                env = _Env(fam, cls[0], key, f)
                for n in ast.walk(f):
                    target, value = None, None
                    if isinstance(n, ast.AnnAssign):
                        target, t = n.target, fam.resolve_name(cls[0], n.annotation)
                        if _is_self_attr(target) and t in fam.classes:
                            types[target.attr] = t
                        continue
                    if isinstance(n, ast.Assign) and len(n.targets) == 1:
                        target, value = n.targets[0], n.value
                    if _is_self_attr(target) and target.attr not in types and (t := env.type_of(value)):
                        if t[0] == "instance":
                            types[target.attr] = t[1]
    for stmt in driver.body:  # the driver's options are its options_class
        if isinstance(stmt, ast.Assign) and any(getattr(t, "id", "") == "options_class" for t in stmt.targets):
            if (t := fam.resolve_name("driver", stmt.value)) in fam.classes:
                fam.attr_types[fam.driver].setdefault("options", t)


def _is_self_attr(node) -> bool:
    return isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "self"


class _Env:
    """The types of the names inside one function: ``self``, annotated parameters, typed local assignments."""

    def __init__(self, fam: _Family, mod: str, self_cls: tuple[str, str] | None, func: ast.AST):
        self.fam, self.mod = fam, mod
        self.names: dict[str, tuple[str, str]] = {}
        if isinstance(func, ast.FunctionDef):
            args = func.args.posonlyargs + func.args.args + func.args.kwonlyargs
            for i, a in enumerate(args):
                if i == 0 and self_cls is not None and a.arg == "self":
                    self.names["self"] = self_cls
                elif a.annotation is not None and (t := fam.resolve_name(mod, a.annotation)) in fam.classes:
                    self.names[a.arg] = fam.driver if t in fam.mixins else t
                elif a.arg == "drv":
                    self.names["drv"] = fam.driver
            for _ in range(2):
                for n in ast.walk(func):
                    if isinstance(n, ast.Assign) and len(n.targets) == 1:
                        self._bind(n.targets[0], n.value)

    def _bind(self, target, value) -> None:
        if isinstance(target, ast.Tuple) and isinstance(value, ast.Tuple) and len(target.elts) == len(value.elts):
            for t, v in zip(target.elts, value.elts):
                self._bind(t, v)
        elif isinstance(target, ast.Name) and (t := self.type_of(value)) and t[0] == "instance":
            self.names.setdefault(target.id, t[1])

    def type_of(self, expr) -> tuple | None:
        """("instance", cls), ("class", cls), ("module", stem), ("callable", key) or None (unknown)."""
        fam = self.fam
        if isinstance(expr, ast.Name):
            if expr.id in self.names:
                return "instance", self.names[expr.id]
            if expr.id in fam.imports[self.mod][0]:
                return "module", fam.imports[self.mod][0][expr.id]
            r = fam.resolve_name(self.mod, expr)
            return None if r is None else ("class", r) if r in fam.classes else ("callable", r)
        if isinstance(expr, ast.Attribute):
            base = self.type_of(expr.value)
            if base is None:
                return None
            if base[0] == "module":
                r = (base[1], expr.attr)
                return ("class", r) if r in fam.classes else ("callable", r) if r in fam.nodes else None
            if base[0] in ("instance", "class"):
                cls = base[1]
                if base[0] == "instance" and (t := fam.attr_types.get(cls, {}).get(expr.attr)):
                    return "instance", t
                k = fam.owner_key(cls, expr.attr)
                return None if k is None else ("callable", k)
            return None
        if isinstance(expr, ast.Call):
            f = self.type_of(expr.func)
            if f and f[0] == "class":
                return "instance", f[1]
            if f and f[0] == "callable":
                node, mod, _ = fam.nodes[f[1]]
                if isinstance(node, ast.FunctionDef) and node.returns is not None:
                    if (t := fam.resolve_name(mod, node.returns)) in fam.classes:
                        return "instance", fam.driver if t in fam.mixins else t
        return None


def _refs(fam: _Family, key: Key, not_guessed: set[Key]):
    """(key, typed) of what ``key`` reaches; an untyped attribute guesses by name, never a key in ``not_guessed``."""
    node, mod, cls = fam.nodes[key]
    if isinstance(node, ast.ClassDef) and (mod, node.name) not in fam.mixins | {fam.driver}:
        for name in ("__init__", "__post_init__"):
            if (k := fam.owner_key((mod, node.name), name)) is not None:
                yield k, True
        walk = [n for stmt in node.body if not isinstance(stmt, ast.FunctionDef) for n in ast.walk(stmt)]
        walk += [n for b in node.bases + node.decorator_list for n in ast.walk(b)]
    else:
        walk = list(ast.walk(node))
    env = _Env(fam, mod, fam.driver if key[0] == "self" else cls, node)
    by_name: dict[str, list[Key]] = {}
    for k in fam.nodes:
        by_name.setdefault(k[1].rpartition(".")[2], []).append(k)
    for n in walk:
        if isinstance(n, ast.Attribute):
            base = env.type_of(n.value)
            t = env.type_of(n)
            if base is not None and base[0] == "instance" and base[1] in fam.nodes:
                yield base[1], True  # an object of a family class in use: its class (and construction) too
            if t is not None and t[0] in ("callable", "class"):
                if t[1] not in {("self", h) for h in MOVE_HOOKS}:
                    yield t[1], True
            elif base is None and getattr(n.value, "id", None) not in fam.external[mod] \
                    and not n.attr.startswith("__"):  # super().__init__ is the base's
                yield from ((k, False) for k in by_name.get(n.attr, []) if (k[0] == "self" or "." in k[1])
                            and k not in {("self", h) for h in MOVE_HOOKS} and k not in not_guessed)
        elif isinstance(n, ast.Name) and (r := fam.resolve_name(mod, n)) is not None and r in fam.nodes:
            yield r, True


def _reach(fam: _Family, roots, not_guessed: set[Key]) -> tuple[set[Key], set[Key]]:
    """Everything reached from ``roots``, and what of it was reached through a resolved reference."""
    seen: set[Key] = set()
    typed = set(roots)
    todo = list(roots)
    while todo:
        if (k := todo.pop()) not in seen:
            seen.add(k)
            for r, is_typed in _refs(fam, k, not_guessed):
                typed |= {r} if is_typed else set()
                todo.append(r)
    return seen, typed


def _code_lines(node: ast.AST, lines: list[str]) -> int:
    skip = {i for n in ast.walk(node) if isinstance(n, (ast.FunctionDef, ast.ClassDef))
            and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)
            for i in range(n.body[0].lineno, n.body[0].end_lineno + 1)}
    if isinstance(node, ast.ClassDef):  # its methods are nodes of their own
        skip |= {i for f in node.body if isinstance(f, ast.FunctionDef)
                 for i in range(f.lineno - len(f.decorator_list), f.end_lineno + 1)}
    return sum(1 for i in range(node.lineno, node.end_lineno + 1)
               if i not in skip and lines[i - 1].strip() and not lines[i - 1].strip().startswith("#"))


def move_code(folder: Path, package: str | None = None) -> tuple[int, list[str]]:
    """A family's move code (module docstring): (code lines, the names counted, as ``module.name``,
    ``module.Class.method`` or ``self.method``)."""
    fam = _parse(folder, package or f"payload_agent.drivers.{folder.name}")
    hooks = [("self", h) for h in MOVE_HOOKS if ("self", h) in fam.nodes]
    shared = [("self", r) for r in SHARED_ROOTS if ("self", r) in fam.nodes]
    moved, moved_typed = _reach(fam, hooks, set())
    shared_keys, _ = _reach(fam, shared, moved_typed)
    # a class whose methods the shared code uses is shared, its construction with it
    used = {fam.nodes[k][2] for k in shared_keys if fam.nodes[k][2] is not None} | (shared_keys & set(fam.classes))
    shared_keys |= {k for k, (_, _, cls) in fam.nodes.items() if k in used or (cls in used and k[1].rpartition(".")[2]
                                                                              in ("__init__", "__post_init__"))}
    own = moved - shared_keys
    return (sum(_code_lines(fam.nodes[k][0], fam.modules[fam.nodes[k][1]][1]) for k in own),
            sorted(f"{m}.{n}" for m, n in own))
