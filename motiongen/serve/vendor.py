"""The browser scripts `motiongen serve` needs, vendored from npm at build time.

The page (static/index.html) loads three.js through an import map:

    "three"         -> /static/vendor/three.module.js
    "three/addons/" -> /static/vendor/addons/

so static/vendor/ mirrors the npm package `three` (pinned in web/package.json and
web/package-lock.json) with `build/` flattened and `examples/jsm/` renamed `addons/`. Only the
entry points below and the files they import (followed through relative imports) are copied, plus
three.js's LICENSE. Nothing is committed and nothing is fetched from a CDN at run time: setup.py
calls vendor_from_npm() while building (wheel, sdist or `pip install -e .`), and the server calls
missing_assets() at start-up to name what is absent.

Standard library only: setup.py loads this file by path, in a build environment without torch.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

# Files the page imports directly, as paths inside static/vendor/.
ENTRY_POINTS = (
    "three.module.js",
    "addons/controls/OrbitControls.js",
    "addons/loaders/GLTFLoader.js",
)
LICENSE = "LICENSE"
PACKAGE = "three"

# `import ... from './x.js'`, `export ... from '../x.js'`, `import './x.js'`, `import('./x.js')`:
# only relative specifiers; bare ones ('three') resolve through the page's import map.
_RELATIVE_IMPORT = re.compile(
    r"""(?:\bfrom\s*|\bimport\s*\(?\s*)(['"])(\.{1,2}/[^'"\n]+)\1"""
)


class VendorError(RuntimeError):
    """npm is missing or failed, or the npm package lacks a file the page needs."""


def vendor_dir() -> Path:
    """Where the vendored scripts live (and are served from, as /static/vendor/)."""
    return Path(__file__).resolve().parent / "static" / "vendor"


def _npm_path(vendor_path: str) -> str:
    """static/vendor/ path -> path inside node_modules/three/."""
    if vendor_path == LICENSE:
        return LICENSE
    if vendor_path.startswith("addons/"):
        return "examples/jsm/" + vendor_path[len("addons/"):]
    return "build/" + vendor_path


def _relative_imports(text: str, importer: str) -> list[str]:
    """Vendor paths of the relative imports in `text`, a module at vendor path `importer`."""
    base = Path(importer).parent
    found = []
    for match in _RELATIVE_IMPORT.finditer(text):
        parts: list[str] = list(base.parts)
        for piece in match.group(2).split("/"):
            if piece == "..":
                if parts:
                    parts.pop()
            elif piece not in ("", "."):
                parts.append(piece)
        found.append("/".join(parts))
    return found


def _closure(read) -> tuple[list[str], list[str]]:
    """(present, missing) vendor paths: ENTRY_POINTS, what they import, and LICENSE.
    `read(vendor_path)` returns the file's text or None where it is absent."""
    present, missing, seen = [], [], set()
    todo = list(ENTRY_POINTS)
    while todo:
        path = todo.pop(0)
        if path in seen:
            continue
        seen.add(path)
        text = read(path)
        if text is None:
            missing.append(path)
            continue
        present.append(path)
        todo.extend(p for p in _relative_imports(text, path) if p not in seen)
    (present if read(LICENSE) is not None else missing).append(LICENSE)
    return present, missing


def _reader(root: Path, to_path=lambda p: p):
    def read(vendor_path: str):
        file = root / to_path(vendor_path)
        return file.read_text(encoding="utf-8") if file.is_file() else None
    return read


def missing_assets(dest: Path | None = None) -> list[str]:
    """Vendor paths (relative to static/vendor/) the page needs that are not there; [] when the
    page can run."""
    return _closure(_reader(Path(dest) if dest is not None else vendor_dir()))[1]


def _installed_version(web_dir: Path) -> str | None:
    manifest = web_dir / "node_modules" / PACKAGE / "package.json"
    try:
        return json.loads(manifest.read_text(encoding="utf-8"))["version"]
    except (OSError, ValueError, KeyError):
        return None


def _locked_version(web_dir: Path) -> str | None:
    try:
        lock = json.loads((web_dir / "package-lock.json").read_text(encoding="utf-8"))
        return lock["packages"]["node_modules/" + PACKAGE]["version"]
    except (OSError, ValueError, KeyError):
        return None


def npm_install(web_dir: Path) -> None:
    """`npm ci` in web_dir unless node_modules already holds the locked three.js version."""
    web_dir = Path(web_dir)
    locked = _locked_version(web_dir)
    if locked is not None and _installed_version(web_dir) == locked:
        return
    npm = shutil.which("npm")
    if npm is None:
        raise VendorError("npm not found (install Node.js + npm to vendor three.js)")
    command = [npm, "ci" if locked is not None else "install", "--no-audit", "--no-fund"]
    result = subprocess.run(command, cwd=web_dir, capture_output=True, text=True)
    if result.returncode != 0:
        tail = (result.stderr or result.stdout).strip().splitlines()[-5:]
        raise VendorError(f"{' '.join(command[1:])} failed in {web_dir}: " + " | ".join(tail))


def vendor_from_npm(web_dir: Path, dest: Path | None = None) -> list[str]:
    """Install web/'s npm dependencies and copy what the page needs into dest (default
    vendor_dir()), replacing what was there. Returns the vendor paths copied."""
    web_dir = Path(web_dir)
    dest = Path(dest) if dest is not None else vendor_dir()
    npm_install(web_dir)
    package = web_dir / "node_modules" / PACKAGE
    present, missing = _closure(_reader(package, _npm_path))
    if missing:
        raise VendorError(f"npm package {PACKAGE} lacks: "
                          + ", ".join(_npm_path(p) for p in missing))
    if dest.exists():
        shutil.rmtree(dest)
    for path in present:
        target = dest / path
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(package / _npm_path(path), target)
    (dest / "VERSION").write_text(f"{PACKAGE} {_installed_version(web_dir)}\n", encoding="utf-8")
    return present
