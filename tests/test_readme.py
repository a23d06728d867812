"""The README's Python snippet runs as written from an empty folder (slow: a full SIVA fit)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_readme_python_snippet_runs_from_a_temp_dir(tmp_path):
    text = (ROOT / "README.md").read_text()
    code = re.search(r"## Python\n.*?```python\n(.*?)```", text, re.S)[1]
    expected = re.search(r"^# (\{.*\})$", code, re.M)[1]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, timeout=900, env=env)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.strip() == expected
