"""Load a scenario script (``scenarios/<name>.py``) as a module, for tests, studies and notebooks."""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def scenario(name: str):
    """The module ``scenarios/<name>.py``, loaded once (the scenarios are scripts, not a package)."""
    key = f"hydrofrac_scenario_{name}"
    if key not in sys.modules:
        path = SCENARIOS / f"{name}.py"
        if not path.exists():
            raise ValueError(f"no scenario {name!r}: {path} does not exist; the scenarios are "
                             f"{sorted(p.stem for p in SCENARIOS.glob('*.py'))}")
        spec = importlib.util.spec_from_file_location(key, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        spec.loader.exec_module(module)
    return sys.modules[key]
