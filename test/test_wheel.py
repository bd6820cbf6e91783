"""The package installs whole: the wheel built from the source tree holds every module and data
file of it, and every module (and console script) imports from that wheel alone. An editable
install (make setup's) never shows a package the wheel leaves out: it serves it from the source
tree."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from importlib.metadata import Distribution
from pathlib import Path

import pytest
from installed import PACKAGE, REPO, check_installed_copy, source_files

pytestmark = pytest.mark.slow

VERSION = '0.1.0'
DATA = f'{PACKAGE}-{VERSION}.data/data/'
#: What setup.py reads: the build runs on a copy of these, so that it leaves nothing in the
#: source tree and no earlier build/ folder of it can add stale modules to the wheel.
SETUP_INPUTS = ('setup.py', 'setup.cfg', 'package.xml', 'resource', 'config', 'launch', PACKAGE)


def pip(*args: str) -> None:
    result = subprocess.run([sys.executable, '-m', 'pip', *args, '--disable-pip-version-check',
                             '--no-index', '--quiet'], capture_output=True, text=True,
                            check=False, timeout=180)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]


@pytest.fixture(scope='module')
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel of the source tree, built as `pip wheel .` does, without network."""
    root = tmp_path_factory.mktemp('wheel')
    source = root / 'source'
    source.mkdir()
    for name in SETUP_INPUTS:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, source / name,
                            ignore=shutil.ignore_patterns('__pycache__', '*.pyc'))
        else:
            shutil.copy2(REPO / name, source / name)
    pip('wheel', '--no-deps', '--no-build-isolation', '--wheel-dir', str(root / 'dist'),
        str(source))
    (built,) = (root / 'dist').glob('*.whl')
    return built


def wheel_names(wheel: Path) -> set[str]:
    with zipfile.ZipFile(wheel) as archive:
        return set(archive.namelist())


def test_the_wheel_holds_every_module_of_the_source_tree(wheel: Path) -> None:
    modules = {n for n in wheel_names(wheel) if n.startswith(f'{PACKAGE}/') and n.endswith('.py')}
    missing = sorted(set(source_files()) - modules)
    assert not missing, f'not in the wheel (a folder without __init__.py?): {missing}'
    assert modules == set(source_files()), sorted(modules - set(source_files()))


def test_the_wheel_holds_the_data_files(wheel: Path) -> None:
    """The ament index marker, package.xml, every file of config/ and launch/, byte for byte."""
    expected = {f'share/ament_index/resource_index/packages/{PACKAGE}':
                REPO / 'resource' / PACKAGE,
                f'share/{PACKAGE}/package.xml': REPO / 'package.xml'}
    for folder in ('config', 'launch'):
        for path in sorted((REPO / folder).iterdir()):
            if path.is_file():
                expected[f'share/{PACKAGE}/{folder}/{path.name}'] = path
    assert any(k.endswith('/cell.yaml') for k in expected)
    assert any(k.endswith('.launch.py') for k in expected)
    with zipfile.ZipFile(wheel) as archive:
        data = {n.removeprefix(DATA) for n in archive.namelist() if n.startswith(DATA)}
        assert data == set(expected), (sorted(data - set(expected)), sorted(set(expected) - data))
        for name, path in expected.items():
            assert archive.read(DATA + name) == path.read_bytes(), name


def test_every_module_and_script_imports_from_the_wheel_alone(wheel: Path,
                                                                tmp_path: Path) -> None:
    target = tmp_path / 'target'
    pip('install', '--no-deps', '--target', str(target), str(wheel))
    installed = Distribution.at(target / f'{PACKAGE}-{VERSION}.dist-info')
    scripts = {ep.name: ep.value for ep in installed.entry_points.select(group='console_scripts')}
    assert {'analyze_bag', 'predict_accuracy', 'calibrate_cell', 'run_cell'} <= set(scripts)
    work = tmp_path / 'work'
    work.mkdir()
    check_installed_copy(target, scripts, work)
