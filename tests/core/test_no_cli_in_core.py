"""core is the science library: importing any of its modules loads neither typer nor rich."""

from __future__ import annotations

import pkgutil
import subprocess
import sys

import core


def test_no_core_module_imports_the_command_line_packages():
    names = sorted(m.name for m in pkgutil.walk_packages(core.__path__, "core."))
    assert "core.pipeline" in names and "core.options" in names  # the walk found core's modules
    code = ("import importlib, sys\n"
            f"for name in {names!r}: importlib.import_module(name)\n"
            "print(' '.join(sorted({m.split('.')[0] for m in sys.modules})))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            check=True).stdout.split()
    assert "core" in loaded
    assert not {"typer", "rich", "click", "cli"} & set(loaded)
