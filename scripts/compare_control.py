#!/usr/bin/env python
"""Compare motion control under every attitude estimator (``controllers.compare.main``;
installed as ``spherebot-compare``). ``--help`` lists the options.

    .venv/bin/python scripts/compare_control.py --quick          # what `make demo` runs
    .venv/bin/python scripts/compare_control.py --full --backend ray --address auto
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from controllers.compare import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
