"""The rules the layout keeps: the library reaches no ROS by any means (one AST test, and the
import itself), every wire name comes from positioning_cell.names, and the code passes ruff
and mypy (strict on the library)."""

from __future__ import annotations

import ast
import configparser
import importlib.util
import subprocess
import sys
from functools import cache
from pathlib import Path

import positioning_cell

REPO = Path(__file__).resolve().parent.parent
PACKAGE = REPO / 'positioning_cell'
#: The ROS layer, by folder: the nodes and the ROS adapter they share with the tools. Nothing
#: else imports rclpy or a ROS message type.
ROS_LAYER = ('nodes/', 'ros/')
#: The command lines (argparse shells) and the test harness: they may use the ROS adapter,
#: never rclpy itself.
ADAPTER_USERS = ('tools/', 'testing/')


def _rel(path: Path) -> str:
    return path.relative_to(PACKAGE).as_posix()


def in_ros_layer(path: Path) -> bool:
    rel = _rel(path)
    return any(rel.startswith(r) for r in ROS_LAYER)


def in_library(path: Path) -> bool:
    """Neither the ROS layer nor a command line nor the test harness: the pure library."""
    return not in_ros_layer(path) and not _rel(path).startswith(ADAPTER_USERS)


def sources() -> list[Path]:
    return sorted(PACKAGE.rglob('*.py'))


@cache
def is_ros_package(name: str) -> bool:
    """rclpy, the launch system, or a ROS interface package (one with msg, srv or action)."""
    if name in ('rclpy', 'launch', 'launch_ros', 'rosidl_runtime_py'):
        return True
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        return False
    return any((Path(loc) / sub).is_dir() for loc in spec.submodule_search_locations
               for sub in ('msg', 'srv', 'action'))


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import in ``path``, at any depth (function bodies too)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.lineno, node.module))
    return out


def dynamic_imports(path: Path) -> list[int]:
    """Lines that import by name at run time: importlib or __import__."""
    lines = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.id if isinstance(func, ast.Name) else (
                func.attr if isinstance(func, ast.Attribute) else '')
            if name in ('__import__', 'import_module'):
                lines.append(node.lineno)
    return lines


def test_nothing_outside_the_ros_layer_reaches_ros() -> None:
    """Outside ``nodes/`` and ``ros/``: no import of rclpy, the launch system, a ROS message
    package or the nodes (at any depth), and no import by name at run time; the library
    (outside ``tools/`` too) does not import the ROS adapter either."""
    found = []
    for path in sources():
        if in_ros_layer(path):
            continue
        rel = path.relative_to(REPO)
        for line, module in imported_modules(path):
            top = module.split('.')[0]
            if is_ros_package(top) or module.startswith('positioning_cell.nodes'):
                found.append(f'{rel}:{line} imports {module}')
            elif in_library(path) and module.startswith('positioning_cell.ros'):
                found.append(f'{rel}:{line} imports the ROS adapter {module}')
        found += [f'{rel}:{line} imports by name' for line in dynamic_imports(path)]
    assert not found, found
    # The rule can fail: the ROS layer itself does reach ROS.
    assert any(is_ros_package(m.split('.')[0])
               for _, m in imported_modules(PACKAGE / 'ros' / 'spin.py'))


def module_name(path: Path) -> str:
    return '.'.join(path.relative_to(REPO).with_suffix('').parts).removesuffix('.__init__')


def module_imports(path: Path, known: set[str]) -> set[str]:
    """The project's modules that ``path`` imports when it is loaded: the imports at module
    level (under ``if TYPE_CHECKING`` and ``try`` too), not those in function bodies."""
    tree = ast.parse(path.read_text(), str(path))
    package = module_name(path) if path.name == '__init__.py' else \
        module_name(path).rpartition('.')[0]
    found: set[str] = set()

    def visit(body: list[ast.stmt]) -> None:
        for node in body:
            if isinstance(node, ast.If):
                visit(node.body)
                visit(node.orelse)
            elif isinstance(node, ast.Try):
                visit(node.body)
                visit(node.orelse)
                visit(node.finalbody)
            elif isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name in known)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ''
                if node.level:
                    parts = package.split('.')
                    base = '.'.join(parts[:len(parts) - node.level + 1] + ([base] if base else []))
                for alias in node.names:
                    sub = f'{base}.{alias.name}'
                    found.add(sub if sub in known else base)
    visit(tree.body)
    return found & known


