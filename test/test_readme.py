"""The README is the front page: short, its library example runs as printed (the public API it
shows is kept), and every link into the docs leads to a page that exists."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
README = REPO / 'README.md'


@pytest.mark.parametrize('page', [README, REPO / 'docs' / 'howto' / 'library.md'],
                         ids=['README', 'docs/howto/library.md'])
def test_the_library_example_runs(page: Path) -> None:
    """The first Python block of the README and of the docs' library page runs as shown."""
    blocks = re.findall(r'```python\n(.*?)```', page.read_text(), flags=re.S)
    assert blocks, f'no python example in {page.name}'
    namespace: dict[str, object] = {}
    exec(compile(blocks[0], str(page), 'exec'), namespace)
    pose, commands = namespace['pose'], namespace['commands']
    assert pose.converged.all()  # type: ignore[attr-defined]
    assert commands.lengths.shape == (1, 3)  # type: ignore[attr-defined]


def test_the_readme_is_a_front_page() -> None:
    """At most ~150 lines, with the two commands; the rest lives in docs/."""
    text = README.read_text()
    assert len(text.splitlines()) <= 150
    assert '`make run`' in text and '`make test`' in text


def test_every_link_of_the_readme_exists() -> None:
    links = re.findall(r'\]\(([^)#]+)(?:#[^)]*)?\)', README.read_text())
    assert any(link.startswith('docs/') for link in links)
    missing = [link for link in links if not (REPO / link).exists()]
    assert not missing, missing
