"""pytest setup of the Python tools' tests (`python3 -m pytest tools/tests`): tools/ on sys.path, so that its
packages import as such (`from reference.raypatch_reference import build_model`, `from data import make_golden`),
and this folder, for the reference tests' shared helpers (reference_helpers.py)."""

import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent
for folder in (TESTS, TESTS.parent):  # tools/ first
    if str(folder) not in sys.path:
        sys.path.insert(0, str(folder))
