"""The install pins what it takes from PyPI: every package pip put into the venv (not the
Debian ones it sees through --system-site-packages) is pinned, at the version installed, in
pyproject.toml or constraints.txt.  A package that pip adds later (a new dependency of
pyvista) fails this test until it is pinned."""
import re
import sys
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _norm(name):
    return re.sub(r"[-_.]+", "-", name).lower()


def _pins():
    text = (ROOT / "constraints.txt").read_text() + "\n" + (ROOT / "pyproject.toml").read_text()
    return {_norm(m.group(1)): m.group(2) for m in re.finditer(r"([A-Za-z0-9_.\-]+)==([A-Za-z0-9_.+\-]+)", text)}


def _venv_distributions():
    prefix = Path(sys.prefix).resolve()
    for dist in metadata.distributions():
        where = Path(str(dist.locate_file(""))).resolve()
        if prefix in where.parents or where == prefix:
            yield dist


@pytest.mark.skipif(sys.prefix == sys.base_prefix, reason="not run from the project's venv")
def test_every_package_pip_installed_is_pinned():
    pins = _pins()
    unpinned, wrong = [], []
    for dist in _venv_distributions():
        name = _norm(dist.metadata["Name"])
        if name in ("hydrofrac", "pip", "setuptools", "wheel"):
            continue
        if name not in pins:
            unpinned.append(f"{name}=={dist.version}")
        elif pins[name] != dist.version:
            wrong.append(f"{name}: installed {dist.version}, pinned {pins[name]}")
    assert not unpinned, f"pin these in constraints.txt: {unpinned}"
    assert not wrong, f"installed versions differ from the pins: {wrong}"