def import_graph() -> dict[str, set[str]]:
    """Module → the project's modules it imports at load time."""
    paths = {module_name(p): p for p in sources()}
    known = set(paths)
    return {m: module_imports(p, known) - {m} for m, p in paths.items()}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return found


def test_no_import_cycle() -> None:
    """No module imports, through others, itself when it loads."""
    assert cycles(import_graph()) == []
    # The check can fail: a cycle it is shown is found.
    assert cycles({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': set()}) == [['a', 'b', 'c']]


#: Below the positioner's move state machine: the library that ``motion/`` uses and that must
#: not use it back (the motion vocabulary lives in ``moves/``).
BELOW_MOTION = ('core', 'clearance', 'mechanics', 'limits', 'moves', 'calibration', 'frames',
                'metrology', 'sim', 'accuracy', 'prediction', 'tolerance', 'bag', 'recording')


def test_no_arrow_from_the_library_up_into_motion() -> None:
    """The library under ``motion/`` does not import it."""
    graph = import_graph()
    up = [f'{m} -> {d}' for m, deps in graph.items() for d in deps
          if m.split('.')[1:2] and m.split('.')[1] in BELOW_MOTION
          and d.startswith('positioning_cell.motion')]
    assert not up, up
    assert 'positioning_cell.moves.trajectory' in graph['positioning_cell.motion.mover']


def test_the_library_imports_without_rclpy() -> None:
    """Importing every module of the library and the command lines loads no rclpy, but for
    the command lines that use the ROS adapter."""
    names = []
    for path in sources():
        imports_adapter = any(m.startswith('positioning_cell.ros')
                              for _, m in imported_modules(path))
        if not in_ros_layer(path) and not imports_adapter:
            names.append(module_name(path))
    assert 'positioning_cell.core.kinematics' in names and 'positioning_cell.clearance' in names
    code = ('import importlib, sys\n'
            f'for name in {names!r}:\n'
            '    importlib.import_module(name)\n'
            "bad = sorted(m for m in sys.modules if m.split('.')[0] == 'rclpy')\n"
            'assert not bad, bad\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            check=False)
    assert result.returncode == 0, result.stderr


def string_constants(path: Path) -> list[tuple[int, str]]:
    """(line, text) of the string constants of ``path`` that are not docstrings."""
    tree = ast.parse(path.read_text(), str(path))
    docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                  if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef,
                                    ast.AsyncFunctionDef))
                  and n.body and isinstance(n.body[0], ast.Expr)
                  and isinstance(n.body[0].value, ast.Constant)}
    return [(n.lineno, n.value) for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str)
            and id(n) not in docstrings]


def test_every_wire_name_is_declared_once() -> None:
    """Topic and service names appear as strings only in positioning_cell/names.py."""
    from positioning_cell import names

    wire = {v for k, v in vars(names).items() if k.isupper() and isinstance(v, str)
            and v.startswith('/')}
    assert '/legs/joint_states' in wire and '/positioner/move_to_pose' in wire
    found = [f'{path.relative_to(REPO)}:{line} {text!r}' for path in sources()
             if path.name != 'names.py' for line, text in string_constants(path)
             if text in wire]
    assert not found, found


