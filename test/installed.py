"""An installed copy of the package checked against the source tree: every module there, and
each one importing from that copy alone (shared by the wheel and the colcon install tests)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PACKAGE = 'positioning_cell'

# Runs in a child: imports every module and resolves every entry point, then says which failed
# and which positioning_cell module came from somewhere other than the installed copy.
_CHILD = r'''
import importlib, json, sys
from pathlib import Path

site, request, answer = Path(sys.argv[1]).resolve(), Path(sys.argv[2]), Path(sys.argv[3])
# The venv's editable install of the source tree (setuptools' __editable__ finder) serves any
# immediate subpackage the installed copy lacks: out of the way, so that such a one fails.
sys.meta_path[:] = [f for f in sys.meta_path
                    if not getattr(f, '__module__', '').startswith('__editable__')]
wanted = json.loads(request.read_text())
failed = {}
for name in wanted['modules']:
    try:
        importlib.import_module(name)
    except Exception as exc:
        failed[name] = f'{type(exc).__name__}: {exc}'
for name, target in wanted['entry_points'].items():
    module, _, attr = target.partition(':')
    try:
        obj = importlib.import_module(module)
        for part in attr.split('.'):
            obj = getattr(obj, part)
        if not callable(obj):
            raise TypeError('not callable')
    except Exception as exc:
        failed[f'{name} = {target}'] = f'{type(exc).__name__}: {exc}'
outside = {}
for name, module in list(sys.modules.items()):
    if name == 'positioning_cell' or name.startswith('positioning_cell.'):
        file = getattr(module, '__file__', None)
        if file is None or not Path(file).resolve().is_relative_to(site):
            outside[name] = file
package = sys.modules.get('positioning_cell')
answer.write_text(json.dumps({'failed': failed, 'outside': outside,
                              'package': getattr(package, '__file__', None)}))
'''


def source_files() -> list[str]:
    """Every module file of the source tree, relative to the repository
    (``positioning_cell/.../x.py``)."""
    return sorted(p.relative_to(REPO).as_posix() for p in (REPO / PACKAGE).rglob('*.py')
                  if '__pycache__' not in p.parts)


def module_name(file: str) -> str:
    """``positioning_cell/a/b.py`` → ``positioning_cell.a.b``; a package's ``__init__.py`` →
    the package."""
    parts = file.removesuffix('.py').split('/')
    return '.'.join(parts[:-1] if parts[-1] == '__init__' else parts)


def installed_files(site: Path) -> list[str]:
    """Every module file of the package installed under ``site`` (a site-packages or target
    directory), relative to it."""
    return sorted(p.relative_to(site).as_posix() for p in (site / PACKAGE).rglob('*.py')
                  if '__pycache__' not in p.parts)


def _import_alone(site: Path, entry_points: dict[str, str], work: Path) -> dict[str, object]:
    """Import every module of the source tree, and resolve each ``name → 'module:attr'`` entry
    point, in a child Python whose only path to the package is ``site``: run from ``work`` (an
    empty directory, not the source tree), PYTHONPATH ``site`` alone, the venv's editable
    finder removed. Returns ``failed`` (name → error), ``outside`` (positioning_cell modules
    not loaded from ``site`` → their file) and ``package`` (positioning_cell's ``__file__``)."""
    request, answer = work / 'request.json', work / 'answer.json'
    request.write_text(json.dumps({'modules': [module_name(f) for f in source_files()],
                                   'entry_points': entry_points}))
    env = dict(os.environ, PYTHONPATH=str(site), PYTHONDONTWRITEBYTECODE='1')
    env.pop('PYTHONHOME', None)
    result = subprocess.run([sys.executable, '-c', _CHILD, str(site), str(request), str(answer)],
                            cwd=work, env=env, capture_output=True, text=True, check=False,
                            timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    found: dict[str, object] = json.loads(answer.read_text())
    return found


def check_installed_copy(site: Path, entry_points: dict[str, str], work: Path) -> None:
    """The package installed under ``site`` is whole: every module file of the source tree and
    no other, each module importing from ``site`` alone (with positioning_cell itself from
    there), each entry point resolving to a callable. ``work``: an empty directory."""
    files = installed_files(site)
    missing = sorted(set(source_files()) - set(files))
    assert not missing, f'not installed (a folder without __init__.py?): {missing}'
    assert files == source_files(), sorted(set(files) - set(source_files()))
    found = _import_alone(site, entry_points, work)
    assert found['failed'] == {}, found['failed']
    assert found['outside'] == {}, found['outside']
    assert Path(str(found['package'])).resolve() == (site / PACKAGE / '__init__.py').resolve()
