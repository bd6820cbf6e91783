"""The Markdown of the generated reference pages (docs/_ext/generated.py's registry): the
parameters of every node from its settings type, the wire names from positioning_cell.names
and the QoS profiles from positioning_cell.ros.qos, with where the code uses them."""

from __future__ import annotations

import ast
import dataclasses
import json
import math
import typing
from collections import defaultdict
from functools import cache
from pathlib import Path
from typing import Any

import positioning_cell
from positioning_cell import names
from positioning_cell.parameters import Declaration, declarations

PACKAGE = Path(positioning_cell.__file__).resolve().parent


def _cell(text: str) -> str:
    """``text`` safe inside a Markdown table cell."""
    return text.replace('|', '\\|').replace('\n', ' ')


def _value(value: Any) -> str:
    """A parameter default as it would be written in a parameter file."""
    if value is None:
        return '(not set)'
    if isinstance(value, bool):
        return f'`{str(value).lower()}`'
    if isinstance(value, float) and not math.isfinite(value):
        return f'`{value}`'
    if isinstance(value, (list, tuple)):
        return f'`{_cell(json.dumps(list(value)))}`' if value else '`[]`'
    return f'`{_cell(repr(value) if isinstance(value, str) else str(value))}`'


def _rule(d: Declaration) -> str:
    parts = [d.constraints() or '']
    if not d.rule.finite:
        parts.append('+inf allowed')
    return _cell('; '.join(p for p in parts if p)) or '—'


def _table(decls: list[Declaration]) -> list[str]:
    rows = ['| parameter | type | default | unit, range, rule | set while running | description |',
            '| --- | --- | --- | --- | --- | --- |']
    rows += [f'| `{d.name}` | {d.kind.value} | {_value(d.default)} | {_rule(d)} | '
             f'{"dynamic" if d.rule.dynamic else "read-only"} | {_cell(d.rule.description)} |'
             for d in decls]
    return rows


def node_settings() -> dict[str, type]:
    """Node name -> its settings type (:data:`positioning_cell.node_settings.NODE_SETTINGS`,
    which the nodes declare), in the order of ``names.NODE_EXECUTABLES``."""
    from positioning_cell.node_settings import NODE_SETTINGS

    return dict(NODE_SETTINGS)


def _groups(cls: type) -> dict[str, type]:
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls)
            if dataclasses.is_dataclass(hints[f.name])}


def parameters() -> str:
    """Every node's parameters: the groups several nodes share once, then a table per node."""
    settings = node_settings()
    executables = {n.name: n.executable for n in names.NODE_EXECUTABLES}
    users: dict[tuple[str, type], list[str]] = defaultdict(list)
    for node, cls in settings.items():
        for field_name, group_type in _groups(cls).items():
            users[field_name, group_type].append(node)
    shared = {key: nodes for key, nodes in users.items() if len(nodes) > 1}
    shared_decls = {key: declarations(key[1], f'{key[0]}.') for key in shared}
    out = ['## Groups several nodes share', '',
           'Declared once on their library type; in `config/cell.yaml` under `/**:`. A node '
           'whose defaults differ lists those parameters in its own table.', '']
    for (field_name, group_type), nodes in sorted(shared.items(), key=lambda kv: kv[0][0]):
        out += [f'### `{field_name}.*`', '',
                f'{{py:class}}`~{group_type.__module__}.{group_type.__qualname__}`, read by '
                + ', '.join(f'`{n}`' for n in nodes) + '.', '',
                *_table(shared_decls[field_name, group_type]), '']
    for node, cls in settings.items():
        own = [d for d in declarations(cls)
               if not any(d in shared_decls[key] for key in shared_decls
                          if d.name.startswith(f'{key[0]}.') and node in shared[key])]
        groups = [f'`{key[0]}.*`' for key in sorted(shared, key=lambda k: k[0])
                  if node in shared[key]]
        out += [f'## `{node}` (`{executables[node]}`)', '',
                f'Settings type {{py:class}}`~{cls.__module__}.{cls.__qualname__}`'
                + (f'; also the shared groups {", ".join(groups)}' if groups else '') + '.', '',
                *_table(own), '']
    return '\n'.join(out)


# -- names.py and the QoS module, read as source ------------------------------------------------
def _documented_assignments(path: Path) -> list[tuple[str, str, str, str]]:
    """(section, NAME, value, doc) of every module-level string constant of ``path``: the
    section is the last ``# -- title ---`` comment above it, the doc its ``#:`` lines."""
    lines = path.read_text().splitlines()
    docs = _comments_above(path)
    out = []
    for node in ast.parse('\n'.join(lines)).body:
        if (isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name)
                and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)):
            above = [line for line in lines[:node.lineno - 1] if line.startswith('# --')]
            section = above[-1].strip('# -') if above else ''
            name = node.targets[0].id
            out.append((section, name, node.value.value, docs.get(name, '')))
    return out


