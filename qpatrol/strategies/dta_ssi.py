"""``dta-ssi``: see :mod:`qpatrol.strategies.dta`."""

from __future__ import annotations

from qpatrol.strategies.dta import SSI as Strategy

__all__ = ["Strategy"]
