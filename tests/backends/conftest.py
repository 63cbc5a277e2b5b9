"""Lets the backend tests import the shared contract (backend_contract.py) whatever pytest's import mode."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
