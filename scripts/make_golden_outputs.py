#!/usr/bin/env python3
"""Write tests/golden/golden_outputs.npz: the per-instant path's outputs on the golden takes.

    python scripts/make_golden_outputs.py

Run it only when a change is MEANT to change the outputs (a fix in association, tracks or fusion), and say
so in the commit; tests/golden/test_golden_outputs.py then pins the new outputs. The takes and the runners
are in tests/golden/golden_takes.py.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "golden"))

from golden_takes import write_golden


def main() -> int:
    path = write_golden()
    print(f"wrote {path} ({path.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
