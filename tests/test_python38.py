"""The robot-side path runs on Python 3.8 (Duckietown's daffy containers: Ubuntu 20.04; docs/DEPLOY.md "Install and
run"): every module `naocal calibrate --robot duckiebot --backend ros` and `naocal offsets export` can import is
parsed as Python 3.8 (ast.parse(feature_version=(3, 8)): match, parenthesised context managers, except*) and
searched for what 3.8 parses but cannot run: possessive quantifiers and atomic groups in regular expressions,
builtin generics (list[int]) and X | Y of types evaluated at run time
(outside annotations, or in them without `from __future__ import annotations`), dict | dict, decorators that are
not a dotted name or call (PEP 614), a starred subscript, and the 3.9+ (and numpy 2) names below.

The modules: the static closure of naocal's imports (module-level and inside functions: conservative) from the
command line (tools/cli.py and the verbs it registers), every robot kind's __init__ (the command line asks each for
its options) and the Duckiebot's calibrate.py and ros_driver.py."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SEEDS = ["naocal/__main__.py", "tools/cli.py", "kinds/duckiebot/calibrate.py", "kinds/duckiebot/ros_driver.py",
         "kinds/duckiebot/verbs.py"]
MODULE_NAME = re.compile(r"naocal(\.[A-Za-z_]\w*)+")
NEW_REGEX = re.compile(r"\(\?>|(?<!\\)[*+?}]\+")  # `(?>...)`, `x*+`, `x++`, `x?+`, `x{n}+`: Python 3.11+ re
BUILTIN_GENERICS = {"list", "dict", "tuple", "set", "frozenset", "type"}
TYPE_NAMES = BUILTIN_GENERICS | {"int", "float", "str", "bytes", "bool", "complex", "object"}
# attributes new in Python 3.9-3.11 (str.removeprefix, argparse.BooleanOptionalAction, functools.cache ...) or in
# numpy 1.25+ / 2 (numpy 1.24 is the last for Python 3.8)
NEW_NAMES = {"removeprefix", "removesuffix", "is_relative_to", "with_stem", "readlink", "hardlink_to", "bit_count",
             "pairwise", "lcm", "BooleanOptionalAction", "randbytes", "TaskGroup", "to_thread", "ulp", "nextafter",
             "set_int_max_str_digits", "StrEnum", "cache", "UTC", "Self", "TypeAlias", "ParamSpec", "Annotated",
             "NoneType", "chdir", "ExceptionGroup", "trapezoid", "concat", "unstack", "isdtype", "vecdot",
             "matrix_transpose", "cumulative_sum", "permute_dims", "exceptions"}
NEW_MODULES = {"tomllib", "zoneinfo", "graphlib"}
NEW_KEYWORDS = {("zip", "strict"), ("dataclass", "slots"), ("dataclass", "kw_only"), ("bisect", "key"),
                ("bisect_left", "key"), ("bisect_right", "key"), ("insort", "key")}


def module_file(name: str):
    parts = name.split(".")
    if parts[0] != "naocal":
        return None
    base = ROOT.joinpath("naocal" if len(parts) == 1 else Path(*parts[1:]))
    for candidate in (base / "__init__.py", base.with_suffix(".py")):
        if candidate.is_file():
            return candidate
    return None


def imported_names(path: Path, tree) -> set:
    package = ["naocal"] + list(path.relative_to(ROOT).parts[:-1])
    if package[-1:] == ["naocal"] and len(package) == 2:
        package = ["naocal"]
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[:len(package) - node.level + 1] + ([base] if base else []))
            names |= {base} | {f"{base}.{a.name}" for a in node.names}
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "import_module" and node.args
              and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
            names.add(node.args[0].value)  # importlib.import_module("naocal.tools.cmd_...")
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and MODULE_NAME.fullmatch(node.value):
            names.add(node.value)  # a module named in a table (cli.VERB_MODULES)
    return {".".join(n.split(".")[:i]) for n in names for i in range(1, len(n.split(".")) + 1)}


def robot_side_modules() -> list:
    todo = [ROOT / s for s in SEEDS] + sorted((ROOT / "kinds").glob("*/__init__.py"))
    seen = set()
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for name in imported_names(path, ast.parse(path.read_text())):
            found = module_file(name)
            if found is not None and found not in seen:
                todo.append(found)
    return sorted(seen)


def problems(source: str, where: str = "<source>") -> list:
    """What keeps `source` from running on Python 3.8 (as far as the syntax tree shows)."""
    try:
        tree = ast.parse(source, feature_version=(3, 8))
    except SyntaxError as err:
        return [f"{where}:{err.lineno}: not Python 3.8: {err.msg}"]
    lazy_annotations = any(isinstance(n, ast.ImportFrom) and n.module == "__future__"
                           and any(a.name == "annotations" for a in n.names) for n in tree.body)
    in_annotation = set()
    for node in ast.walk(tree):
        annotations = []
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = node.args
            annotations += [x.annotation for x in a.posonlyargs + a.args + a.kwonlyargs + [a.vararg, a.kwarg]
                            if x is not None and x.annotation is not None]
            annotations += [node.returns] if node.returns is not None else []
        elif isinstance(node, ast.AnnAssign):
            annotations.append(node.annotation)
        in_annotation |= {id(sub) for annotation in annotations for sub in ast.walk(annotation)}

    def generic(n) -> bool:
        return isinstance(n, ast.Subscript) and isinstance(n.value, ast.Name) and n.value.id in BUILTIN_GENERICS

    def a_type(n, other) -> bool:
        return ((isinstance(n, ast.Name) and n.id in TYPE_NAMES) or generic(n)
                or (isinstance(n, ast.Constant) and n.value is None and isinstance(other, (ast.Name, ast.Subscript))))

    found = []
    for node in ast.walk(tree):
        at = f"{where}:{getattr(node, 'lineno', '?')}"
        evaluated = not (lazy_annotations and id(node) in in_annotation)
        if evaluated and generic(node):
            found.append(f"{at}: {node.value.id}[...] evaluated at run time (Python 3.9+)")
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):
            if evaluated and (a_type(node.left, node.right) or a_type(node.right, node.left)):
                found.append(f"{at}: X | Y of types evaluated at run time (Python 3.10+)")
            if isinstance(node.left, (ast.Dict, ast.DictComp)) or isinstance(node.right, (ast.Dict, ast.DictComp)):
                found.append(f"{at}: dict | dict (Python 3.9+)")
        if isinstance(node, ast.AugAssign) and isinstance(node.op, ast.BitOr) and isinstance(
                node.value, (ast.Dict, ast.DictComp)):
            found.append(f"{at}: dict |= dict (Python 3.9+)")
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            for decorator in node.decorator_list:
                target = decorator.func if isinstance(decorator, ast.Call) else decorator
                while isinstance(target, ast.Attribute):
                    target = target.value
                if not isinstance(target, ast.Name):
                    found.append(f"{at}: a decorator that is not a dotted name or call (Python 3.9+)")
        if isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Tuple) and any(
                isinstance(e, ast.Starred) for e in node.slice.elts):
            found.append(f"{at}: a starred subscript (Python 3.11+)")
        if isinstance(node, ast.Attribute) and node.attr in NEW_NAMES:
            found.append(f"{at}: .{node.attr} (Python 3.9+ or numpy 1.25+)")
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            modules = [a.name for a in node.names] + ([node.module] if isinstance(node, ast.ImportFrom) else [])
            found += [f"{at}: module {m} (Python 3.9+)" for m in modules if m and m.split(".")[0] in NEW_MODULES]
            if isinstance(node, ast.ImportFrom) and node.module != "__future__":
                found += [f"{at}: {a.name} (Python 3.9+)" for a in node.names if a.name in NEW_NAMES]
        if isinstance(node, ast.Call):
            name = node.func.id if isinstance(node.func, ast.Name) else getattr(node.func, "attr", "")
            found += [f"{at}: {name}({k.arg}=) (Python 3.10+)" for k in node.keywords if (name, k.arg) in NEW_KEYWORDS]
            if (isinstance(node.func, ast.Attribute) and isinstance(node.func.value, ast.Name)
                    and node.func.value.id == "re" and node.args and isinstance(node.args[0], ast.Constant)
                    and isinstance(node.args[0].value, str) and NEW_REGEX.search(node.args[0].value)):
                found.append(f"{at}: a possessive quantifier or atomic group in a regular expression (Python 3.11+)")
    return found


def test_the_robot_side_modules_run_on_python_3_8():
    modules = robot_side_modules()
    names = {str(m.relative_to(ROOT)) for m in modules}
    assert {"kinds/duckiebot/ros_driver.py", "kinds/duckiebot/mission.py", "kinds/duckiebot/drive_log.py",
            "kinds/nao/options.py", "solver/fileio.py", "agent/rundir.py"} <= names, sorted(names)
    found = [p for m in modules for p in problems(m.read_text(), str(m.relative_to(ROOT)))]
    assert not found, "\n".join(found)


@pytest.mark.parametrize("source", [
    "with (open('a') as f, open('b') as g):\n    pass\n",
    "match x:\n    case 1:\n        pass\n",
    "name = text.removeprefix('db')\n",
    "both = {'a': 1} | other\n",
    "Rows = list[tuple[int, int]]\n",
    "ok = isinstance(x, int | float)\n",
    "def f(x: list[int]) -> None:\n    pass\n",  # evaluated at definition without the __future__ import
    "import argparse\np.add_argument('--x', action=argparse.BooleanOptionalAction)\n",
    "for a, b in zip(x, y, strict=True):\n    pass\n",
    "from dataclasses import dataclass\n@dataclass(frozen=True, kw_only=True)\nclass C:\n    a: int\n",
    "import numpy as np\narea = np.trapezoid(y, x)\n",
    "@buttons[0].connect\ndef f():\n    pass\n",
    "import tomllib\n",
    "import re\nSTRING = re.compile(r'\"(?:[^\"\\\\]++|\\\\.)*+\"')\n",
])
def test_the_check_finds_what_python_3_8_cannot_run(source):
    assert problems(source)


def test_the_check_passes_what_python_3_8_runs():
    source = ("from __future__ import annotations\nimport os\nfrom dataclasses import dataclass\n\n"
              "@dataclass(frozen=True)\nclass C:\n    a: list[int] | None = None\n\n"
              "def f(x: dict[str, int], flags: int) -> tuple[int, ...]:\n    return (flags | os.O_APPEND,)\n"
              "merged = {**x, **y}\nrows = [(t, a) for t, a in zip(x, y)]\n"
              "import re\nPLUS = re.compile(r'a\\++|[+]+|x{2}')\n")
    assert problems(source) == []
