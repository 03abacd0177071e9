"""The configuration reference (docs/configuration.md), generated from the pydantic models: every
section and field with its type, default, allowed values and description (Field(description=...),
the one text config/bogiemon.toml's comments repeat). `bogiemon check-config --reference` prints it;
a test checks that the committed page is this text, so it cannot drift from the models."""

from __future__ import annotations

import enum
import math
import re
import types
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import annotated_types
from pydantic import BaseModel
from pydantic.fields import FieldInfo

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.daemon.config_sections import Section
from bogiemon.daemon.config_sources import SOURCE_KINDS

PAGE_PATH = "docs/configuration.md"

HEAD = """\
# Configuration reference

Every section and field of the configuration file, with its type, default, allowed values and
description. This page is generated from the pydantic models (`bogiemon/daemon/config*.py`) by
`bogiemon check-config --reference` (`make config-reference` writes it); a test checks that it
matches them, so edit the models' descriptions, not this page.

- Every field is optional: a field left out takes its default; a file passed with `--config` needs
  only the fields it changes. `config/bogiemon.toml` is the shipped default, with these descriptions
  as comments.
- Unknown fields are errors (with a suggestion for a typo); every bad field is reported at once with
  its path; no number may be infinite or NaN. `bogiemon check-config FILE` checks a file as `run`
  would and prints it resolved, defaults filled in, with the digest its events carry.
- Units are in the names: `_s` seconds, `_h` hours, `_hz` hertz, `_m` metres, `_mps2` m/s^2,
  `_kmh` km/h, `_bytes` bytes.
- What `check-config` accepts, `run` starts and a reload (`systemctl reload`, SIGHUP) applies;
  what it rejects, a reload rejects too, with the error in the journal and in `systemctl status`,
  and the running config stays. A recording whose rate `[processing]` cannot run is named the
  same way by `analyze`, `replay` and `calibrate`.
- `include` names files relative to the including file's folder; after `..` and symlinks are
  resolved they must lie in that folder or below it, unless the file sets
  `allow_absolute_includes = true`. An included file cannot include others or set that flag. Every
  config file must be a regular UTF-8 file of at most 1 MiB.
- Tables written by `bogiemon calibrate` (the `[decision.fused.<load>]`, `[decision.load_states.<load>]`
  and `[decision.load_discriminant]` tables, and the commissioned fields of `[health]`) belong in
  the calibration file that `include` names, not in a hand-written config.
- A credential or key file of `[mqtt]` (`username_file`, `password_file`, `tls_key_file`) that its
  group or others can read is a warning at every load, in the journal and as a `# warning:` line of
  `check-config`: `chmod 600` it, or hand it over with systemd's `LoadCredential=`.
"""


@dataclass(frozen=True)
class _Table:
    """One table of the page: a TOML section path, its model and the text above its fields."""

    path: str  # "geometry", "decision.fused.<load>", "" for the top level
    model: type[BaseModel]
    about: str
    title: str = ""  # the heading, when it is not the path's (a source kind's)


def reference_text() -> str:
    """The whole page, as Markdown."""
    tables = list(_tables())
    lines = [HEAD, "## Contents", ""]
    lines += [f"- [{_title(t)}](#{_slug(_title(t))})" for t in tables]
    for table in tables:
        lines += ["", f"## {_title(table)}", ""]
        if table.about:
            lines += [_prose(table.about), ""]
        lines += ["| field | type | default | allowed | description |", "|---|---|---|---|---|"]
        for name, info in table.model.model_fields.items():
            if table.model is BogiemonConfig and (name == "source" or _section_model(info.annotation) is not None):
                continue  # a section of its own below
            lines.append(_row(table, name, info))
    return "\n".join(lines) + "\n"


def _tables() -> Iterator[_Table]:
    """The top level, then each section in the model's order, each followed by its sub-tables."""
    yield _Table("", BogiemonConfig, "Fields outside any section, at the top of the file.")
    for name, info in BogiemonConfig.model_fields.items():
        if name == "source":
            yield from _source_tables()
            continue
        model = _section_model(info.annotation)
        if model is not None:
            yield from _section_tables(name, model)


