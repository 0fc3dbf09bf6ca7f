"""Reading qpatrol's CSV files back exactly.

qpatrol writes floats as the shortest text that reads back to the same float64
(:data:`qpatrol.measures.records.FLOAT_FORMAT`). pandas 3 reads such text exactly by default;
pandas 2's default parser may be off by one unit in the last place, so there the
round-trip parser is asked for.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

_EXACT: dict[str, Any] = (
    {"float_precision": "round_trip"} if int(pd.__version__.split(".")[0]) < 3 else {}
)


def read_csv(path: str | Path, **kwargs: Any) -> pd.DataFrame:
    """``pandas.read_csv`` with every float read back to the exact float64 written."""
    return pd.read_csv(path, **_EXACT, **kwargs)
