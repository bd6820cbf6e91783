"""The library is pure (no rclpy), and the code passes ruff and mypy (strict on the library)."""

from __future__ import annotations

import pkgutil
import subprocess
import sys
from pathlib import Path

import positioning_cell

REPO = Path(__file__).resolve().parent.parent


def library_modules() -> list[str]:
    """Every module of the package outside positioning_cell.nodes."""
    names = []
    for info in pkgutil.walk_packages(positioning_cell.__path__, 'positioning_cell.'):
        if not info.name.startswith('positioning_cell.nodes'):
            names.append(info.name)
    return names


def test_library_imports_without_rclpy() -> None:
    modules = library_modules()
    assert 'positioning_cell.kinematics' in modules and 'positioning_cell.clearance' in modules
    code = (
        'import importlib, sys\n'
        f'for name in {modules!r}:\n'
        '    importlib.import_module(name)\n'
        "bad = sorted(m for m in sys.modules if m.split('.')[0] == 'rclpy')\n"
        'assert not bad, bad\n'
    )
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            check=False)
    assert result.returncode == 0, result.stderr


def test_ruff() -> None:
    result = subprocess.run([sys.executable, '-m', 'ruff', 'check', '--no-cache', '.'],
                            cwd=REPO, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout + result.stderr


def test_mypy_strict_on_the_library() -> None:
    files = [str(p.relative_to(REPO)) for p in sorted((REPO / 'positioning_cell').rglob('*.py'))
             if 'nodes' not in p.parts]
    result = subprocess.run(
        [sys.executable, '-m', 'mypy', '--strict', '--cache-dir', '/dev/null', *files],
        cwd=REPO, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout + result.stderr


def test_mypy_on_the_nodes() -> None:
    result = subprocess.run(
        [sys.executable, '-m', 'mypy', '--cache-dir', '/dev/null', 'positioning_cell/nodes'],
        cwd=REPO, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
