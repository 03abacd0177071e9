"""The configuration's one text per field: the models' descriptions, repeated by the shipped file's
comments and by the generated reference page, neither of which may drift from them."""

import re
import subprocess
import sys
from pathlib import Path

import pytest
from pydantic import BaseModel

from bogiemon.daemon.config import BogiemonConfig, default_config_text
from bogiemon.daemon.config_reference import PAGE_PATH, reference_text
from bogiemon.daemon.config_sections import Section
from bogiemon.daemon.config_sources import SOURCE_KINDS

ROOT = Path(__file__).resolve().parents[2]
FIELD = re.compile(r"^(?P<indent>#   )?(?P<key>[a-z_0-9]+) = ")
TABLE = re.compile(r"^\[(?P<path>[a-z_.0-9]+)\]$")


def model_at(path: str, kind: str = "can") -> type[BaseModel]:
    """The model of a TOML table path ("", "health", "decision.thresholds.full.i4_norm", "source")."""
    model: type[BaseModel] = BogiemonConfig
    keys = [k for k in path.split(".") if k]
    while keys:
        key = keys.pop(0)
        if model is BogiemonConfig and key == "source":
            return SOURCE_KINDS[kind]
        annotation = model.model_fields[key].annotation
        while not (isinstance(annotation, type) and issubclass(annotation, Section)):
            args = [a for a in getattr(annotation, "__args__", ()) if a is not type(None)]
            if getattr(annotation, "__origin__", None) is dict:
                keys.pop(0)  # a load state, an indicator: the key of a table of tables
                annotation = args[1]
            else:
                (annotation,) = args
        model = annotation
    return model


def shipped_fields() -> list[tuple[str, str, str, str]]:
    """(table path, source kind, field, the comment right above it) of every field the shipped file
    sets or shows commented out (a source kind's fields); the comment's lines joined."""
    found = []
    path, kind = "", "can"
    lines = default_config_text().splitlines()
    for i, line in enumerate(lines):
        table = TABLE.match(line)
        if table:
            path, kind = table["path"], "can"
            continue
        field = FIELD.match(line)
        if field is None:
            continue
        prefix = "#   # " if field["indent"] else "# "
        if field["indent"] and field["key"] == "kind":
            kind = line.split('"')[1]  # a commented-out source kind: its fields follow
            continue
        comment: list[str] = []
        j = i - 1
        while j >= 0 and lines[j].startswith(prefix.rstrip()) and not FIELD.match(lines[j]) and lines[j].rstrip() != prefix.rstrip():
            comment.insert(0, lines[j][len(prefix):] if lines[j].startswith(prefix) else "")
            j -= 1
        found.append((path, kind, field["key"], " ".join(" ".join(comment).split())))
    return found


def test_the_comment_above_every_field_of_the_shipped_file_is_its_description_in_the_model() -> None:
    mismatches = []
    for path, kind, key, comment in shipped_fields():
        description = " ".join((model_at(path, kind).model_fields[key].description or "").split())
        if comment != description:
            mismatches.append(f"[{path}] {key} (kind {kind}):\n  file:  {comment}\n  model: {description}")
    assert mismatches == []


def test_the_shipped_file_shows_every_source_kinds_fields() -> None:
    # The other kinds' blocks name only their own fields: max_block_s and the backoffs are shown once, for "can".
    shared = set(SOURCE_KINDS["can"].model_fields) - {"kind", "interface", "channel", "layout", "dbc_path", "receive_buffer_bytes"}
    shown = {(kind, key) for path, kind, key, _ in shipped_fields() if path == "source"}
    expected = {(kind, key) for kind, model in SOURCE_KINDS.items() for key in model.model_fields
                if kind == "can" or key not in shared | {"kind"}}  # fmt: skip
    assert shared == {"max_block_s", "reconnect_backoff_min_s", "reconnect_backoff_max_s"}
    assert shown == expected


def test_every_field_of_every_section_has_a_description() -> None:
    page = reference_text()
    models = {model_at(path, kind) for path, kind, _, _ in shipped_fields()} | set(SOURCE_KINDS.values())
    models |= {model_at(p) for p in ("decision.fused.full", "decision.load_states.full", "decision.load_discriminant")}
    for model in models:
        assert model is BogiemonConfig or model.__doc__, f"{model.__name__} has no docstring, the text of its section"
        for name, info in model.model_fields.items():
            if model is BogiemonConfig and (name == "source" or isinstance(info.annotation, type) and issubclass(info.annotation, Section)):
                continue  # a section: its model's docstring says what it is
            assert info.description, f"{model.__name__}.{name} has no description"
            assert f"| `{name}` |" in page


@pytest.mark.parametrize("path", ["decision.fused.<load>", "decision.load_states.<load>", "decision.load_discriminant", "decision.thresholds.<load>.<indicator>"])
def test_the_reference_has_a_table_for_each_table_calibrate_writes(path: str) -> None:
    assert f"\n## `[{path}]`\n" in reference_text()


def test_the_committed_reference_page_is_the_one_the_models_generate() -> None:
    committed = (ROOT / PAGE_PATH).read_text(encoding="utf-8")
    assert committed == reference_text(), f"{PAGE_PATH} is stale: run `make config-reference`"


def test_check_config_reference_prints_the_page() -> None:
    proc = subprocess.run([sys.executable, "-m", "bogiemon", "check-config", "--reference"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == reference_text()