def test_ruff() -> None:
    result = subprocess.run([sys.executable, '-m', 'ruff', 'check', '--no-cache', '.'],
                            cwd=REPO, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout + result.stderr


@cache
def _mypy_run() -> tuple[int, str]:
    """mypy over the whole package, once for both checks below, with the rules of the mypy
    configuration alone (setup.cfg: strict, the ROS layer relaxed: one run applies each
    module's own section): its exit status and output. Its incremental cache is kept in the
    checkout's .test-tmp (ignored by git; ``make setup`` fills it), so a run checks only what
    changed since. One run, not one per layer: the ROS layer's run checked the library it
    imports all over again (cold, on an idle 2-core VM: 66 s of CPU and 39 s of wall time for
    the two side by side against 37 s and 37 s for one; the parallel tier is bound by its
    CPU)."""
    files = [str(p.relative_to(REPO)) for p in sources()]
    result = subprocess.run([sys.executable, '-m', 'mypy', '--cache-dir',
                             str(REPO / '.test-tmp' / 'mypy_cache' / 'package'), *files],
                            cwd=REPO, capture_output=True, text=True, check=False, timeout=600)
    return result.returncode, result.stdout + result.stderr


def _mypy(ros_layer: bool) -> None:
    """No mypy error in the library (``ros_layer`` False) or in the ROS layer (True); an
    error outside the package, or a run that failed without naming an error (a crash), fails
    both."""
    code, out = _mypy_run()
    errors = [line for line in out.splitlines() if ': error:' in line]
    paths = [REPO / line.split(':', 1)[0] for line in errors]
    mine = [line for line, path in zip(errors, paths, strict=True)
            if not path.is_relative_to(PACKAGE) or in_ros_layer(path) == ros_layer]
    assert not mine, '\n'.join(mine)
    assert code == 0 or errors, out


def test_the_mypy_configuration_is_strict_on_the_library() -> None:
    """setup.cfg carries strict; only the ROS layer (nodes/, ros/) has relaxed sections."""
    config = configparser.ConfigParser()
    config.read(REPO / 'setup.cfg')
    assert config.getboolean('mypy', 'strict')
    relaxed = [m.strip() for s in config.sections() if s.startswith('mypy-positioning_cell')
               for m in s.removeprefix('mypy-').split(',')]
    assert relaxed and all(m in ('positioning_cell.nodes.*', 'positioning_cell.ros.*')
                           for m in relaxed), relaxed


def test_mypy_strict_on_the_library() -> None:
    _mypy(ros_layer=False)


def test_mypy_on_the_ros_layer() -> None:
    _mypy(ros_layer=True)


def test_nodes_stay_thin() -> None:
    """A node is parameters, subscriptions, publishers and one library call per callback."""
    for path in sorted((PACKAGE / 'nodes').glob('*_node.py')):
        lines = len(path.read_text().splitlines())
        assert lines <= 200, f'{path.name}: {lines} lines'
    assert positioning_cell.__version__


class _MarkExpression:
    """The part of pytest's config that conftest.pytest_ignore_collect reads: ``-m``."""

    def __init__(self, expression: str) -> None:
        self.expression = expression

    def getoption(self, name: str) -> str:
        assert name == 'markexpr'
        return self.expression


def test_every_timing_test_is_collected_by_the_timing_tier() -> None:
    """make test's second tier runs ``-m timing``: a module holding a test marked timing,
    at module level or on the test alone, must not be left out of its collection (one
    marked on the test alone in a module marked nodes was left out of both tiers)."""
    from conftest import decorated_marks, module_marks, pytest_ignore_collect

    timing = [path for path in sorted((REPO / 'test').glob('test_*.py'))
              if 'timing' in module_marks(path)
              or any('timing' in marks for marks in decorated_marks(path))]
    assert REPO / 'test' / 'test_recorder_node.py' in timing  # marked on one test only
    left_out = [path.name for path in timing
                if pytest_ignore_collect(path, _MarkExpression('timing')) is not None]  # type: ignore[arg-type]
    assert not left_out, left_out
    library = _MarkExpression('not nodes and not slow')  # make test-library: none of these
    assert all(pytest_ignore_collect(path, library) for path in timing  # type: ignore[arg-type]
               if 'nodes' in module_marks(path))
