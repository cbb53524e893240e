"""Export the JSON Schema of every model to ``schemas/json/<Name>.json``.

Run ``python -m schemas.export`` after changing a model; a test fails while the files are stale.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from . import MODELS

JSON_DIR = Path(__file__).resolve().parent / "json"


def json_schema(name: str) -> dict[str, object]:
    """The JSON Schema of one model, with its wire identity recorded in ``$id`` and ``title``."""
    model = MODELS[name]
    schema = model.model_json_schema(mode="serialization")
    schema["$id"] = model.schema_id()
    schema["title"] = name
    return schema


def render(name: str) -> str:
    return json.dumps(json_schema(name), indent=2, sort_keys=True) + "\n"


def main(argv: list[str] | None = None) -> int:
    JSON_DIR.mkdir(exist_ok=True)
    for name in sorted(MODELS):
        (JSON_DIR / f"{name}.json").write_text(render(name))
    stale = {p.stem for p in JSON_DIR.glob("*.json")} - set(MODELS)
    for name in stale:
        (JSON_DIR / f"{name}.json").unlink()
    print(f"wrote {len(MODELS)} schemas to {JSON_DIR}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
