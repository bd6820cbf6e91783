"""The README's library example runs as printed (the public API it shows is kept)."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parent.parent / 'README.md'


def test_the_library_example_of_the_readme_runs() -> None:
    blocks = re.findall(r'```python\n(.*?)```', README.read_text(), flags=re.S)
    assert blocks, 'no python example in the README'
    namespace: dict[str, object] = {}
    exec(compile(blocks[0], str(README), 'exec'), namespace)
    pose, commands = namespace['pose'], namespace['commands']
    assert pose.converged.all()  # type: ignore[attr-defined]
    assert commands.lengths.shape == (1, 3)  # type: ignore[attr-defined]
