"""``dta-ssi-part``: see :mod:`qpatrol.strategies.dta`."""

from __future__ import annotations

from qpatrol.strategies.dta import PartSSI as Strategy

__all__ = ["Strategy"]
