#!/usr/bin/env python
"""Thin wrapper of ``controllers.train_cli`` (installed as ``spherebot-train``: see its --help)."""
import sys

from controllers.train_cli import main

if __name__ == "__main__":
    sys.exit(main())