def _section_tables(path: str, model: type[BaseModel]) -> Iterator[_Table]:
    yield _Table(path, model, _doc(model))
    for name, info in model.model_fields.items():
        nested = _nested(info.annotation)
        if nested is not None:
            keys, sub = nested
            yield from _section_tables(".".join([path, name, *keys]), sub)


def _source_tables() -> Iterator[_Table]:
    for kind, model in SOURCE_KINDS.items():
        about = _doc(model)
        if kind == "can":
            about += " The default kind: a [source] without `kind` is this one."
        yield _Table("source", model, about, title=f'`[source] kind = "{kind}"`')


# -- the types ------------------------------------------------------------------------------------


def _section_model(annotation: Any) -> type[BaseModel] | None:
    return annotation if isinstance(annotation, type) and issubclass(annotation, Section) else None


def _nested(annotation: Any) -> tuple[list[str], type[BaseModel]] | None:
    """For a field that holds tables: the keys of the path below it (<load>, <indicator>) and the
    model of each table; None for a field that holds a value."""
    model = _section_model(annotation)
    if model is not None:
        return [], model
    origin, args = get_origin(annotation), get_args(annotation)
    if origin in (Union, types.UnionType) and type(None) in args:
        inner = [a for a in args if a is not type(None)]
        return _nested(inner[0]) if len(inner) == 1 else None
    if origin is dict:
        below = _nested(args[1])
        if below is not None:
            return [f"<{_key_name(args[0])}>", *below[0]], below[1]
    return None


def _key_name(annotation: Any) -> str:
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return re.sub(r"(?<!^)(?=[A-Z])", "_", annotation.__name__).lower().removesuffix("_state")  # LoadState -> load
    return "indicator" if get_origin(annotation) is Literal else "key"


