"""Every doc reference resolves, and the front doors stay short.

- Relative links in README.md, CHANGELOG.rst, docs/, models/ and experiments/ point at files that
  exist, and their ``#anchor`` at a heading of that file.
- Repository paths named in backticks in the current docs (README.md, docs/, models/) exist.
  The changelog and experiments/ are history: they name code as it was, so only their links count.
- A citation of a doc section in the code (``docs/INTERFACES.md §3``, ``docs/X.md, "Heading"``,
  ``README, "Heading"``, ``model card, "Heading"``) names a heading that exists, and a doc or an
  experiment the code names exists.
- README.md <= 200 lines, models/MODEL_CARD.md <= 250, docs/ARCHITECTURE.md <= 150.
- No work-log or issue numbers (``session 12``, ``issue 15``) in the docs or the code.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CURRENT = [ROOT / 'README.md', *sorted((ROOT / 'docs').glob('*.md')),
           *sorted((ROOT / 'models').glob('*.md'))]
HISTORY = [*sorted((ROOT / 'experiments').rglob('*.md'))]
CODE = [p for d in ('landing_zone', 'msg_adapters') for p in sorted((ROOT / d).rglob('*.py'))]
CODE_OF_PACKAGES = list(CODE)
CODE += [p for d in ('scripts', 'config', 'launch') if (ROOT / d).is_dir()
         for p in sorted((ROOT / d).iterdir()) if p.suffix in ('.py', '.sh', '.xml', '.yaml')]
LIMITS = {'README.md': 200, 'models/MODEL_CARD.md': 250, 'docs/ARCHITECTURE.md': 150}
ROOTS = ('landing_zone', 'msg_adapters', 'docs', 'models', 'config', 'test', 'scripts',
         'experiments', 'launch', 'resource')
CITED = {'README': 'README.md', 'model card': 'models/MODEL_CARD.md'}


def rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def read(path: Path) -> str:
    return path.read_text(encoding='utf-8')


def without_code_blocks(text: str) -> str:
    return re.sub(r'^```.*?^```', '', text, flags=re.S | re.M)


def headings(path: Path) -> list[str]:
    text = without_code_blocks(read(path))
    return [m.group(1).strip() for m in re.finditer(r'^#{1,6} +(.+)$', text, re.M)]


def slug(heading: str) -> str:
    """GitHub's anchor for a heading."""
    text = re.sub(r'[^\w\- ]', '', heading.lower().replace('`', ''))
    return text.replace(' ', '-')


def links(path: Path) -> list[str]:
    text = without_code_blocks(read(path))
    if path.suffix == '.rst':
        return re.findall(r'`[^`<]*<([^>`]+)>`_', text)
    return re.findall(r'!?\[[^\]]*\]\(([^)\s]+)\)', text)


def link_problem(doc: Path, target: str) -> str | None:
    if re.match(r'[a-z]+:', target):
        return None                                    # http(s), mailto
    file, _, anchor = target.partition('#')
    dest = (doc.parent / file).resolve() if file else doc
    if not dest.exists():
        return f'{rel(doc)}: link to {target}, which does not exist'
    if anchor and dest.suffix == '.md':
        if anchor not in {slug(h) for h in headings(dest)}:
            return f'{rel(doc)}: link to {target}, which has no heading #{anchor}'
    return None


@pytest.mark.parametrize('doc', [ROOT / 'CHANGELOG.rst', *CURRENT, *HISTORY], ids=rel)
def test_links_resolve(doc):
    problems = [p for t in links(doc) if (p := link_problem(doc, t))]
    assert not problems, '\n'.join(problems)


@pytest.mark.parametrize('doc', CURRENT, ids=rel)
def test_backticked_paths_exist(doc):
    names = re.findall(r'`([^`\s]+)`', without_code_blocks(read(doc)))
    path = re.compile(rf'(?:{"|".join(ROOTS)})/[\w./-]*')
    paths = {n.rstrip('.,;:') for n in names if path.fullmatch(n)}
    missing = sorted(p for p in paths if not (ROOT / p).exists())
    assert not missing, f'{rel(doc)} names paths that do not exist: {missing}'


def flat(text: str) -> str:
    """Comment and docstring text joined across lines (line-leading '#' dropped)."""
    return ' '.join(re.sub(r'^\s*#+\s?', '', line).strip() for line in text.splitlines())


def has_heading(doc: Path, title: str) -> bool:
    want = ' '.join(title.lower().split()).rstrip('.')
    return any(h.lower().startswith(want) or want in h.lower() for h in headings(doc))


def has_section_number(doc: Path, number: str) -> bool:
    return any(re.match(rf'{number}\.\s', h) for h in headings(doc))


def citations(text: str) -> list[tuple[str, str]]:
    """(doc, section) pairs cited: section is '§N' or a quoted heading."""
    found = []
    quoted = r'(?:"([^"]{3,80})"|\'([^\']{3,80})\')'
    for m in re.finditer(rf'((?:docs|models)/\w+\.md)`*,?\s*(?:§\s*(\d+)|section (\d+)|{quoted})',
                         text):
        number = m.group(2) or m.group(3)
        found.append((m.group(1), f'§{number}' if number else m.group(4) or m.group(5)))
    for name, doc in CITED.items():
        for m in re.finditer(rf'\b{name},\s*{quoted}', text):
            found.append((doc, m.group(1) or m.group(2)))
    return found


@pytest.mark.parametrize('source', CODE, ids=rel)
def test_code_citations_resolve(source):
    text = flat(read(source))
    problems = []
    for doc, section in citations(text):
        path = ROOT / doc
        if not path.is_file():
            problems.append(f'{doc} does not exist')
        elif section.startswith('§'):
            if not has_section_number(path, section[1:]):
                problems.append(f'{doc} has no section {section}')
        elif not has_heading(path, section):
            problems.append(f'{doc} has no heading "{section}"')
    for name in set(re.findall(r'\b((?:docs|models)/\w+\.md|experiments/[\w-]+)', text)):
        if not (ROOT / name).exists():
            problems.append(f'{name} does not exist')
    assert not problems, f'{rel(source)}: ' + '; '.join(sorted(set(problems)))


@pytest.mark.parametrize('name, limit', sorted(LIMITS.items()))
def test_line_limits(name, limit):
    lines = len(read(ROOT / name).splitlines())
    assert lines <= limit, f'{name} has {lines} lines, the limit is {limit}'


@pytest.mark.parametrize('path', [*CURRENT, *CODE_OF_PACKAGES], ids=rel)
def test_no_work_log_or_issue_numbers(path):
    hits = [line.strip() for line in read(path).splitlines()
            if re.search(r'\b(?:session|issue)s?\s+\d+', line, re.I)]
    assert not hits, f'{rel(path)}: ' + ' | '.join(hits)
