"""Every third-party import of the package is declared where each install path looks: pip's
``install_requires`` (setup.py) and ``package.xml`` (an exec_depend with its rosdep key); and
nothing is declared that the code does not use."""

from __future__ import annotations

import ast
import re
import sys
import xml.etree.ElementTree as ET
from importlib.metadata import distribution, packages_distributions
from pathlib import Path

from test_code_quality import imported_modules, is_ros_package

REPO = Path(__file__).resolve().parent.parent
#: rosdep key of each pip distribution the code imports (rosdistro rosdep/python.yaml).
#: mcap has no key of its own: mcap-ros2-support's pip rule installs it.
ROSDEP = {'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'numba': 'python3-numba',
          'pyyaml': 'python3-yaml', 'matplotlib': 'python3-matplotlib',
          'ruamel-yaml': 'python3-ruamel.yaml', 'rosbags': 'python3-rosbags-pip',
          'mcap': 'mcap-ros2-support', 'rich': 'python3-rich',
          'foxglove-sdk': 'python3-foxglove-sdk-pip', 'dask': 'python3-dask-pip',
          'zstandard': 'python3-zstandard-pip', 'lz4': 'python3-lz4-pip',
          'distributed': 'python3-distributed-pip'}
#: Distributions that an extra of a requirement brings and the code reaches only through the
#: requiring distribution's modules (dask[distributed]: ``dask.distributed`` is the
#: distributed package): each needs its rosdep key and its pin in the `cell` extra too.
THROUGH = {'dask': ('distributed',)}
#: Declared but never imported: the build system's own.
BUILD_ONLY = {'setuptools'}


def normalised(name: str) -> str:
    """A distribution name as PEP 503 compares them."""
    return re.sub(r'[-_.]+', '-', name).lower()


def third_party_imports() -> dict[str, set[str]]:
    """Top-level imported names of the package and its launch files → the files importing
    them; the standard library and the package itself left out."""
    found: dict[str, set[str]] = {}
    files = [*(REPO / 'positioning_cell').rglob('*.py'), *(REPO / 'launch').glob('*.py')]
    for path in files:
        for _, module in imported_modules(path):
            top = module.split('.')[0]
            if top in sys.stdlib_module_names or top in ('positioning_cell', '__future__'):
                continue
            found.setdefault(top, set()).add(str(path.relative_to(REPO)))
    return found


def install_requires() -> set[str]:
    tree = ast.parse((REPO / 'setup.py').read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call)
                and getattr(n.func, 'id', '') == 'setup')
    value = next(k.value for k in call.keywords if k.arg == 'install_requires')
    names = ast.literal_eval(value)
    return {normalised(re.split(r'[<>=!~ \[]', n)[0]) for n in names}


def exec_depends() -> set[str]:
    root = ET.parse(REPO / 'package.xml').getroot()
    return {e.text.strip() for e in root.iter('exec_depend') if e.text}


def test_every_import_is_declared_for_pip_and_rosdep() -> None:
    imports = third_party_imports()
    dists = packages_distributions()
    pip, rosdep = install_requires(), exec_depends()
    missing = []
    used_dists, used_keys = set(), set()
    for top, files in sorted(imports.items()):
        if is_ros_package(top) or top == 'ament_index_python':
            used_keys.add(top)
            if top not in rosdep:
                missing.append(f'{top} (in {sorted(files)}): no <exec_depend>{top}')
            continue
        dist = normalised(dists[top][0]) if top in dists else top
        used_dists.add(dist)
        if dist not in pip:
            missing.append(f'{top} (in {sorted(files)}): {dist} not in install_requires')
        for needed in (dist, *THROUGH.get(dist, ())):
            key = ROSDEP.get(needed)
            if key is None:
                missing.append(f'{top}: add the rosdep key of {needed} to ROSDEP and '
                               'package.xml')
            else:
                used_keys.add(key)
                if key not in rosdep:
                    missing.append(f'{top}: no <exec_depend>{key}')
    assert not missing, missing
    assert {'numpy', 'rosbags', 'mcap', 'matplotlib'} <= used_dists
    unused = sorted((pip - used_dists - BUILD_ONLY) | (rosdep - used_keys))
    assert not unused, f'declared but not imported: {unused}'


def test_the_extras_pin_every_runtime_dependency() -> None:
    """The `cell` extra (what make setup installs) pins an exact version of each."""
    cell = distribution('positioning_cell').requires or []
    pinned = {normalised(r.split('==')[0]) for r in cell if '==' in r and 'extra == "cell"' in r}
    wanted = install_requires() - BUILD_ONLY
    wanted |= {d for w in wanted for d in THROUGH.get(w, ())}
    assert wanted <= pinned, wanted - pinned
