"""MkDocs hook (mkdocs.yml, `hooks`): the checkout root on sys.path while the site builds.

training/ is not installed (it runs from the checkout as `python -m training`), so the
command-line reference of `python -m training` imports it from here, as pytest's
`pythonpath = ["."]` does for the tests.
"""

from __future__ import annotations

import sys
from pathlib import Path

CHECKOUT = Path(__file__).resolve().parents[1]


def on_startup(command: str, dirty: bool) -> None:
    """Put the checkout root first on sys.path, once, before any page is read."""
    if str(CHECKOUT) not in sys.path:
        sys.path.insert(0, str(CHECKOUT))
