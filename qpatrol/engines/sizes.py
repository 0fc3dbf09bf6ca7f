"""Sizes of the compiled engine's tables, readable without importing numba (the
engine's choice, :func:`qpatrol.engines.compiled_gap`, needs them before any compile)."""

#: Most powers ``keep ** n`` the compiled ``evap`` keeps (32 MiB): its table runs to the
#: run's steps or to the first power that is 0.0 (n = 36,883 at the default evaporation
#: 0.02), see :mod:`qpatrol.engines.compiled.evap`.
EVAP_POWERS_MAX = 1 << 22
