import sys
from pathlib import Path

# Make tests/scenes.py importable as `scenes`.
sys.path.insert(0, str(Path(__file__).parent))
