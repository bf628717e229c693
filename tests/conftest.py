import shutil
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(autouse=True)
def _runtime_dir(monkeypatch):
    # Each test gets its own registry and ipc directory: no test sees a user's graphs or another
    # test's. Short, under /tmp, because ipc socket paths are limited to about 100 characters.
    d = tempfile.mkdtemp(prefix="dh-", dir="/tmp")
    monkeypatch.setenv("DOCKHIL_RUNTIME_DIR", d)
    monkeypatch.chdir(ROOT)
    yield
    shutil.rmtree(d, ignore_errors=True)


def dockhil_cmd(*args):
    return [sys.executable, "-m", "dockhil.cli", *map(str, args)]


@pytest.fixture
def write_launch(tmp_path):
    def write(text: str, name: str = "scene.yaml") -> Path:
        p = tmp_path / name
        p.write_text(text)
        return p

    return write
