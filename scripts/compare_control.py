#!/usr/bin/env python
"""Compare motion control under every attitude estimator (``controllers.compare.main``;
installed as ``spherebot-compare``). ``--help`` lists the options.

    .venv/bin/python scripts/compare_control.py --quick          # what `make demo` runs
    .venv/bin/python scripts/compare_control.py --full --backend ray --address auto
"""
import sys

from controllers.compare import main

if __name__ == "__main__":
    sys.exit(main())
