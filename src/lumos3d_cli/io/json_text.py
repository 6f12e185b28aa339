"""JSON documents as strict JSON: JSON has no NaN or Infinity (Python's `json` writes them, and
strict readers such as jq or a browser's JSON.parse refuse the file), so a value that is not
finite (the PSNR of a view identical to its reference, the sharpness against a reference without
detail) is written as null, and said."""

from __future__ import annotations

import json
import logging
import math
from typing import Any

from lumos3d_cli.errors import listed

logger = logging.getLogger(__name__)


def _finite(value: Any, where: str, replaced: list[str]) -> Any:
    if type(value).__module__ == "numpy" and getattr(value, "ndim", None) == 0:
        value = value.item()  # a numpy scalar as the Python number it holds (not its str(), as `default` would)
    if isinstance(value, float) and not math.isfinite(value):
        replaced.append(f"{where} ({value})")
        return None
    if isinstance(value, dict):
        return {key: _finite(item, f"{where}.{key}" if where else str(key), replaced) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(item, f"{where}[{index}]", replaced) for index, item in enumerate(value)]
    return value


def finite_document(document: Any, name: str | None = None, written_as: str = "null") -> Any:
    """`document` with every non-finite float replaced by None; `name` (the file it goes to):
    a warning lists the values replaced, saying they are `written_as` (None: replaced without a
    word, for a copy of a document already written and warned about)."""
    replaced: list[str] = []
    cleaned = _finite(document, "", replaced)
    if replaced and name is not None:
        logger.warning("%s: %d value(s) are not finite, written as %s: %s", name, len(replaced), written_as,
                       listed(replaced, 4))
    return cleaned


def json_text(document: Any, name: str | None = None) -> str:
    """Strict JSON text of `document` (indented, one final newline): see `finite_document`."""
    return json.dumps(finite_document(document, name), indent=2, allow_nan=False, default=str) + "\n"