def _type_text(annotation: Any) -> str:
    origin, args = get_origin(annotation), get_args(annotation)
    if origin is Annotated:
        return _type_text(args[0])
    if origin in (Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        text = " or ".join(_type_text(a) for a in inner)
        return f"{text} (optional)" if type(None) in args else text
    if origin is list:
        return f"list of {_plural(_type_text(args[0]))}"
    if origin is dict:
        nested = _nested(annotation)
        if nested is not None:
            return "tables"
        return "table"
    if origin is Literal or (isinstance(annotation, type) and issubclass(annotation, enum.Enum)):
        return "string"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "table"
    names = {bool: "boolean", int: "integer", float: "float", str: "string", Path: "path"}
    return names.get(annotation, getattr(annotation, "__name__", str(annotation)))


def _plural(text: str) -> str:
    return {"list of floats": "lists of floats"}.get(text, text + "s")


def _choices(annotation: Any) -> list[str] | None:
    origin, args = get_origin(annotation), get_args(annotation)
    if origin is Literal:
        return [str(a) for a in args]
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return [str(member.value) for member in annotation]
    return None


def _allowed(annotation: Any, metadata: list[Any]) -> str:
    parts: list[str] = []
    choices = _choices(annotation)
    if choices is not None:
        quoted = [f'"{c}"' for c in choices]
        parts.append(quoted[0] if len(quoted) == 1 else "one of " + ", ".join(quoted))
    origin, args = get_origin(annotation), get_args(annotation)
    if origin is list:
        item = args[0]
        item_metadata: list[Any] = []
        if get_origin(item) is Annotated:
            item, *extra = get_args(item)
            for e in extra:
                item_metadata += list(e.metadata) if isinstance(e, FieldInfo) else [e]
        inner = _allowed(item, item_metadata)
        if inner:
            parts.append(f"each {inner}")
    for m in metadata:
        parts += _bound(m)
    return "; ".join(parts)


def _bound(m: Any) -> list[str]:
    if isinstance(m, annotated_types.Gt):
        return [f"> {_number(m.gt)}"]
    if isinstance(m, annotated_types.Ge):
        return [f">= {_number(m.ge)}"]
    if isinstance(m, annotated_types.Lt):
        return [f"< {_number(m.lt)}"]
    if isinstance(m, annotated_types.Le):
        return [f"<= {_number(m.le)}"]
    if isinstance(m, annotated_types.MinLen):
        return [f"at least {m.min_length} character{'s' if m.min_length != 1 else ''}"]
    if isinstance(m, annotated_types.MaxLen):
        return [f"at most {m.max_length} characters"]
    pattern = getattr(m, "pattern", None)
    if pattern is not None:
        return [f"matches `{pattern}`"]
    return []


def _number(value: Any) -> str:
    """A bound as a reader takes it in: 2^31 - 1 rather than 2147483647, 1e6 rather than 1e+06."""
    if isinstance(value, float):
        if value.is_integer() and abs(value) < 1e5:
            return str(int(value))
        exponent = round(math.log10(abs(value))) if value else 0
        return f"1e{exponent}" if value == 10.0**exponent else f"{value:g}"
    if value >= 1 << 20 and (value & (value - 1)) == 0:
        return f"2^{value.bit_length() - 1}"
    if value >= 1 << 20 and ((value + 1) & value) == 0:
        return f"2^{value.bit_length()} - 1"
    if value >= 100_000:
        return f"{value:_}".replace("_", " ")
    return str(value)


# -- the defaults ---------------------------------------------------------------------------------


def _default(info: FieldInfo) -> str:
    if info.is_required():
        return "required"
    value = info.get_default(call_default_factory=True)
    if _nested(info.annotation) is not None:
        return _tables_default(value)
    return "absent" if value is None else f"`{_toml(value)}`"


def _tables_default(value: Any) -> str:
    if value is None or value == {}:
        return "none"  # a table written by calibrate, or absent
    flat: list[str] = []

    def walk(keys: list[str], v: Any) -> None:
        if isinstance(v, BaseModel):
            values = ", ".join(f"{k} = {_toml(x)}" for k, x in v.model_dump(mode="json", exclude_none=True).items())
            flat.append(f"`{'.'.join(keys)}`: {values}")
        elif isinstance(v, dict):
            for k, x in v.items():
                walk([*keys, str(k.value if isinstance(k, enum.Enum) else k)], x)

    walk([], value)
    return "; ".join(flat)


def _toml(value: Any) -> str:
    if value is None:
        return "absent"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, enum.Enum):
        return _toml(value.value)
    if isinstance(value, (str, Path)):
        return f'"{value}"'
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return str(value)


# -- the text -------------------------------------------------------------------------------------


def _row(table: _Table, name: str, info: FieldInfo) -> str:
    nested = _nested(info.annotation)
    description = info.description or ""
    if nested is not None and _section_model(info.annotation) is None:
        below = ".".join([table.path, name, *nested[0]])
        description += f" See [{_title_of(below)}](#{_slug(_title_of(below))})."
    cells = [
        f"`{name}`",
        _type_text(info.annotation),
        _default(info),
        _cell(_allowed(info.annotation, list(info.metadata))),
        _cell(description),
    ]
    return "| " + " | ".join(cells) + " |"


def _title(table: _Table) -> str:
    return table.title or ("Top level" if not table.path else _title_of(table.path))


def _title_of(path: str) -> str:
    return f"`[{path}]`"


def _slug(title: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but '-' and '_' dropped, spaces to '-'."""
    return re.sub(r"[^\w\- ]", "", title.lower()).replace(" ", "-")


def _doc(model: type[BaseModel]) -> str:
    return " ".join((model.__doc__ or "").split())


def _prose(text: str) -> str:
    """Text for a paragraph: a '<' that could open an HTML tag, outside code spans, is escaped."""
    parts = text.split("`")
    return "`".join(p if i % 2 else re.sub(r"<(?=[A-Za-z/!?])", "&lt;", p) for i, p in enumerate(parts))


def _cell(text: str) -> str:
    """Text for a table cell: one line, '|' escaped (inside code spans too, as GitHub's tables need)."""
    return _prose(" ".join(text.split())).replace("|", "\\|")
