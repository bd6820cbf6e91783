"""The docs (docs/, Sphinx + MyST) build without a warning, their generated reference pages
come from the code through the one registry, and the library example they show runs."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
DOCS = REPO / 'docs'
sys.path.insert(0, str(DOCS / '_ext'))

import generated  # noqa: E402  (docs/_ext: the registry of generated pages)


@pytest.mark.slow
def test_the_docs_build_without_warnings(tmp_path: Path) -> None:
    """Every page, the generated reference and the API from the docstrings; any warning fails.
    The dummy builder reads and resolves everything (where the warnings come from) but writes
    no HTML: `make docs` writes it. In one process: the parallel tier is bound by its CPU
    (three workers on two cores), and ``-j auto``'s second reader only adds to it (alone on the
    VM: 42.5 s of CPU against 36.2 s serially, 31 s of wall time against 37 s)."""
    result = subprocess.run(
        [sys.executable, '-m', 'sphinx', '-W', '--keep-going', '-q', '-E',
         '-b', 'dummy',
         '-d', str(tmp_path / 'doctrees'), str(DOCS), str(tmp_path / 'out')],
        capture_output=True, text=True, check=False, timeout=600)
    assert result.returncode == 0, result.stdout[-5000:] + result.stderr[-5000:]


def test_every_generated_page_is_included_and_its_source_exists() -> None:
    """Each registry entry names a callable that returns Markdown, and a page includes it."""
    sources = '\n'.join(p.read_text() for p in DOCS.rglob('*.md')
                        if 'generated' not in p.relative_to(DOCS).parts)
    for page, source in generated.PAGES.items():
        module, _, name = source.partition(':')
        assert callable(getattr(importlib.import_module(module), name)), source
        fragment = Path(page).relative_to('reference')
        assert f'{{include}} {fragment.as_posix()}' in sources, f'{page}: included by no page'


def test_the_generated_pages_hold_the_code_tables() -> None:
    """The pages say what the code says: the fault matrix and exit codes as their modules
    print them, every wire name and every node's parameters."""
    from positioning_cell import names
    from positioning_cell.parameters import declarations
    from positioning_cell.procedures import fault_trials
    from positioning_cell.tools import exits

    assert fault_trials.markdown_table().strip() in generated.render(
        'reference/generated/fault_matrix.md')
    assert exits.markdown_table() in generated.render('reference/generated/exit_codes.md')
    wire = generated.render('reference/generated/names.md')
    for name in (names.JOINT_TRAJECTORY, names.MOVE_TO_POSE, names.CALIBRATE_ACTION):
        assert f'`{name}`' in wire
    parameters = generated.render('reference/generated/parameters.md')
    import reference_tables
    for node, cls in reference_tables.node_settings().items():
        assert f'## `{node}`' in parameters
        for d in declarations(cls):
            assert f'`{d.name}`' in parameters, f'{node}: {d.name} missing'
