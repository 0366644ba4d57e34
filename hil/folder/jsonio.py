"""The one JSON policy of every file the bench writes (docs/run-folder.md, "JSON"): numpy values
become plain numbers and lists, tuples lists, keys strings, a non-finite number ``null`` (JSON
has no NaN; every reader takes ``null`` as "not measured"); files are written whole or not at
all (a temporary file renamed over the old one), so a kill mid-write never leaves half a JSON.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from hil.errors import BadInputError


def jsonable(obj: Any) -> Any:
    """``obj`` as plain JSON values under the policy above."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [jsonable(v) for v in obj.tolist()]
    if isinstance(obj, np.bool_ | np.integer):
        return obj.item()
    if isinstance(obj, np.floating):
        obj = float(obj)
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def write_json(path: Path, obj: Any) -> Path:
    """Write ``obj`` to ``path`` atomically under the policy above."""
    tmp = path.with_name(path.name + ".writing")
    tmp.write_text(json.dumps(jsonable(obj), indent=2, allow_nan=False) + "\n")
    os.replace(tmp, path)
    return path


#: A JSON object read from a run folder's file, before the reader checks it into its record.
JsonObject = dict[str, Any]


def read_json_object(path: Path) -> JsonObject:
    """A JSON object from ``path``; BadInputError naming the file otherwise."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise BadInputError(f"{path}: not JSON ({exc})") from exc
    if not isinstance(data, dict):
        raise BadInputError(f"{path}: not a JSON object")
    return data
