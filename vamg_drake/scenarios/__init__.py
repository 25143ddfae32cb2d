"""Scenario files shipped with the package.

`DEMO_SCENARIO` is the README demo's default scenario: the static benchmark
suite's scene 3 (see the file's header).
"""

from pathlib import Path

#: The demo's default scenario file (README command 1, `scripts/demo.sh`).
DEMO_SCENARIO = Path(__file__).with_name("demo.yaml")
