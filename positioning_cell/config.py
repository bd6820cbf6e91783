"""Shipped configuration: where ``config/`` is, and reading ROS 2 parameter files without ROS."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

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


def load_yaml_mapping(path: str | Path, what: str, expected: str) -> dict[str, Any]:
    """Parse a YAML file that must hold a mapping; ConfigError naming ``what`` (e.g.
    'parameter file') and the file for a missing file, invalid YAML, or another top level
    (``expected`` says what the mapping holds)."""
    try:
        text = Path(path).read_text()
    except OSError as err:
        raise ConfigError(f'cannot read {what} {path}: {err}') from err
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(f'{what} {path} is not valid YAML: {err}') from err
    if not isinstance(data, dict):
        raise ConfigError(f'{what} {path}: expected a mapping of {expected}, got '
                          f'{type(data).__name__}')
    return data


def load_parameter_file(path: str | Path) -> dict[str, Any]:
    """Parse a ROS 2 parameter file; ConfigError for a missing file or invalid YAML."""
    return load_yaml_mapping(path, 'parameter file', 'node names')


def node_parameters(data: Mapping[str, Any], node_name: str) -> dict[str, Any]:
    """Nested parameters a node named ``node_name`` receives: ``/**`` merged with its own
    section (``node_name``, ``/node_name`` or ``/**/node_name``), the node's section winning."""
    merged: dict[str, Any] = {}
    for key in ('/**', node_name, f'/{node_name}', f'/**/{node_name}'):
        section = data.get(key)
        if isinstance(section, Mapping):
            _deep_merge(merged, dict(section.get('ros__parameters', {}) or {}))
    return merged


def _deep_merge(into: dict[str, Any], new: Mapping[str, Any]) -> None:
    for key, value in new.items():
        if isinstance(value, Mapping) and isinstance(into.get(key), dict):
            _deep_merge(into[key], value)
        else:
            into[key] = dict(value) if isinstance(value, Mapping) else value


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
