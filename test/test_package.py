"""The package builds with colcon as on a ROS install (without --symlink-install: a copy, as a
release build installs it): ament index marker, share files, every module of the source tree,
each importing from the install alone, and every declared executable where `ros2 run` looks
(<prefix>/lib/positioning_cell/<exe>), each of which starts."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from importlib.metadata import distribution
from pathlib import Path

import pytest
from cell_harness import REPO, Client, isolated_domain, wait_until
from installed import check_installed_copy

from positioning_cell import names
from positioning_cell.ros.processes import OWN_PROCESS_GROUP

#: The installed executables start nodes.
pytestmark = pytest.mark.nodes

PACKAGE = 'positioning_cell'
# Node names of the executables (the one table: positioning_cell.names).
NODE_NAMES = {node.executable: node.name for node in names.NODE_EXECUTABLES}
#: The nodes' console entry points (positioning_cell/ros/entry.py); the tools' are their main().
NODE_ENTRY = 'positioning_cell.ros.entry:'


def declared_executables() -> dict[str, str]:
    """console_scripts of the installed distribution: name → 'module:function'."""
    eps = distribution(PACKAGE).entry_points
    return {ep.name: ep.value for ep in eps if ep.group == 'console_scripts'}


@pytest.fixture(scope='module')
def colcon_install(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp('colcon')
    env = dict(os.environ, COLCON_HOME=str(root / 'colcon_home'))
    colcon = Path(sys.executable).parent / 'colcon'
    result = subprocess.run(
        [str(colcon), 'build', '--base-paths', str(REPO), '--packages-select', PACKAGE,
         '--build-base', str(root / 'build'), '--install-base', str(root / 'install'),
         '--event-handlers', 'console_direct-'],
        cwd=root, env=env, capture_output=True, text=True, check=False, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return root / 'install'


def one_message_bag(path: Path) -> Path:
    """A bag holding one /diagnostics message."""
    from rosbags.typesys import Stores, get_typestore

    from positioning_cell.bag import BagWriter

    store = get_typestore(Stores.ROS2_JAZZY)
    msgtype = 'diagnostic_msgs/msg/DiagnosticArray'
    cls = store.types[msgtype]
    header = store.types['std_msgs/msg/Header'](
        stamp=store.types['builtin_interfaces/msg/Time'](sec=1, nanosec=0), frame_id='')
    with BagWriter(path) as writer:
        writer.write('/diagnostics', msgtype,
                     bytes(store.serialize_cdr(cls(header=header, status=[]), msgtype)), 10**9)
    return path


def ament_lookup(install: Path, code: str) -> str:
    """Run ament_index_python in a child with the colcon prefix first on AMENT_PREFIX_PATH."""
    prefix = f'{install / PACKAGE}{os.pathsep}{os.environ.get("AMENT_PREFIX_PATH", "")}'
    env = dict(os.environ, AMENT_PREFIX_PATH=prefix)
    result = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                            text=True, check=True)
    return result.stdout.strip()


def test_share_files_and_index(colcon_install: Path) -> None:
    share = Path(ament_lookup(colcon_install, (
        'from ament_index_python.packages import get_package_share_directory as g\n'
        f'print(g("{PACKAGE}"))')))
    assert share == colcon_install / PACKAGE / 'share' / PACKAGE
    assert (share / 'package.xml').is_file()
    assert (share / 'config' / 'cell.yaml').is_file()
    shipped_launch = sorted(p.name for p in (REPO / 'launch').glob('*.py'))
    assert sorted(p.name for p in (share / 'launch').glob('*.py')) == shipped_launch
    marker = (colcon_install / PACKAGE / 'share' / 'ament_index' / 'resource_index' /
              'packages' / PACKAGE)
    assert marker.is_file()


def test_config_found_through_the_index(colcon_install: Path) -> None:
    found = ament_lookup(colcon_install, (
        'from positioning_cell.config import config_path\nprint(config_path())'))
    assert found == str(colcon_install / PACKAGE / 'share' / PACKAGE / 'config' / 'cell.yaml')


def test_the_install_holds_every_module_and_each_imports_from_it_alone(
        colcon_install: Path, tmp_path: Path) -> None:
    """The copy colcon installed, not the source tree (which the venv's editable install and a
    symlink install serve, hiding a folder the copy lacks)."""
    site = (colcon_install / PACKAGE / 'lib' /
            f'python{sys.version_info.major}.{sys.version_info.minor}' / 'site-packages')
    check_installed_copy(site, declared_executables(), tmp_path)


def test_every_executable_is_where_ros2_run_looks_and_starts(colcon_install: Path,
                                                              tmp_path: Path) -> None:
    executables = declared_executables()
    prefix = Path(ament_lookup(colcon_install, (
        'from ament_index_python.packages import get_package_prefix as g\n'
        f'print(g("{PACKAGE}"))')))
    lib = prefix / 'lib' / PACKAGE
    for name in executables:
        assert os.access(lib / name, os.X_OK), f'{name} missing from {lib}'
    # The container (several nodes in one process: test_container starts it) answers --help.
    nodes = {n: v for n, v in executables.items()
             if v.startswith(NODE_ENTRY) and n != names.CONTAINER}
    tools = {n: v for n, v in executables.items() if n not in nodes}
    helps = {name: subprocess.Popen([str(lib / name), '--help'], stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True) for name in tools}
    try:
        for name, proc in helps.items():  # command-line tools answer --help (all at once)
            _, err = proc.communicate(timeout=60)
            assert proc.returncode == 0, f'{name} --help: {err}'
    finally:  # one that does not answer is not left running
        for proc in helps.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait(timeout=10)
    if not nodes:
        return
    # Nodes that need an argument to run get one: the player a one-message bag, looped.
    # (`-p node:name:=value`: a node-specific rule, which beats the file's node section.)
    node_args = {'bag_player_node': ['-p', f'bag_player:bag:={one_message_bag(tmp_path / "bag")}',
                                     '-p', 'bag_player:loop:=true'],
                 'live_view_node': ['-p', 'live_view:port:=0']}  # any free port
    with isolated_domain() as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
        env.pop('_ROS_WHEELS_BOOTSTRAP_COMPLETE', None)
        procs = {}
        try:
            for name in nodes:
                log = open(tmp_path / f'{name}.log', 'wb')  # noqa: SIM115
                procs[name] = (subprocess.Popen(
                    [str(lib / name), '--ros-args', '--params-file',
                     str(REPO / 'config' / 'cell.yaml'), *node_args.get(name, [])],
                    stdout=log, stderr=subprocess.STDOUT, env=env,
                    cwd=tmp_path, **OWN_PROCESS_GROUP), log)
            expected = {NODE_NAMES.get(n, n) for n in nodes}
            with Client(domain, 'package_test_client') as client:
                def all_up() -> bool:
                    return expected <= set(client.node.get_node_names())
                wait_until(all_up, 60.0, f'nodes {sorted(expected)} in the graph')
        finally:
            for proc, _ in procs.values():
                if proc.poll() is None:
                    proc.send_signal(signal.SIGINT)
            deadline = time.monotonic() + 20
            codes = {}
            for name, (proc, log) in procs.items():
                try:
                    codes[name] = proc.wait(timeout=max(deadline - time.monotonic(), 0.1))
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    codes[name] = proc.wait()
                log.close()
        logs = {n: (tmp_path / f'{n}.log').read_text(errors='replace')[-2000:] for n in nodes}
        assert all(code == 0 for code in codes.values()), (codes, logs)


def test_the_interface_packages_build_from_the_same_wheels() -> None:
    """interfaces/tf2_msgs is built as the project's interfaces are (docs/howto/building.md):
    the same pinned build requirements, the ROS package and version its definitions come
    from, skipped by colcon; the installed one is the standard TFMessage."""
    import tomllib
    from tf2_msgs.msg import TFMessage

    folders = [REPO / 'interfaces' / name for name in ('positioning_cell_interfaces', 'tf2_msgs')]
    builds = [tomllib.loads((f / 'pyproject.toml').read_text())['build-system'] for f in folders]
    assert builds[0] == builds[1]
    assert (REPO / 'interfaces' / 'tf2_msgs' / 'COLCON_IGNORE').is_file()
    package = ET.parse(folders[1] / 'package.xml').getroot()
    assert (package.findtext('name'), package.findtext('version')) == ('tf2_msgs', '0.36.4')
    assert (folders[1] / 'msg' / 'TFMessage.msg').read_text() == (
        'geometry_msgs/TransformStamped[] transforms\n')
    assert TFMessage.get_fields_and_field_types() == {
        'transforms': 'sequence<geometry_msgs/TransformStamped>'}


def test_colcon_finds_both_packages_from_the_documented_base_paths() -> None:
    """docs/howto/building.md: `colcon build --base-paths . interfaces` (colcon does not look for a
    package inside another package's folder)."""
    colcon = Path(sys.executable).parent / 'colcon'
    result = subprocess.run([str(colcon), '--log-base', os.devnull, 'list', '--base-paths', '.',
                             'interfaces'],
                            cwd=REPO, capture_output=True, text=True, check=False, timeout=60)
    assert result.returncode == 0, result.stderr
    found = {line.split('\t')[0]: line.split('\t')[-1] for line in result.stdout.splitlines()}
    assert found == {PACKAGE: '(ros.ament_python)',
                     'positioning_cell_interfaces': '(ros.ament_cmake)'}, result.stdout
