"""The relative links of the README and the docs pages reach a file, and their #anchors a heading.

The README summarises each topic and links to the section of docs/ that holds it; a heading
renamed or a section moved would leave such a link pointing nowhere, unnoticed.
"""

from __future__ import annotations

from pathlib import Path
import re

import pytest

from repo_root import REPO

PAGES = [REPO / 'README.md', *sorted((REPO / 'docs').glob('*.md')), REPO / 'DEVELOPERS.md']
FENCED = re.compile(r'^```.*?^```', flags=re.MULTILINE | re.DOTALL)
LINK = re.compile(r'\]\(([^)\s]+)\)')


def _prose(page: Path) -> str:
    """The page without its code blocks."""
    return FENCED.sub('', page.read_text(encoding='utf-8'))


def anchors(page: Path) -> set[str]:
    """GitHub's anchors of a page's headings.

    Lower case, punctuation but '-' and '_' dropped, spaces to '-'; '-1', '-2', ... after a
    repeated one.
    """
    seen: dict[str, int] = {}
    for heading in re.findall(r'^#{1,6} (.+)$', _prose(page), flags=re.MULTILINE):
        slug = re.sub(r'[^\w\- ]', '', heading.strip().lower()).replace(' ', '-')
        seen[slug] = seen.get(slug, 0) + 1
        if seen[slug] > 1:
            seen[f'{slug}-{seen[slug] - 1}'] = 1
    return set(seen)


def test_anchors_follow_github() -> None:
    page = REPO / 'README.md'
    assert {'what-make-demo-does', 'messages-face_tracking_msgs-in-msg_defs'} <= anchors(page)


@pytest.mark.parametrize('page', PAGES, ids=lambda page: page.name)
def test_relative_links_resolve(page: Path) -> None:
    broken = []
    for target in LINK.findall(re.sub(r'`[^`\n]*`', '', _prose(page))):
        if re.match(r'[a-z]+:', target):  # https:, mailto:
            continue
        path, _, anchor = target.partition('#')
        linked = (page.parent / path).resolve() if path else page
        if not linked.exists():
            broken.append(f'{target}: no such file')
        elif anchor and linked.suffix == '.md' and anchor not in anchors(linked):
            broken.append(f'{target}: no such heading')
    assert broken == []
