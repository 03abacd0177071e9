"""The house as a checked contract: which folder of bogiemon may import which, read from the code.

    python tests/house.py            # `make test` runs it before pytest; exit 1 on a broken layer

The folders are mapped onto `bogiemon.<folder>` in pyproject.toml ([tool.setuptools.package-dir]),
which hides the import graph from tools that look for a `bogiemon/` directory; this reads the same
mapping, parses every module with `ast` (nothing is imported or run) and checks each import
against the rules in [tool.bogiemon.house]:

- `never`: a layer never imports another, not even inside a function;
- `lazily`: a layer imports another only inside a function (what a command needs when it runs),
  never when the module is imported;
- `only_from`: a layer is imported by the listed modules alone, and by them only lazily.

A target is a layer (`daemon`) or a part of one, dotted below the package (`daemon.delivery`: that
package and every module in it).

Imports under `if TYPE_CHECKING:` are for the type checker and never run: they are not counted.
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
    module: str  # the importing module, e.g. bogiemon.daemon.cli.main
    path: str  # its file, relative to the repository
    line: int
    target: str  # the imported module, e.g. bogiemon.lab.study
    lazy: bool  # inside a function: runs when called, not when the module is imported


@dataclass(frozen=True)
class Rule:
    kind: str  # "never", "lazily" or "only_from"
    layer: str  # never/lazily: the importing layer; only_from: the imported one
    targets: tuple[str, ...]  # never/lazily: the imported layers; only_from: the modules allowed
    why: str


def layer_of(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == PACKAGE else None


def modules(root: Path, package_dirs: Mapping[str, str]) -> Iterator[tuple[str, Path]]:
    """Every module of the mapped packages: (dotted name, file)."""
    by_folder = {(root / folder).resolve(): package for package, folder in package_dirs.items()}
    seen: set[Path] = set()
    for folder in sorted(by_folder):
        for path in sorted(folder.rglob("*.py")):
            if path in seen:
                continue
            seen.add(path)
            # The deepest mapped folder holding the file names its package.
            holder = max((f for f in by_folder if path.is_relative_to(f)), key=lambda f: len(f.parts))
            rest = path.relative_to(holder).with_suffix("").parts
            name = ".".join((by_folder[holder], *rest))
            yield name.removesuffix(".__init__"), path


def _type_checking_block(node: ast.AST) -> bool:
    test = getattr(node, "test", None)
    return isinstance(node, ast.If) and (
        (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
        or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")
    )


def imports_of(module: str, path: Path, root: Path) -> Iterator[Import]:
    """The project's imports in one module, each marked lazy when it sits inside a function."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    rel = str(path.relative_to(root))

    def visit(node: ast.AST, lazy: bool) -> Iterator[Import]:
        for child in ast.iter_child_nodes(node):
            if _type_checking_block(child):
                continue
            inner = lazy or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)
            if isinstance(child, ast.Import):
                for alias in child.names:
                    if alias.name.split(".")[0] == PACKAGE:
                        yield Import(module, rel, child.lineno, alias.name, lazy)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = module.split(".") if is_package else module.split(".")[:-1]
                    base = base[: len(base) - child.level + 1]
                    target = ".".join([*base, child.module] if child.module else base)
                else:
                    target = child.module or ""
                if target.split(".")[0] == PACKAGE:
                    yield Import(module, rel, child.lineno, target, lazy)
            yield from visit(child, inner)

    yield from visit(tree, False)


def load_rules(pyproject: Mapping[str, object]) -> list[Rule]:
    house = pyproject["tool"]["bogiemon"]["house"]  # type: ignore[index]
    rules = []
    for kind in ("never", "lazily", "only_from"):
        for entry in house.get(kind, []):
            rules.append(Rule(kind, entry["layer"], tuple(entry["targets"]), entry["why"]))
    return rules


def reaches(target_module: str, target: str) -> bool:
    """Whether an import of target_module reaches a rule's target: a layer, or a dotted part of one."""
    if "." not in target:
        return layer_of(target_module) == target
    prefix = f"{PACKAGE}.{target}"
    return target_module == prefix or target_module.startswith(prefix + ".")


def violations(found: list[Import], rules: list[Rule]) -> list[str]:
    # An only_from entry is the one way through a `never`: its modules may reach the layer lazily.
    gates = {(module, r.layer) for r in rules if r.kind == "only_from" for module in r.targets}
    out = []
    for imp in found:
        src, dst = layer_of(imp.module), layer_of(imp.target)
        if dst is None or src == dst:
            continue
        gated = imp.lazy and (imp.module, dst) in gates
        where = f"{imp.path}:{imp.line}: {imp.module} imports {imp.target}{' (inside a function)' if imp.lazy else ''}"
        for rule in rules:
            hit = next((t for t in rule.targets if reaches(imp.target, t)), None)
            if rule.kind == "never" and src == rule.layer and hit is not None and not gated:
                out.append(f"{where}: broken layer '{rule.layer} never imports {hit}': {rule.why}")
            elif rule.kind == "lazily" and src == rule.layer and hit is not None and not imp.lazy:
                out.append(f"{where}: broken layer '{rule.layer} imports {hit} only inside a function': {rule.why}")
            elif rule.kind == "only_from" and dst == rule.layer and (imp.module not in rule.targets or not imp.lazy):
                allowed = ", ".join(rule.targets)
                out.append(f"{where}: broken layer '{rule.layer} is imported only by {allowed}, inside a function': {rule.why}")
    return out


def check(root: Path | None = None) -> tuple[list[str], int]:
    """(every violation as one line, the number of modules read) for the repository at root."""
    root = root or ROOT
    pyproject = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))
    package_dirs = pyproject["tool"]["setuptools"]["package-dir"]
    found: list[Import] = []
    n_modules = 0
    for module, path in modules(root, package_dirs):
        n_modules += 1
        found += imports_of(module, path, root)
    return violations(found, load_rules(pyproject)), n_modules


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
