"""Check doc/architecture.md and its diagram's source (tools/architecture_diagram.py)."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _diagram():
    spec = importlib.util.spec_from_file_location(
        'architecture_diagram', ROOT / 'tools' / 'architecture_diagram.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_file_in_the_diagram_exists():
    diagram = _diagram()
    names = diagram.files()
    assert len(names) >= 15
    assert [f for f in names if not list(ROOT.glob(f.rstrip('/')))] == []
    for a, b, _ in diagram.ARROWS:
        assert a in diagram.BOXES and b in diagram.BOXES


def test_architecture_page_names_every_box_and_the_picture():
    text = (ROOT / 'doc' / 'architecture.md').read_text()
    diagram = _diagram()
    assert [t for (_, _, t, _) in diagram.BOXES.values() if t.split(' (')[0].lower()
            not in text.lower()] == []
    assert '(img/architecture.png)' in text and (ROOT / 'doc' / 'img' /
                                                   'architecture.png').is_file()


def test_the_diagram_draws(tmp_path):
    pytest.importorskip('matplotlib')
    out = _diagram().draw(tmp_path / 'a.png')
    assert out.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
