"""Shipped configuration: where ``config/`` is, and reading ROS 2 parameter files without ROS."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from positioning_cell import files
from positioning_cell.errors import ConfigError

PACKAGE = 'positioning_cell'


def share_directory() -> Path:
    """``share/positioning_cell`` of the install (ament index), else of the Python environment
    (``pip install .`` without ROS), else the source tree (editable installs and
    checkouts)."""
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )
    except ImportError:
        pass
    else:
        try:
            share = Path(get_package_share_directory(PACKAGE))
        except (PackageNotFoundError, LookupError, ValueError, KeyError, OSError):
            # OSError: AMENT_PREFIX_PATH unset (ament_index_python raises EnvironmentError).
            pass
        else:
            if (share / 'config').is_dir():
                return share
    # pip installs the data files under the environment's prefix (no ament index needed).
    installed = Path(sys.prefix) / 'share' / PACKAGE
    if (installed / 'config').is_dir():
        return installed
    return Path(__file__).resolve().parent.parent


def config_path(name: str = 'cell.yaml') -> Path:
    """Path of a shipped config file, e.g. ``cell.yaml``."""
    path = share_directory() / 'config' / name
    if not path.is_file():
        raise ConfigError(f'shipped config file {name!r} not found at {path}')
    return path


def load_yaml_mapping(path: str | Path, kind: files.FileKind, expected: str) -> dict[str, Any]:
    """The YAML mapping of the file ``path`` of ``kind`` (read and parsed by
    :func:`positioning_cell.files.load_yaml`: a regular file within the kind's size, bounded
    YAML); ConfigError naming the kind and the file for a missing or unreadable file, one that
    is not a regular file or too large, invalid or refused YAML, or another top level
    (``expected`` says what the mapping holds)."""
    data = files.load_yaml(path, kind)
    if not isinstance(data, dict):
        raise ConfigError(f'{files.describe(kind, path)}: expected a mapping of {expected}, got '
                          f'{type(data).__name__}')
    return data


def load_parameter_file(path: str | Path) -> dict[str, Any]:
    """Parse a ROS 2 parameter file (:func:`load_yaml_mapping`); ConfigError says why not."""
    return load_yaml_mapping(path, files.PARAMETER_FILE, 'node names')


def node_parameters(data: Mapping[str, Any], node_name: str) -> dict[str, Any]:
    """Nested parameters a node named ``node_name`` receives: ``/**`` merged with its own
    section (``node_name``, ``/node_name`` or ``/**/node_name``), the node's section winning."""
    params: dict[str, Any] = {}
    for key in ('/**', node_name, f'/{node_name}', f'/**/{node_name}'):
        section = data.get(key)
        if isinstance(section, Mapping):
            params = merged(params, section.get('ros__parameters', {}) or {})
    return params


def merged(base: Mapping[str, Any], more: Mapping[str, Any]) -> dict[str, Any]:
    """Nested parameters ``base`` with ``more`` laid over them, nested mappings merged key by
    key (neither is changed)."""
    out = dict(base)
    for key, value in more.items():
        old = out.get(key)
        out[key] = (merged(old, value) if isinstance(old, Mapping) and isinstance(value, Mapping)
                    else dict(value) if isinstance(value, Mapping) else value)
    return out


def flatten(params: Mapping[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested parameters as the dotted names rclpy uses (``mechanism.base_radius``)."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        name = f'{prefix}{key}'
        if isinstance(value, Mapping):
            out.update(flatten(value, name + '.'))
        else:
            out[name] = value
    return out
