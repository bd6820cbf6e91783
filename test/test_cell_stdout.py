"""``cell``'s stdout holds its answer only: what the DDS library writes to the process's
standard output (Fast DDS logs its errors to ``std::cout``) goes to stderr, so a ``--json``
document still parses (positioning_cell.ros.early.answers_only_on_stdout)."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest
from cell_harness import executable, isolated_domain

from positioning_cell.config import config_path
from positioning_cell.ros.processes import cell_environment

pytestmark = pytest.mark.nodes


def test_a_dds_error_on_stdout_does_not_spoil_the_json_answer(tmp_path: Path) -> None:
    # The shipped profile with one bad value: Fast DDS logs "XMLPARSER Error" on its stdout
    # at the participant's creation (and goes on with its defaults).
    profile = tmp_path / 'bad_profile.xml'
    profile.write_text(config_path('fastdds_loopback.xml').read_text().replace(
        '>USER_DATA_ONLY<', '>NOT_A_SETTING<'))
    with isolated_domain() as domain:
        own_profile = dict(os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=str(profile))
        env = cell_environment(domain, own_profile)
        result = subprocess.run([executable('cell'), 'status', '--json', '--timeout', '1'],
                                capture_output=True, text=True, env=env, timeout=120,
                                check=False)
    assert 'XMLPARSER' in result.stderr, result.stderr  # the library did write its error
    doc = json.loads(result.stdout)  # and stdout is the answer alone
    assert doc['command'] == 'status' and doc['exit_name'] == 'not_there', doc
    assert result.returncode == doc['exit_code']
