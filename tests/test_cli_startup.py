"""`siva --help` is fast because nothing heavy is imported for it (lazy imports)."""
from __future__ import annotations

import subprocess
import sys
import time

HEAVY = ("torch", "scipy", "fastapi", "matplotlib", "numba")


def test_help_imports_nothing_heavy():
    code = ("import sys, contextlib, io\n"
            "from siva_core.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try: main(['--help'])\n"
            "    except SystemExit: pass\n"
            f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n")
    t0 = time.perf_counter()
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    elapsed = time.perf_counter() - t0
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]", run.stdout
    print(f"siva --help in {elapsed:.2f} s")


def test_recording_import_does_not_load_torch():
    run = subprocess.run([sys.executable, "-c", "import sys; from siva_core import Recording; "
                          "print('torch' in sys.modules)"], capture_output=True, text=True,
                         timeout=60)
    assert run.stdout.strip() == "False", run.stderr
