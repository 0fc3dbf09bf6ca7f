"""Where qpatrol's shipped maps and configs are."""

from __future__ import annotations

from pathlib import Path

#: The package folder (``qpatrol/``) and the checkout above it, when run from one.
PACKAGE = Path(__file__).resolve().parents[1]
CHECKOUT = PACKAGE.parent


def shipped_dir(kind: str) -> Path:
    """The folder of shipped ``maps`` or ``configs``: the checkout's when qpatrol runs from
    one, else the copy installed with the package (``qpatrol/data/<kind>``)."""
    if (CHECKOUT / "pyproject.toml").is_file() and (CHECKOUT / kind).is_dir():
        return CHECKOUT / kind
    return PACKAGE / "data" / kind
