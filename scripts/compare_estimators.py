#!/usr/bin/env python
"""Thin wrapper of ``fusion.estimators_cli`` (installed as a command: see its --help)."""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fusion.estimators_cli import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
