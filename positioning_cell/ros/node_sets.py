"""Several positioners in one ROS graph (issue 27, item 1): each positioner's node set (the
cell's nodes, names.CELL_NODES) under a namespace of its own, as ROS 2 runs several robots;
the coordinator (``cell_coordinator_node``) in the root namespace talks to each.

Every node of a set gets ``-r __ns:=/<ns>`` and a remap of every wire name the set uses
(names.SET_TOPICS, SET_SERVICES and each action of SET_ACTIONS through its endpoints) to
``/<ns><name>`` (:func:`remap_arguments`): the nodes keep their absolute names (names.py) and
the single positioner's cell is unchanged. Each set's parameters are the cell's parameter
files rewritten for it (:func:`set_parameter_files`): every node's section under its
namespaced name (a file's ``/**`` section applies as it is), the names that bind the set's
nodes to each other (the driver's commander, the positioner's sources, its coordinate-system
file) in the namespace, and every seed in the files (``seed`` or ``*_seed`` keys) moved on by
the set's index, so that each positioner is a machine of its own: its own geometric errors,
clearance, drives and noise. Plain Python; the processes: :mod:`positioning_cell.ros.processes`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from positioning_cell import names
from positioning_cell.config import load_parameter_file, merged
from positioning_cell.coordinated.cell_file import GRAVITY, CellFile
from positioning_cell.errors import ConfigError
from positioning_cell.frames.transforms import Transform
from positioning_cell.ros.processes import Processes


class _NoAliases(yaml.SafeDumper):
    """YAML without anchors and aliases: rcl's parameter-file parser refuses them."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def _dump(doc: Mapping[str, Any]) -> str:
    return yaml.dump(doc, Dumper=_NoAliases, sort_keys=False)


#: The wildcard section of a ROS parameter file: it applies to every node, in any namespace.
ALL_NODES = '/**'
#: Where each set's coordinate systems persist (under ROS_HOME, default ~/.ros): one file per
#: namespace, as the single cell's is ``positioning_cell/coordinate_systems.yaml``.
SYSTEMS_FILE = Path('positioning_cell') / 'sets' / '{namespace}' / 'coordinate_systems.yaml'


def check_namespace(namespace: str) -> str:
    """``namespace`` if it names a set (letters, digits, '_', not starting with a digit: a
    ROS name token); ConfigError otherwise."""
    if not namespace.isidentifier() or not namespace.isascii():
        raise ConfigError(f'namespace {namespace!r}: a node set is named by letters, digits '
                          "and '_', not starting with a digit")
    return namespace


def remap_arguments(namespace: str) -> list[str]:
    """The ROS arguments (after ``--ros-args``) that put a node of the cell in the set
    ``namespace``: its namespace and every name of names.SET_TOPICS, SET_SERVICES and the
    endpoints of SET_ACTIONS remapped to :func:`names.in_set`."""
    check_namespace(namespace)
    wire = [*names.SET_TOPICS, *names.SET_SERVICES,
            *(f'{action}/{part}' for action in names.SET_ACTIONS
              for part in names.ACTION_ENDPOINTS)]
    args = ['-r', f'__ns:=/{namespace}']
    for name in dict.fromkeys(wire):
        args += ['-r', f'{name}:={names.in_set(name, namespace)}']
    return args


def _shift_seeds(params: Any, by: int) -> Any:
    """``params`` (a node's nested parameters) with every ``seed`` / ``*_seed`` integer >= 0
    moved on by ``by`` (a negative seed means "none drawn": kept)."""
    if not isinstance(params, Mapping):
        return params
    out = {}
    for key, value in params.items():
        seed = str(key) == 'seed' or str(key).endswith('_seed')
        if seed and isinstance(value, int) and not isinstance(value, bool) and value >= 0:
            out[key] = value + by
        else:
            out[key] = _shift_seeds(value, by)
    return out


def bindings(namespace: str) -> dict[str, dict[str, Any]]:
    """The parameters that bind the set's nodes to each other, by node name: the driver obeys
    the set's positioner, the positioner takes the set's driver and tracker, and keeps its
    coordinate systems in a file of the set's own."""
    def node(name: str) -> str:
        return f'/{namespace}/{name}'

    home = Path(os.environ.get('ROS_HOME') or Path.home() / '.ros')
    return {
        names.NODE_DRIVER: {'command': {'commander': node(names.NODE_POSITIONER)}},
        names.NODE_POSITIONER: {
            'sources': {'leg_driver': node(names.NODE_DRIVER),
                        'tracker': node(names.NODE_MEASUREMENT)},
            'operator': {'coordinate_systems_file': str(
                home / str(SYSTEMS_FILE).format(namespace=namespace))},
        },
    }


