"""The house as a checked contract: which layer of bogiemon may import which, read from the code.

    python tests/house.py            # `make test` runs it before pytest; exit 1 on a broken layer

The layers are the folders of the package, bogiemon/<layer>/ (a module's layer is the second part
of its name). This parses every module with `ast` (nothing is imported or run) and checks each
import against [tool.bogiemon.house] in pyproject.toml:

- `layers`: the layers from the top down. A layer imports only layers below it; layers on one line
  (`"fleet | lab"`) are siblings and never import each other. A layer not listed is a breach.
- `never`: a layer never imports a part of a lower one (`daemon.delivery`: that package and every
  module in it), not even inside a function;
- `only`: of a lower layer, a layer imports only the parts listed (judgement reads drivers.base,
  the block and its status bits, and nothing else of the drivers);
- `lazily`: a layer imports another only inside a function (what one command or source needs when it
  runs), never when the module is imported: a rule of start-up time, not of direction.

And one rule with no exception: no cycle of imports between modules, the imports inside functions
and those for the type checker (`if TYPE_CHECKING:`) counted too. A cycle that only the type
checker or a function sees is still two modules that cannot be read one without the other.
"""

from __future__ import annotations

import ast
import sys
import tomllib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "bogiemon"


@dataclass(frozen=True)
class Import:
    module: str  # the importing module, e.g. bogiemon.cli.main
    path: str  # its file, relative to the repository
    line: int
    target: str  # the imported module, e.g. bogiemon.lab.study
    lazy: bool  # inside a function: runs when called, not when the module is imported
    typing_only: bool = False  # under `if TYPE_CHECKING:`: seen by the type checker alone


@dataclass(frozen=True)
class Rule:
    kind: str  # "never", "only" or "lazily"
    layer: str  # the importing layer
    targets: tuple[str, ...]  # never/lazily: the imported layers or parts; only: the parts allowed
    why: str
    of: str = ""  # only: the lower layer whose parts are listed


