"""docs/ARCHITECTURE.md lists the real modules: every path it names exists, and every module
and package of landing_zone/ and msg_adapters/ is named in its list."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / 'docs' / 'ARCHITECTURE.md'


def listed() -> list[str]:
    text = DOC.read_text(encoding='utf-8')
    block = text.split('## Packages and modules', 1)[1].split('```', 2)[1]
    return [line.split()[0] for line in block.splitlines() if line.strip()
            and line.split()[0].startswith(('landing_zone/', 'msg_adapters/'))]


def test_every_listed_module_exists():
    paths = listed()
    assert len(paths) > 50
    missing = [p for p in paths if not (ROOT / p).exists()]
    assert not missing, f'docs/ARCHITECTURE.md lists what does not exist: {missing}'


def test_every_module_is_listed():
    paths = set(listed())
    actual = set()
    for pkg in ('landing_zone', 'msg_adapters'):
        for path in (ROOT / pkg).rglob('*.py'):
            rel = path.relative_to(ROOT)
            actual.add(f'{rel.parent}/' if path.name == '__init__.py' else str(rel))
    actual.discard('landing_zone/')
    actual.add('landing_zone/__init__.py')
    missing = sorted(actual - paths)
    assert not missing, f'docs/ARCHITECTURE.md does not list {missing}'


def test_the_modules_it_names_in_the_text_exist():
    text = DOC.read_text(encoding='utf-8')
    for name in sorted(set(re.findall(r'`((?:landing_zone|msg_adapters)/[\w/]+\.py)`', text))):
        assert (ROOT / name).is_file(), name
    for name in sorted(set(re.findall(r'\b((?:mapping|judging|frontends|io|sim|learn|bench)'
                                      r'/\w+\.py)', text))):
        assert (ROOT / 'landing_zone' / name).is_file(), name
