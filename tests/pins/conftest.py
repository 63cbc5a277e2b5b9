import sys
from pathlib import Path

# pin_data is importable by name (the suite runs with --import-mode=importlib, no packages under tests/);
# the fingerprints themselves are computed in a child process (pin_data.py, PINNED_ENV)
sys.path.insert(0, str(Path(__file__).parent))