def layer_of(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == PACKAGE else None


def modules(root: Path) -> Iterator[tuple[str, Path]]:
    """Every module of the package: (dotted name, file)."""
    package = root / PACKAGE
    for path in sorted(package.rglob("*.py")):
        name = ".".join(path.relative_to(root).with_suffix("").parts)
        yield name.removesuffix(".__init__"), path


def _type_checking_block(node: ast.AST) -> bool:
    test = getattr(node, "test", None)
    return isinstance(node, ast.If) and (
        (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
        or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")
    )


def imports_of(module: str, path: Path, root: Path) -> Iterator[Import]:
    """The project's imports in one module, each marked lazy (inside a function) or typing-only."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    rel = str(path.relative_to(root))

    def visit(node: ast.AST, lazy: bool, typing_only: bool) -> Iterator[Import]:
        for child in ast.iter_child_nodes(node):
            inner = lazy or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)
            typed = typing_only or _type_checking_block(child)
            if isinstance(child, ast.Import):
                for alias in child.names:
                    if alias.name.split(".")[0] == PACKAGE:
                        yield Import(module, rel, child.lineno, alias.name, lazy, typing_only)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = module.split(".") if is_package else module.split(".")[:-1]
                    base = base[: len(base) - child.level + 1]
                    target = ".".join([*base, child.module] if child.module else base)
                else:
                    target = child.module or ""
                if target.split(".")[0] == PACKAGE:
                    # `from bogiemon.daemon import tomlout` imports the module bogiemon.daemon.tomlout
                    for alias in child.names:
                        sub = f"{target}.{alias.name}"
                        yield Import(module, rel, child.lineno, sub if sub in _KNOWN else target, lazy, typing_only)
            yield from visit(child, inner, typed)

    yield from visit(tree, False, False)


_KNOWN: set[str] = set()  # the package's module names, to tell `from package import module` apart


def parse_layers(lines: list[str]) -> dict[str, int]:
    """layer -> its level from the top (0); siblings share a level."""
    return {name.strip(): level for level, line in enumerate(lines) for name in line.split("|")}


def load_rules(pyproject: Mapping[str, object]) -> tuple[dict[str, int], list[Rule]]:
    house = pyproject["tool"]["bogiemon"]["house"]  # type: ignore[index]
    rules = []
    for kind in ("never", "only", "lazily"):
        for entry in house.get(kind, []):
            rules.append(Rule(kind, entry["layer"], tuple(entry["targets"]), entry["why"], entry.get("of", "")))
    return parse_layers(list(house["layers"])), rules


def reaches(target_module: str, target: str) -> bool:
    """Whether an import of target_module reaches a rule's target: a layer, or a dotted part of one."""
    if "." not in target:
        return layer_of(target_module) == target
    prefix = f"{PACKAGE}.{target}"
    return target_module == prefix or target_module.startswith(prefix + ".")


def violations(found: list[Import], layers: Mapping[str, int], rules: list[Rule]) -> list[str]:
    out = []
    for imp in found:
        src, dst = layer_of(imp.module), layer_of(imp.target)
        if dst is None or src is None or src == dst:
            continue
        where = f"{imp.path}:{imp.line}: {imp.module} imports {imp.target}{' (inside a function)' if imp.lazy else ''}"
        if src not in layers or dst not in layers:
            missing = src if src not in layers else dst
            out.append(f"{where}: the layer '{missing}' is not in [tool.bogiemon.house] layers")
            continue
        if imp.typing_only:
            continue  # a type's name only: the cycle check below is its rule
        if layers[src] == layers[dst]:
            out.append(f"{where}: broken layer '{src} and {dst} are siblings and never import each other'")
        elif layers[src] > layers[dst]:
            out.append(f"{where}: broken layer '{src} never imports {dst}, a layer above it'")
        for rule in rules:
            if rule.layer != src:
                continue
            hit = next((t for t in rule.targets if reaches(imp.target, t)), None)
            if rule.kind == "never" and hit is not None:
                out.append(f"{where}: broken layer '{rule.layer} never imports {hit}': {rule.why}")
            elif rule.kind == "lazily" and hit is not None and not imp.lazy:
                out.append(f"{where}: broken layer '{rule.layer} imports {hit} only inside a function': {rule.why}")
            elif rule.kind == "only" and dst == rule.of and hit is None:
                out.append(f"{where}: broken layer '{rule.layer} imports of {rule.of} only {', '.join(rule.targets)}': {rule.why}")
    return out


def cycles(found: list[Import]) -> list[list[str]]:
    """The cycles of imports (lazy and typing-only ones included): each strongly connected
    component of more than one module, sorted (Tarjan's algorithm)."""
    graph: dict[str, set[str]] = {}
    for imp in found:
        if imp.target in _KNOWN and imp.target != imp.module:
            graph.setdefault(imp.module, set()).add(imp.target)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in sorted(graph):
        if v not in index:
            connect(v)
    return sorted(out)


def check(root: Path | None = None) -> tuple[list[str], int]:
    """(every violation as one line, the number of modules read) for the repository at root."""
    root = root or ROOT
    pyproject = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))
    found_modules = list(modules(root))
    _KNOWN.clear()
    _KNOWN.update(name for name, _ in found_modules)
    found: list[Import] = []
    for module, path in found_modules:
        found += imports_of(module, path, root)
    layers, rules = load_rules(pyproject)
    problems = violations(found, layers, rules)
    by_module = {name: str(path.relative_to(root)) for name, path in found_modules}
    for component in cycles(found):
        problems.append(f"{by_module[component[0]]}: an import cycle (those inside functions and for TYPE_CHECKING counted): {' <-> '.join(component)}")
    return list(dict.fromkeys(problems)), len(found_modules)  # `from x import a, b`: one line, not two


def main() -> int:
    problems, n_modules = check()
    for line in problems:
        print(f"house: {line}", file=sys.stderr)
    if problems:
        print(f"house: {len(problems)} import(s) break the layers in pyproject.toml [tool.bogiemon.house]", file=sys.stderr)
        return 1
    print(f"house: {n_modules} modules keep the layers of pyproject.toml [tool.bogiemon.house]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
