"""The layering (docs/CONVENTIONS.md, docs/ARCHITECTURE.md): solver <- body, sim, backends <- agent <- kinds <- tools.
What each package may import (no exceptions), no import cycles, no compatibility shims, one class per name, no
private name imported from another module, and command modules that name no robot kind."""

import ast
import importlib
import importlib.util
import sys
from collections import defaultdict

import pytest

from conftest import ROOT

PACKAGES = ("solver", "body", "sim", "backends", "agent", "kinds", "tools")
# What each package must never import (module-level or inside functions).
FORBIDDEN = {
    "solver": ("backends", "agent", "tools", "body", "sim", "pybullet", "zmq", "cv2"),
    "body": ("backends", "agent", "tools", "sim"),
    "sim": ("backends", "agent", "tools"),
    "backends": ("agent", "tools"),
    "agent": ("backends.mock", "backends.mock_render", "body.nao_body.NaoBody_", "sim", "kinds", "tools"),
    # a kind uses tools' output helpers (tables, exports, reports) but never a command module nor the command line
    "kinds": ("tools.cli", "tools.__main__", *(f"tools.{p.stem}" for p in (ROOT / "tools").glob("cmd_*.py"))),
}


def local(name: str) -> str:
    """An imported module's name in the repository's layout: naocal.kinds.arm.model -> kinds.arm.model (the folders are the
    import package naocal's subpackages); other names as they are."""
    return name[len("naocal."):] if name.startswith("naocal.") else name


def imports_of(path):
    tree = ast.parse(path.read_text(), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            yield from (local(alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield local(node.module)


def python_files(package):
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_packages_import_only_what_their_layer_may(package):
    bad = []
    for path in python_files(package):
        relative = str(path.relative_to(ROOT))
        for name in imports_of(path):
            for forbidden in FORBIDDEN[package]:
                if name == forbidden or name.startswith(forbidden + "."):
                    bad.append(f"{relative} imports {name}")
    assert not bad, bad


def test_errors_live_in_one_home_each_without_shims():
    """A refused command is the joint limits' own (solver.limits raises it; the backends too); the robot-side errors
    live with the backends; nothing re-exports another module's names under an old name."""
    from naocal.backends import errors
    from naocal.solver import errors as solver_errors

    assert not hasattr(errors, "SafetyError")  # raised by the limits and the backends alike: solver.errors'
    source = (ROOT / "solver" / "errors.py").read_text()
    for name in ("RobotTimeout", "BridgeError"):
        assert f"class {name}" not in source and not hasattr(solver_errors, name)
        assert issubclass(getattr(errors, name), solver_errors.NaocalError)
    for old in ("solver.synthetic", "backends.pybullet_body", "solver.moved"):
        assert importlib.util.find_spec(old) is None, old
    for package in PACKAGES:
        for path in python_files(package):
            tree = ast.parse(path.read_text())
            assert not any(isinstance(node, ast.FunctionDef) and node.name == "__getattr__" for node in tree.body), \
                f"{path.relative_to(ROOT)}: a module-level __getattr__ (a compatibility shim)"


def module_name(path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph() -> dict:
    """{module: the modules of naocal it imports}, at module level or inside functions (a lazy import that dodges a
    cycle is still one): `from a.b import c` counts as a.b.c when that is a module, else a.b."""
    modules = {module_name(path): path for package in PACKAGES for path in python_files(package)}

    def resolve(name):
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph = {}
    for name, path in modules.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets.update(resolve(local(alias.name)) for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                module = local(node.module)
                targets.update(resolve(f"{module}.{alias.name}") or resolve(module) for alias in node.names)
        graph[name] = targets - {None, name}
    return graph


def cycles(graph) -> list:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(graph)))
    try:
        for v in sorted(graph):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return found


def test_the_cycle_check_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_the_import_graph_sees_the_package_s_imports():
    """The modules import each other as naocal.<folder>.<module>: the graph and the layer check must see those
    (they saw none once the folders became the naocal package, and passed whatever was imported)."""
    graph = import_graph()
    assert "solver.effects" in graph["kinds.arm.model"] and "solver.effect" in graph["solver.effects.joint_offsets"]
    assert sum(len(targets) for targets in graph.values()) > len(graph)
    assert "kinds.arm.model" in set(imports_of(ROOT / "kinds" / "arm" / "identify.py"))


def test_every_module_imports_and_no_import_forms_a_cycle():
    graph = import_graph()
    assert not cycles(graph), cycles(graph)
    for name in sorted(graph):
        if not name.endswith("__main__"):  # (runs the command line)
            importlib.import_module(name)


def test_one_class_per_name():
    """Two classes of one name with different meanings (the robot at rest and a plan's image were both `Still`; a
    feasible stance and a candidate effect both `Candidate`) are traps: one name, one concept."""
    homes = defaultdict(list)
    for package in PACKAGES:
        for path in python_files(package):
            for node in ast.parse(path.read_text()).body:
                if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                    homes[node.name].append(str(path.relative_to(ROOT)))
    twice = {name: files for name, files in homes.items() if len(files) > 1}
    assert not twice, twice


def test_command_modules_name_no_kind():
    """Each verb finds the robot kind once (kinds.for_data / kinds.for_args) and runs its body: a command module
    imports the registry `kinds` only, never a kind's package nor a kind's modules (the arm's or the NAO's)."""
    bad = []
    for path in sorted((ROOT / "tools").glob("cmd_*.py")):
        for name in imports_of(path):
            parts = name.split(".")
            if (parts[0] == "kinds" and len(parts) > 1) or any(p.startswith("arm") for p in parts[1:]):
                bad.append(f"tools/{path.name} imports {name}")
    assert not bad, bad
    assert not list((ROOT / "tools").glob("arm*.py")), "an arm module among the command modules"


def test_no_private_name_is_imported_from_another_module():
    """`from a import _b` reaches into another module's insides: what is shared gets a public name."""
    bad = []
    for package in PACKAGES:
        for path in python_files(package):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.ImportFrom) and node.module != "__future__":
                    bad += [f"{path.relative_to(ROOT)} imports {node.module}.{alias.name}" for alias in node.names
                            if alias.name.startswith("_")]
    assert not bad, bad


def test_the_kinds_beside_the_nao_live_in_their_folders():
    """A plug-in kind's modules (its model, dataset, identify, diagnose, verify, simulator, exports) are in
    kinds/<name>/, not beside the core's: the arm's stack once sat in solver/arm_*.py and backends/arm_*.py."""
    import naocal.kinds as kinds

    names = [kind.name for kind in kinds.registered() if kind is not kinds.default()]
    assert "arm" in names and "duckiebot" in names
    stray = [str(path.relative_to(ROOT)) for package in PACKAGES if package != "kinds"
             for path in python_files(package) for name in names if path.stem.startswith(name)]
    assert not stray, stray
