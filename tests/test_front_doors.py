"""The files a newcomer opens first say what is true: LICENSE is the Apache-2.0 text every
package.xml names, CITATION.cff is valid Citation File Format 1.2.0 for this software and the
paper, CHANGELOG.md follows Keep a Changelog and names every artifact format the loader
reads, and each package's `__init__` says which modules it holds and declares its public
names (`__all__`), every one of which resolves."""
import ast
import hashlib
import importlib
import importlib.util
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

from test_pure_cores import pure_modules

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / 'src'
PACKAGE_DIRS = sorted(p.parent for p in SRC.glob('*/*/__init__.py'))
PACKAGE_XMLS = sorted(SRC.glob('*/package.xml'))

# sha256 of the Apache License 2.0's text from its title through "END OF TERMS AND
# CONDITIONS", whitespace collapsed: the same for the copies jax, aiohttp and
# scikit-build-core ship
APACHE_2_TERMS_SHA256 = '59d8f0ba87ad9a2f1a431123c8d16646e5b89ba53653e818f16d136d77263c99'

# Citation File Format 1.2.0 (schema.json): the keys a file must have, the keys a
# reference (preferred-citation) must have, and the reference types it allows
CFF_REQUIRED = {'cff-version', 'message', 'title', 'authors'}
CFF_REFERENCE_REQUIRED = {'type', 'title', 'authors'}
CFF_REFERENCE_TYPES = {
    'art', 'article', 'audiovisual', 'bill', 'blog', 'book', 'catalogue', 'conference',
    'conference-paper', 'data', 'database', 'dictionary', 'edited-work', 'encyclopedia',
    'film-broadcast', 'generic', 'government-document', 'grant', 'hearing', 'historical-work',
    'legal-case', 'legal-rule', 'magazine-article', 'manual', 'map', 'multimedia', 'music',
    'newspaper-article', 'pamphlet', 'patent', 'personal-communication', 'proceedings', 'quote',
    'report', 'serial', 'slides', 'software', 'software-code', 'software-container',
    'software-executable', 'software-virtual-machine', 'sound-recording', 'standard', 'statute',
    'thesis', 'unpublished', 'video', 'website'}
CFF_PERSON_KEYS = {'family-names', 'given-names', 'name-particle', 'name-suffix', 'alias'}

HISTORY_WORDS = re.compile(r'\b(rounds?|stops?|issues?) [0-9]+', re.IGNORECASE)


def package_field(tag: str) -> set[str]:
    """The values of `tag` over every package.xml."""
    return {ET.parse(p).getroot().findtext(tag) for p in PACKAGE_XMLS}


def check_authors(authors, where: str) -> None:
    assert isinstance(authors, list) and authors, f'{where}: authors must be a non-empty list'
    for author in authors:
        assert isinstance(author, dict), f'{where}: an author is a mapping, got {author!r}'
        assert 'name' in author or CFF_PERSON_KEYS & set(author), \
            f'{where}: an author needs a name (entity) or family-/given-names (person): {author}'


def test_license_is_the_apache_2_0_text_with_its_copyright_line_filled():
    assert package_field('license') == {'Apache-2.0'}
    text = (REPO / 'LICENSE').read_text()
    start, end = 'Apache License', 'END OF TERMS AND CONDITIONS'
    assert text.lstrip().startswith(start)
    terms = text[text.index(start):text.index(end) + len(end)]
    assert hashlib.sha256(' '.join(terms.split()).encode()).hexdigest() == APACHE_2_TERMS_SHA256
    assert re.search(r'^\s*Copyright (19|20)\d\d The lightstage authors$', text, re.MULTILINE)
    assert '[yyyy]' not in text and '[name of copyright owner]' not in text


def test_citation_cff_has_what_cff_1_2_0_requires_for_the_software_and_the_paper():
    cff = yaml.safe_load((REPO / 'CITATION.cff').read_text())
    assert isinstance(cff, dict)
    assert CFF_REQUIRED <= set(cff), f'missing {CFF_REQUIRED - set(cff)}'
    assert cff['cff-version'] == '1.2.0'
    assert cff['type'] == 'software' and cff['title'] == 'lightstage'
    assert isinstance(cff['message'], str) and cff['message'].strip()
    check_authors(cff['authors'], 'the software')
    paper = cff['preferred-citation']
    assert CFF_REFERENCE_REQUIRED <= set(paper), f'missing {CFF_REFERENCE_REQUIRED - set(paper)}'
    assert paper['type'] in CFF_REFERENCE_TYPES
    assert paper['title'] == 'Multiplexed Illumination for Classifying Visually Similar Objects'
    check_authors(paper['authors'], 'the paper')
    assert [a['family-names'] for a in paper['authors']] == ['Wang', 'Dansereau']


def test_citation_names_the_packages_version_and_license():
    cff = yaml.safe_load((REPO / 'CITATION.cff').read_text())
    assert {str(cff['version'])} == package_field('version')
    assert {cff['license']} == package_field('license')


def init_source(package_dir: Path) -> ast.Module:
    return ast.parse((package_dir / '__init__.py').read_text())


