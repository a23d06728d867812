"""Package layering: the public API is what everyone outside siva_core uses, the library
does not import the service, and the ``siva`` program starts without the heavy stack."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import siva_core

ROOT = Path(__file__).resolve().parents[1]
OUTSIDE = ("examples", "benchmarks", "service", "clients", "siva_cli", "tests")

#: tests of private behaviour that may import siva_core._impl: {file: {module: why}}
PRIVATE_ALLOWED: dict[str, dict[str, str]] = {
    "tests/test_simulate.py": {"siva_core._impl.simulate": "the numba kernel cache"},
    "tests/test_refine.py": {"siva_core._impl.output_error": "monkeypatches the module's simulate"},
    "tests/test_training.py": {"siva_core._impl.networks": "the networks' internals"},
    "tests/test_recording.py": {"siva_core._impl.mcap_recording": "the MCAP topic constant"},
    "tests/test_report.py": {"siva_core._impl.report.simulations": "the report's record helpers",
                             "siva_core._impl.report.training_figures": "one figure's axes",
                             "siva_core._impl.report.page": "the page's text"},
    "tests/test_uncertainty.py": {"siva_core._impl.bootstrap": "the bootstrap's internals",
                                  "siva_core._impl.validation": "the noise estimator"},
    "tests/test_identify_holdout.py": {"siva_core._impl.commands": "the hold-out rule"},
    "tests/test_diagnose.py": {"siva_core._impl.diagnose": "the diagnosis' steps",
                               "siva_core._impl.effects": "effect amplitudes"},
    "tests/test_diagnose_parts.py": {"siva_core._impl.diagnose": "the diagnosis' parts",
                                     "siva_core._impl.effects": "effect amplitudes"},
    "tests/test_diagnose_elimination.py": {"siva_core._impl.diagnose": "the backward step"},
    "tests/test_diagnose_sets.py": {"siva_core._impl.diagnose": "sets of effects"},
    "tests/test_chain_cache.py": {"siva_core._impl.chain_cache": "clearing the memo"},
    "tests/test_optim.py": {"siva_core._impl.optim": "FastAdam vs torch's Adam, bit for bit",
                            "siva_core._impl.networks": "the networks FastAdam trains"},
    "tests/test_physical_bounds.py": {
        "siva_core._impl.assessment": "the verdict on a stub result",
        "siva_core._impl.ensemble": "dropping a diverged epoch",
        "siva_core._impl.siva": "moving candidates inside the bounds"},
    "tests/test_diagnose_report_text.py": {
        "siva_core._impl.diagnose.report": "the report's sentences",
        "siva_core._impl.diagnose.signatures": "the damping reading",
        "siva_core._impl.diagnose.where": "the amplitude trend"},
}


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute module) of every import in a file (relative ones resolved)."""
    tree = ast.parse(path.read_text(), str(path))
    package = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[:len(parts) - node.level + 1]
                base = ".".join(p for p in [*parts, base] if p)
            out.append((node.lineno, base))
            out += [(node.lineno, f"{base}.{a.name}") for a in node.names]
    return out


def _python_files(*folders: str) -> list[Path]:
    return sorted(p for f in folders for p in (ROOT / f).rglob("*.py"))


def test_nothing_outside_siva_core_imports_impl() -> None:
    bad = []
    for path in _python_files(*OUTSIDE):
        rel = path.relative_to(ROOT).as_posix()
        allowed = PRIVATE_ALLOWED.get(rel, {})
        by_line: dict[int, list[str]] = {}
        for line, module in _imports(path):
            by_line.setdefault(line, []).append(module)
        for line, modules in by_line.items():
            private = [m for m in modules
                       if m == "siva_core._impl" or m.startswith("siva_core._impl.")]
            ok = any(m == a or m.startswith(a + ".") for m in private for a in allowed)
            if private and not ok:
                bad.append(f"{rel}:{line}: {max(private, key=len)}")
    assert not bad, ("import the public name from siva_core instead (add it to "
                     "siva_core/__init__.py if missing):\n" + "\n".join(sorted(set(bad))))


def test_the_allow_list_is_not_stale() -> None:
    """Every allowed private import is still used (a fixed test leaves the list)."""
    for rel, modules in PRIVATE_ALLOWED.items():
        used = {m for _, m in _imports(ROOT / rel)}
        for module in modules:
            assert module in used, f"{rel} no longer imports {module}: drop it from the list"


@pytest.mark.parametrize("forbidden", ["service", "siva_cli", "clients"])
def test_the_library_does_not_import_the_service(forbidden: str) -> None:
    bad = [f"{p.relative_to(ROOT)}:{line}: {m}" for p in _python_files("siva_core")
           for line, m in _imports(p) if m == forbidden or m.startswith(forbidden + ".")]
    assert not bad, "siva_core must not depend on " + forbidden + ":\n" + "\n".join(bad)


def test_public_api_resolves() -> None:
    for name in siva_core.__all__:
        assert getattr(siva_core, name) is not None, name
    with pytest.raises(AttributeError, match="no_such_name"):
        getattr(siva_core, "no_such_name")
    assert {"simulate", "refine", "output_error", "displacement_mse", "diagnose",
            "register_effect", "recommend_best", "Siva", "Processing"} <= set(siva_core.__all__)


def test_static_imports_match_the_lazy_table() -> None:
    """The ``if TYPE_CHECKING`` imports (what IDEs and type checkers see) list exactly the
    names the lazy table exports, from the same modules."""
    tree = ast.parse((ROOT / "siva_core" / "__init__.py").read_text())
    block = next(n for n in tree.body if isinstance(n, ast.If)
                 and isinstance(n.test, ast.Name) and n.test.id == "TYPE_CHECKING")
    static = {(a.asname or a.name): (node.module.removeprefix("_impl."), a.name)
              for node in block.body if isinstance(node, ast.ImportFrom) for a in node.names}
    assert static == siva_core._EXPORTS


def test_siva_help_loads_neither_torch_nor_the_service_stack() -> None:
    """``siva --help`` must stay fast: the program imports no numerics and no web stack."""
    code = ("import sys, contextlib, io\n"
            "import siva_cli\n"
            "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
            "    try:\n"
            "        siva_cli.main(['--help'])\n"
            "    except SystemExit:\n"
            "        pass\n"
            "assert all(c in out.getvalue() for c in ('identify', 'diagnose', 'serve', 'replay'))\n"
            "heavy = [m for m in ('torch', 'numpy', 'scipy', 'numba', 'fastapi', 'uvicorn')\n"
            "         if m in sys.modules]\n"
            "print(','.join(heavy))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "", f"siva --help imported {res.stdout.strip()}"


def test_library_cli_alone_has_only_library_commands() -> None:
    from siva_core.cli import COMMANDS, build_parser

    assert [c.name for c in COMMANDS] == ["identify", "diagnose"]
    with pytest.raises(SystemExit):
        build_parser().parse_args(["serve"])
    assert "service" not in {c.target.split(".")[0] for c in COMMANDS}
