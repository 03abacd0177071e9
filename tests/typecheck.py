"""The static type check: mypy over every package, the lab, the benchmarks and the tests.

    python tests/typecheck.py        # `make test` runs it after ruff, before the house; exit 1 on a finding

mypy finds a module by its path, and the folders are mapped onto `bogiemon.<folder>` by
setuptools (pyproject.toml, [tool.setuptools.package-dir]), a mapping mypy cannot read. So this
builds a tree of links from the same mapping, build/typecheck/bogiemon/<folder> -> <folder>
(`bogiemon` itself a namespace package, as installed), and mypy reads the package through it
([tool.mypy] mypy_path). Its findings are printed with the real paths (daemon/monitor.py, not
build/typecheck/bogiemon/daemon/monitor.py). The configuration is [tool.mypy] in pyproject.toml;
the incremental cache is .mypy_cache.
"""

from __future__ import annotations

import os
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGE = "bogiemon"
TREE = Path("build/typecheck")  # relative to ROOT; [tool.mypy] mypy_path names it
CHECKED = ("tests", "bench")  # beside the package; bench's scripts import each other bare (mypy_path)


def package_links(package_dirs: dict[str, str]) -> dict[Path, Path]:
    """The links the mapping needs: each mapped folder whose parent package does not already hold it.

    daemon/cli is reached through the daemon link; a subpackage mapped anywhere else gets its own.
    """
    links: dict[Path, Path] = {}
    for package, folder in sorted(package_dirs.items()):
        parent, _, leaf = package.rpartition(".")
        if parent in package_dirs and Path(package_dirs[parent]) / leaf == Path(folder):
            continue
        links[Path(*package.split("."))] = Path(folder)
    return links


def build_tree(root: Path, package_dirs: dict[str, str]) -> Path:
    """build/typecheck with one relative link per mapped folder, rebuilt to match the mapping."""
    tree = root / TREE
    for link, folder in package_links(package_dirs).items():
        at = tree / link
        at.parent.mkdir(parents=True, exist_ok=True)
        target = Path(os.path.relpath(root / folder, at.parent))
        if at.is_symlink() and Path(os.readlink(at)) == target:
            continue
        if at.is_symlink():
            at.unlink()
        at.symlink_to(target, target_is_directory=True)
    return tree


def real_paths(text: str, root: Path, package_dirs: dict[str, str]) -> str:
    """mypy's report with each path through the tree written as the repository's own."""
    for link, folder in sorted(package_links(package_dirs).items(), key=lambda item: -len(item[0].parts)):
        text = text.replace(f"{TREE / link}{os.sep}", f"{folder}{os.sep}")
    return text


def main() -> int:
    from mypy import api  # the test extra's

    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    package_dirs: dict[str, str] = pyproject["tool"]["setuptools"]["package-dir"]
    os.chdir(ROOT)  # mypy_path and the paths below are relative to the repository
    tree = build_tree(ROOT, package_dirs)
    out, err, status = api.run([str(tree / PACKAGE), *CHECKED, *sys.argv[1:]])
    sys.stdout.write(real_paths(out, ROOT, package_dirs))
    sys.stderr.write(real_paths(err, ROOT, package_dirs))
    return status


if __name__ == "__main__":
    sys.exit(main())
