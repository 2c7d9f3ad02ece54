"""Build hook: vendor three.js from npm into motiongen/serve/static/vendor/ (see
motiongen/serve/vendor.py). Everything else is in pyproject.toml.

build_py runs for wheels and, with editable_mode set, for `pip install -e .` (PEP 660); sdist is
hooked too so that an sdist carries the vendored files (web/ is not in it) and a wheel built from
it needs no npm. Without npm the build goes on with a warning; `motiongen serve` then names the
missing files.
"""

import importlib.util
import sys
import warnings
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist

ROOT = Path(__file__).resolve().parent


def _load_vendor():
    # By file path: importing the motiongen package would need torch in the build environment.
    spec = importlib.util.spec_from_file_location(
        "_motiongen_vendor", ROOT / "motiongen" / "serve" / "vendor.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def vendor_three():
    vendor = _load_vendor()
    web = ROOT / "web"
    if not (web / "package.json").is_file():
        missing = vendor.missing_assets()
        if missing:  # e.g. a wheel from an sdist made without npm
            print(f"warning: no web/package.json and vendored scripts missing: {', '.join(missing)}",
                  file=sys.stderr)
        return
    try:
        copied = vendor.vendor_from_npm(web, vendor.vendor_dir())
    except (vendor.VendorError, OSError) as err:
        left = vendor.missing_assets()
        note = f"; `motiongen serve` lacks {', '.join(left)}" if left else " (older copy kept)"
        print(f"warning: could not vendor three.js: {err}{note}", file=sys.stderr)
        return
    print(f"vendored {len(copied)} three.js files into {vendor.vendor_dir()}", file=sys.stderr)


class BuildPyWithVendor(build_py):
    def run(self):
        vendor_three()  # before build_py collects package data
        # Folders vendored after package discovery are data (package-data "serve/static/**/*"),
        # not packages: silence setuptools' "absent from the `packages` configuration" for them.
        warnings.filterwarnings("ignore", message=r"Package 'motiongen\.serve\.static\b")
        super().run()


class SdistWithVendor(sdist):
    def run(self):
        vendor_three()
        super().run()


setup(cmdclass={"build_py": BuildPyWithVendor, "sdist": SdistWithVendor})
