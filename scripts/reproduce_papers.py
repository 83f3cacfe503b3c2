#!/usr/bin/env python
"""Thin wrapper of ``benchmarks.papers_cli`` (installed as ``spherebot-papers``: see its --help)."""
import sys

from benchmarks.papers_cli import main

if __name__ == "__main__":
    sys.exit(main())
