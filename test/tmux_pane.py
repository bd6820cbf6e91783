"""A program in a tmux pane on a tmux server of its own (``tmux -L <socket>``), for tests and
benchmarks/live_view.py: started with a given environment, read back with ``capture-pane``
(``-e``: with the colour escapes), typed into with ``send-keys``, the server killed at the
end. The pane stays after the program exits (it prints its exit code)."""

from __future__ import annotations

import shlex
import subprocess
from collections.abc import Mapping
from pathlib import Path

#: Environment variables the program is given (the rest of the test's environment is not).
PASSED = ('ROS_', 'FASTRTPS_', 'RMW_', 'AMENT_', 'PYTHON', 'PATH', 'LD_', 'HOME', 'LANG',
          'LC_')


class TmuxPane:
    """``command`` (a shell line) in a 130 × 40 pane; ``<command>; echo "exited $?"``."""

    def __init__(self, socket: str, command: str, env: Mapping[str, str], log_dir: Path) -> None:
        self.socket = socket
        script = log_dir / f'{socket}.sh'
        exports = ''.join(f'export {k}={shlex.quote(v)}\n' for k, v in env.items()
                          if k.startswith(PASSED))
        # the pane's own size, not the test's: a COLUMNS or LINES exported where pytest runs
        # reaches the pane through the tmux server's environment, and rich draws to it
        # (COLUMNS=400: every row wrapped, no header within the pane)
        script.write_text(f'unset COLUMNS LINES\n{exports}{command}\necho "exited $?"\n'
                          'sleep 600\n')
        self._tmux('new-session', '-d', '-s', 'pane', '-x', '130', '-y', '40',
                   f'bash {shlex.quote(str(script))}')

    def _tmux(self, *args: str) -> str:
        return subprocess.run(['tmux', '-L', self.socket, *args], check=True,
                              capture_output=True, text=True, timeout=30).stdout

    def screen(self, escapes: bool = False) -> str:
        """What the pane shows now (``escapes``: with its colours as SGR sequences)."""
        return self._tmux('capture-pane', '-p', *(['-e'] if escapes else []), '-t', 'pane')

    def keys(self, keys: str) -> None:
        """Type ``keys`` into the pane."""
        self._tmux('send-keys', '-t', 'pane', keys)

    def program_pid(self) -> int:
        """The process id of ``command`` (the child of the pane's bash)."""
        shell = int(self._tmux('list-panes', '-t', 'pane', '-F', '#{pane_pid}').split()[0])
        return int(Path(f'/proc/{shell}/task/{shell}/children').read_text().split()[0])

    def close(self) -> None:
        """Kill the tmux server and the program in it."""
        subprocess.run(['tmux', '-L', self.socket, 'kill-server'], check=False,
                       capture_output=True, timeout=30)

    def __enter__(self) -> TmuxPane:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
