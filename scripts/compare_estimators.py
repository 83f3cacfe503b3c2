#!/usr/bin/env python
"""Thin wrapper of ``benchmarks.estimators_cli`` (installed as ``spherebot-estimators``: see its --help)."""
import sys

from benchmarks.estimators_cli import main

if __name__ == "__main__":
    sys.exit(main())