def set_parameter_files(files: Sequence[Path], namespace: str, index: int, out_dir: Path,
                        overrides: Mapping[str, Mapping[str, Any]] | None = None) -> list[Path]:
    """The parameter files of set ``namespace`` (the ``index``-th of the cell, from 0): each
    of ``files`` rewritten (module docstring) into ``out_dir/<namespace>.<k>.yaml``, then the
    set's :func:`bindings` with ``overrides`` ({node name: nested parameters}, the same for
    every set) in ``out_dir/<namespace>.bindings.yaml`` (last: they win). ConfigError naming a
    file that is not a parameter file."""
    check_namespace(namespace)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for k, path in enumerate(files):
        doc = load_parameter_file(path)
        rewritten: dict[str, Any] = {}
        for node, section in doc.items():
            key = node if str(node).startswith('/') else f'/{namespace}/{node}'
            if str(node).startswith('/') and node != ALL_NODES:
                raise ConfigError(f'{path}: section {node!r}: a set rewrites node names; '
                                  f'give them without a namespace (or {ALL_NODES})')
            rewritten[key] = _shift_seeds(section, index)
        target = out_dir / f'{namespace}.{k}.yaml'
        target.write_text(_dump(rewritten))
        written.append(target)
    bound: dict[str, Any] = merged(overrides or {}, bindings(namespace))
    target = out_dir / f'{namespace}.bindings.yaml'
    target.write_text(_dump({f'/{namespace}/{node}': {'ros__parameters': params}
                             for node, params in bound.items()}))
    return [*written, target]


def start_coordinated(procs: Processes, cell: CellFile, files: Sequence[Path], out_dir: Path,
                      overrides: Mapping[str, Mapping[str, Any]] | None = None,
                      per_set: Mapping[str, Mapping[str, Mapping[str, Any]]] | None = None,
                      container: bool = True) -> None:
    """Start the coordinated cell ``cell`` in ``procs``: its node sets (:func:`start_sets`),
    then the coordinator and the panel (:func:`start_panel`)."""
    start_sets(procs, cell, files, out_dir, overrides, per_set, container)
    start_panel(procs, cell, files, overrides)


def start_sets(procs: Processes, cell: CellFile, files: Sequence[Path], out_dir: Path,
               overrides: Mapping[str, Mapping[str, Any]] | None = None,
               per_set: Mapping[str, Mapping[str, Mapping[str, Any]]] | None = None,
               container: bool = True) -> None:
    """Start one ``cell_container`` per positioner of ``cell`` in ``procs``, hosting
    names.SET_NODES under its namespace (label: the namespace; ``container`` false: each node
    a process of its own, label ``<namespace>.<node>``), with the parameter files ``files``
    rewritten for it, ``overrides`` (by node name, for every set) and ``per_set`` (by
    namespace, then node name: one set's own, e.g. a fault injected in one positioner). Each
    carries no payload of its own (:func:`carried`): without the panel (:func:`start_panel`),
    nothing."""
    for k, entry in enumerate(cell.positioners):
        own = merged(merged(carried(cell, k), overrides or {}),
                      (per_set or {}).get(entry.name, {}))
        params = set_parameter_files(files, entry.name, k, out_dir, own)
        if container:
            procs.start(names.CONTAINER, *remap_arguments(entry.name), params=params,
                        label=entry.name, extra_args=[n.name for n in names.SET_NODES])
            continue
        for node in names.SET_NODES:
            procs.start(node.executable, *remap_arguments(entry.name), params=params,
                        label=f'{entry.name}.{node.name}')


def start_panel(procs: Processes, cell: CellFile, files: Sequence[Path],
                overrides: Mapping[str, Mapping[str, Any]] | None = None) -> None:
    """Mount the panel on the running sets of ``cell``: start the ``cell_coordinator`` on the
    cell file and the ``panel_simulator`` (simulation truth: the panel's wrench on each
    platform, which each set's drives carry), with the parameter files ``files`` and their
    sections of ``overrides``."""
    for node in (names.COORDINATOR, names.PANEL_SIMULATOR):
        section = merged((overrides or {}).get(node.name, {}), {'cell_file': str(cell.path)})
        procs.start(node.executable, params=files, overrides={node.name: section})


def carried(cell: CellFile, index: int) -> dict[str, dict[str, Any]]:
    """What the ``index``-th positioner of ``cell`` carries, by node: no payload of its own
    (the panel's weight and internal forces reach its drives through the panel simulator:
    its load cells read nothing before the panel's first push) and gravity in its base frame
    (the cell frame's, z up, turned into its base)."""
    entry = cell.positioners[index]
    rotation = Transform.from_pq(entry.base_position, entry.base_quaternion).R
    gravity = [float(v) for v in rotation.T @ np.asarray(GRAVITY)]
    payload = {'payload': {'mass': 0.0, 'gravity': gravity}}
    out: dict[str, dict[str, Any]] = {node.name: payload for node in names.SET_NODES}
    out[names.NODE_DRIVER] = {**payload, 'panel_pushes': True}
    return out
