import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(autouse=True)
def _runtime_dir(tmp_path_factory, monkeypatch):
    # Each test session gets its own registry and ipc directory, so tests never see a user's graphs.
    d = tmp_path_factory.getbasetemp() / "rt"
    d.mkdir(exist_ok=True)
    monkeypatch.setenv("DOCKHIL_RUNTIME_DIR", str(d))
    monkeypatch.chdir(ROOT)


def dockhil_cmd(*args):
    return [sys.executable, "-m", "dockhil.cli", *map(str, args)]


@pytest.fixture
def write_launch(tmp_path):
    def write(text: str, name: str = "scene.yaml") -> Path:
        p = tmp_path / name
        p.write_text(text)
        return p

    return write