def _comments_above(path: Path) -> dict[str, str]:
    """NAME -> its ``#:`` comment block, for every module-level assignment of ``path``."""
    source = path.read_text()
    lines = source.splitlines()
    out = {}
    for node in ast.parse(source).body:
        if isinstance(node, ast.Assign) and isinstance(node.targets[0], ast.Name):
            doc: list[str] = []
            i = node.lineno - 2
            while i >= 0 and lines[i].startswith('#:'):
                doc.insert(0, lines[i][2:].strip())
                i -= 1
            out[node.targets[0].id] = ' '.join(doc)
    return out


def _referenced(node: ast.AST) -> str | None:
    """The constant ``node`` names: ``names.X`` or ``qos.X`` or a bare ``X``."""
    if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name):
        return node.attr
    if isinstance(node, ast.Name):
        return node.id
    return None


@cache
def qos_uses() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """(profile -> modules that use it, wire name -> profiles it is used with), from every call
    of the package that is given a ``*_QOS`` profile (the wire name where it is a constant of
    positioning_cell.names in the same call). Read once per build (two pages use it)."""
    wire = {k for k, v in vars(names).items() if k.isupper() and isinstance(v, str)}
    modules: dict[str, set[str]] = defaultdict(set)
    with_name: dict[str, set[str]] = defaultdict(set)
    for path in sorted(PACKAGE.rglob('*.py')):
        if path.name == 'qos.py':
            continue
        rel = path.relative_to(PACKAGE).as_posix()
        tree = ast.parse(path.read_text())
        # A call inside a loop over a table of names (``for kind, name, cb in ((Trigger,
        # names.HOME, ...), ...)``) is given every name of that table.
        looped: dict[int, list[str]] = {}
        for loop in ast.walk(tree):
            if isinstance(loop, ast.For):
                table = [r for r in map(_referenced, ast.walk(loop.iter)) if r in wire]
                if not table:  # most loops: nothing to hand down (a walk of each was 1.4 s)
                    continue
                for inner in ast.walk(loop):
                    looped.setdefault(id(inner), []).extend(table)
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            args = [*node.args, *(k.value for k in node.keywords)]
            refs = [r for r in map(_referenced, args) if r] + looped.get(id(node), [])
            profiles = [r for r in refs if r.endswith('_QOS')]
            for profile in profiles:
                modules[profile].add(rel)
                for r in refs:
                    if r in wire:
                        with_name[r].add(profile)
    return modules, with_name


SECTIONS = {'topics': 'Topics', 'services (positioning_cell_interfaces unless named otherwise)':
            'Services', 'actions (positioning_cell_interfaces)': 'Actions'}


def wire_names() -> str:
    """The topics, services and actions of positioning_cell.names, each with its constant, its
    comment and the QoS profiles the code gives it."""
    _, with_name = qos_uses()
    rows: dict[str, list[str]] = defaultdict(list)
    for section, name, value, doc in _documented_assignments(PACKAGE / 'names.py'):
        title = SECTIONS.get(section)
        if title is None or not value.startswith('/'):
            continue
        profiles = ', '.join(f'`{p}`' for p in sorted(with_name.get(name, ()))) or '—'
        rows[title].append(f'| `{value}` | `names.{name}` | {profiles} | {_cell(doc) or "—"} |')
    out = []
    for title in SECTIONS.values():
        out += [f'## {title}', '', '| name | constant | QoS in the code | note |',
                '| --- | --- | --- | --- |', *rows[title], '']
    if not all(rows[t] for t in SECTIONS.values()):
        raise RuntimeError(f'names.py: a section is empty or renamed: {sorted(rows)}')
    return '\n'.join(out)


def qos_profiles() -> str:
    """Every QoS profile of positioning_cell.ros.qos: its policies, its comment, its users."""
    from positioning_cell.ros import qos

    modules, _ = qos_uses()
    docs = _comments_above(PACKAGE / 'ros' / 'qos.py')
    rows = ['| profile | reliability | durability | history | depth | why | used in |',
            '| --- | --- | --- | --- | --- | --- | --- |']
    for name, profile in vars(qos).items():
        if not name.endswith('_QOS'):
            continue
        used = ', '.join(f'`{m}`' for m in sorted(modules.get(name, ()))) or '—'
        rows.append(f'| `{name}` | {profile.reliability.name.lower()} | '
                    f'{profile.durability.name.lower()} | {profile.history.name.lower()} | '
                    f'{profile.depth} | {_cell(docs.get(name, ""))} | {used} |')
    return '\n'.join(rows)