def declared_all(package_dir: Path) -> list[str]:
    """`__all__` as the package's __init__ assigns it (a literal list or tuple of names)."""
    for node in init_source(package_dir).body:
        if isinstance(node, ast.Assign) and any(getattr(t, 'id', None) == '__all__'
                                                for t in node.targets):
            return list(ast.literal_eval(node.value))
    raise AssertionError(f'{package_dir.name}/__init__.py declares no __all__')


def public_modules(package_dir: Path) -> list[str]:
    modules = [p.stem for p in package_dir.glob('*.py')]
    modules += [p.parent.name for p in package_dir.glob('*/__init__.py')]
    return sorted(m for m in modules if not m.startswith('_'))


@pytest.mark.parametrize('package_dir', PACKAGE_DIRS, ids=lambda p: p.name)
def test_a_package_docstring_names_every_module_it_holds(package_dir):
    doc = ast.get_docstring(init_source(package_dir))
    assert doc and doc.strip(), f'{package_dir.name}/__init__.py has no docstring'
    unnamed = [m for m in public_modules(package_dir) if not re.search(rf'\b{m}\b', doc)]
    assert not unnamed, f'{package_dir.name}/__init__.py does not say what {unnamed} are for'


@pytest.mark.parametrize('package_dir', PACKAGE_DIRS, ids=lambda p: p.name)
def test_every_name_in_a_package_all_resolves(package_dir):
    """A submodule by its spec (found in the installed package, not run: the nodes would load
    ROS and the learned trainer JAX), any other name as an attribute of the package."""
    names = declared_all(package_dir)
    assert names and len(names) == len(set(names)), f'{package_dir.name}.__all__: {names}'
    package = importlib.import_module(package_dir.name)
    modules = set(public_modules(package_dir))
    for name in names:
        if name in modules:
            spec = importlib.util.find_spec(f'{package_dir.name}.{name}')
            assert spec is not None and spec.origin, f'{package_dir.name}.{name} is not installed'
        else:
            assert hasattr(package, name), f'{package_dir.name}.__all__ names {name!r}, ' \
                                           'neither a module of it nor a name it binds'


def test_a_package_init_imports_only_its_core_modules():
    """Importing a package loads no node and no ROS module: whatever an __init__ imports is
    one of the modules tests/test_pure_cores.py imports without ROS."""
    cores = set(pure_modules())
    for package_dir in PACKAGE_DIRS:
        for node in ast.walk(init_source(package_dir)):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                assert node.level == 1, f'{package_dir.name}/__init__.py: only `from .module import`'
                names = [f'{package_dir.name}.{node.module}'] if node.module else \
                    [f'{package_dir.name}.{a.name}' for a in node.names]
            else:
                continue
            assert set(names) <= cores, f'{package_dir.name}/__init__.py imports {names}'


def changelog() -> str:
    return (REPO / 'CHANGELOG.md').read_text()


def releases(text: str) -> list[str]:
    return re.findall(r'^## (.*)$', text, re.MULTILINE)


def readable_artifact_versions() -> tuple[int, ...]:
    """`READABLE_VERSIONS` of mux_classifier/artifact_format.py, read from its source."""
    source = (SRC / 'mux_classifier' / 'mux_classifier' / 'artifact_format.py').read_text()
    for node in ast.parse(source).body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], 'id', '') == 'READABLE_VERSIONS':
            return tuple(ast.literal_eval(node.value))
    raise AssertionError('artifact_format.py defines no READABLE_VERSIONS')


def test_the_changelog_opens_with_an_unreleased_section_then_versioned_releases():
    text = changelog()
    headings = releases(text)
    assert headings[0] == '[Unreleased]'
    unreleased = text.split('## [Unreleased]', 1)[1].split('\n## ', 1)[0]
    assert re.findall(r'^### (\w+)', unreleased, re.MULTILINE)[:4] == \
        ['Added', 'Changed', 'Fixed', 'Security']
    versions = []
    for heading in headings[1:]:
        match = re.fullmatch(r'\[(\d+)\.(\d+)\.(\d+)\] - \d{4}-\d{2}-\d{2}', heading)
        assert match, f'release heading {heading!r} is not "[X.Y.Z] - YYYY-MM-DD"'
        versions.append(tuple(int(v) for v in match.groups()))
    assert versions == sorted(versions, reverse=True) and len(set(versions)) == len(versions)
    assert {'.'.join(map(str, versions[0]))} == package_field('version')


def test_the_changelog_says_what_each_readable_artifact_format_added():
    text = changelog()
    versions = readable_artifact_versions()
    assert versions == tuple(range(1, max(versions) + 1))
    missing = [v for v in versions if not re.search(rf'\*\*Artifact format {v}\*\*', text)]
    assert not missing, f'CHANGELOG.md does not say what artifact format(s) {missing} added'


def test_the_changelog_speaks_of_releases_not_of_work_in_progress():
    text = changelog()
    assert not HISTORY_WORDS.findall(text)
    assert not re.search(r'\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b', text), \
        'no commit hashes'
