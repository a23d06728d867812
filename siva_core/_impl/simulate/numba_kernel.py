"""numba backend: a straight-line RK4 kernel generated from the element kinds' ``expr``.

The kernel is scalar code with a plain loop over the parameter sets, compiled once per
structure *signature* (kinds, topology, parameter slots; masses and parameter values are
arguments) and cached in-process and on disk (a generated module under ``$SIVA_CACHE_DIR``
or ``~/.cache/siva/kernels`` so numba's own cache can persist the machine code).

Serial, not ``prange`` (branch speed6): numba's parallel lowering made each compile ~2.3x
longer (5.4-6.6 s against 2.3-2.8 s cold on a 4-DOF frame at load ~3), and a diagnosis
compiles a kernel for every candidate kind x place of a structure it has not seen (23 % of
a fresh scenario's CPU).  Per call the serial kernel takes the same CPU (0.9-1.0x); the
diagnosis already runs its fits on the cores in threads (``diagnose.parallel``), and a
serial ``nogil`` kernel is re-entrant, so the calls need no lock and run side by side.
"""
from __future__ import annotations

import ast
import hashlib
import importlib.util
import os
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .grid import BLOWUP

#: (written for the kernel's former ``prange``; kept for any other OpenMP region of the
#: process) OpenMP threads (numba's "omp" layer) sleep while they wait instead of
#: spinning (libgomp's default spins ~300k times).  Why: a worker that spins after a batch
#: and a caller that spins at the barrier burn a core each; on a loaded 2-core machine the
#: spinning caller even delays the worker it waits for (cantilever, 11 sets: 7.2 ms CPU
#: and 15 ms wall per call spinning, 3.1 ms and 7 ms passive; docs/perf.md 8.3).  Only
#: the waiting changes, not what is computed (bit-identical).  Read once, when numba
#: starts its thread pool (the first parallel kernel call); a value the user set is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


class NotCompilable(Exception):
    """An element expression the kernel generator cannot translate."""


_FUNCS = {"abs": "abs", "tanh": "math.tanh", "copysign": "math.copysign", "exp": "math.exp",
          "sqrt": "math.sqrt", "log": "math.log", "sin": "math.sin", "cos": "math.cos",
          "atan": "math.atan", "min": "min", "max": "max"}
_CONSTS = {"pi": "math.pi", "e": "math.e"}


class _Renamer(ast.NodeTransformer):
    def __init__(self, names: dict[str, str]):
        self.names = names

    def visit_Call(self, node: ast.Call) -> ast.AST:
        if not isinstance(node.func, ast.Name) or node.func.id not in _FUNCS or node.keywords:
            raise NotCompilable(f"call {ast.unparse(node.func)!r} is not supported in expr")
        node.args = [self.visit(a) for a in node.args]
        node.func = ast.parse(_FUNCS[node.func.id], mode="eval").body
        return node

    def visit_Name(self, node: ast.Name) -> ast.AST:
        if node.id in self.names:
            return ast.copy_location(ast.Name(self.names[node.id], ast.Load()), node)
        if node.id in _CONSTS:
            return ast.parse(_CONSTS[node.id], mode="eval").body
        raise NotCompilable(f"unknown name {node.id!r} in expr")

    def generic_visit(self, node: ast.AST) -> ast.AST:
        allowed = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.IfExp, ast.Compare, ast.BoolOp,
                   ast.Constant, ast.operator, ast.unaryop, ast.cmpop, ast.boolop, ast.Load)
        if not isinstance(node, allowed):
            raise NotCompilable(f"{type(node).__name__} is not supported in expr")
        return super().generic_visit(node)


def _translate(expr: str | None, names: dict[str, str]) -> str:
    if not expr:
        raise NotCompilable("kind has no scalar 'expr'")
    try:
        tree = ast.parse(expr, mode="eval")
    except SyntaxError as exc:
        raise NotCompilable(f"expr {expr!r} is not valid Python ({exc.msg})") from None
    tree = _Renamer(names).visit(tree)
    return ast.unparse(tree)


_SOURCES: dict[tuple, str] = {}


def _signature(structure: Any) -> tuple:
    """What the kernel source depends on: DOF count, parameter order, and each element's
    kind (name, scalar expression, coefficients), parameters and DOF indices."""
    return (structure.n_dof, tuple(structure.parameters),
            tuple((el.kind.name, el.kind.expr, tuple(el.kind.coefficients), tuple(el.params),
                   el.i, el.j) for el in structure.elements))


def _kernel_source(structure: Any) -> str:
    """Python/numba source of the kernel for this structure's signature (memoised per
    signature: writing it parses every element's expression, and a refinement or a
    diagnosis asks for the kernel on every simulation -- ~1 ms each, 8 % of a fit)."""
    sig = _signature(structure)
    src = _SOURCES.get(sig)
    if src is None:
        src = _SOURCES[sig] = _write_kernel_source(structure)
    return src


def _write_kernel_source(structure: Any) -> str:
    n = structure.n_dof
    pnames = list(structure.parameters)
    slot = {p: k for k, p in enumerate(pnames)}
    codes: list[str] = []
    for e, el in enumerate(structure.elements):
        names = {"d": f"d_{e}", "dv": f"dv_{e}"}
        names.update({c: f"p_{slot[p]}" for c, p in zip(el.kind.coefficients, el.params)})
        try:
            codes.append(_translate(el.kind.expr, names))
        except NotCompilable as exc:
            raise NotCompilable(f"element kind {el.kind.name!r}: {exc}") from None

    def acc_block(qn: str, vn: str, un: str, out: str) -> list[str]:
        """The model's accelerations as straight-line code, written out at each RK4 stage
        (a helper function would need 3n + n_params + n arguments; numba refuses ~24+)."""
        lines: list[str] = []
        terms: list[list[str]] = [[] for _ in range(n)]
        for e, el in enumerate(structure.elements):
            if el.j >= 0:
                lines.append(f"d_{e} = {qn}{el.i} - {qn}{el.j}")
                lines.append(f"dv_{e} = {vn}{el.i} - {vn}{el.j}")
                terms[el.j].append(f"+ f_{e}")
            else:
                lines.append(f"d_{e} = {qn}{el.i}")
                lines.append(f"dv_{e} = {vn}{el.i}")
            terms[el.i].append(f"- f_{e}")
            lines.append(f"f_{e} = {codes[e]}  # {el.kind.name}")
        lines += [f"{out}{k} = ({un}{k} {' '.join(terms[k])}) * im_{k}" for k in range(n)]
        return lines

    K: list[str] = []
    ind = " " * 8
    K += [f"{ind}fb = b * fstride"]
    K += [f"{ind}p_{k} = P[b, {k}]" for k in range(len(pnames))]
    K += [f"{ind}g_{k} = G[b, {k}]" for k in range(n)]
    K += [f"{ind}im_{k} = invm[{k}]" for k in range(n)]
    K += [f"{ind}q_{k} = Q0[b, {k}]" for k in range(n)]
    K += [f"{ind}v_{k} = V0[b, {k}]" for k in range(n)]
    K += [f"{ind}for i in range(T):"]
    i2, i3, i4 = ind + " " * 4, ind + " " * 8, ind + " " * 12
    K += [f"{i2}base = i * m2"]
    K += [f"{i2}u_{k} = g_{k} * F[fb, base, {k}]" for k in range(n)]
    K += [i2 + line for line in acc_block("q_", "v_", "u_", "a_")]
    for k in range(n):
        K += [f"{i2}Q[b, i, {k}] = q_{k}", f"{i2}V[b, i, {k}] = v_{k}", f"{i2}A[b, i, {k}] = a_{k}"]
    ok = " and ".join([f"abs(q_{k}) < {BLOWUP!r} and abs(v_{k}) < {BLOWUP!r}" for k in range(n)])
    K += [f"{i2}if not ({ok}):",
          f"{i3}for j in range(i + 1, T):",
          f"{i3}    for k in range({n}):",
          f"{i3}        Q[b, j, k] = np.nan",
          f"{i3}        V[b, j, k] = np.nan",
          f"{i3}        A[b, j, k] = np.nan",
          f"{i3}break",
          f"{i2}if i == T - 1:",
          f"{i3}break"]
    K += [f"{i2}for s in range(m):",
          f"{i3}j = base + 2 * s"]
    K += [f"{i3}ua_{k} = g_{k} * F[fb, j, {k}]" for k in range(n)]
    K += [f"{i3}um_{k} = g_{k} * F[fb, j + 1, {k}]" for k in range(n)]
    K += [f"{i3}ub_{k} = g_{k} * F[fb, j + 2, {k}]" for k in range(n)]
    K += [f"{i3}if s == 0:"]
    K += [f"{i4}k1_{k} = a_{k}" for k in range(n)]
    K += [f"{i3}else:"] + [i4 + line for line in acc_block("q_", "v_", "ua_", "k1_")]
    K += [f"{i3}q2_{k} = q_{k} + hh * v_{k}" for k in range(n)]
    K += [f"{i3}v2_{k} = v_{k} + hh * k1_{k}" for k in range(n)]
    K += [i3 + line for line in acc_block("q2_", "v2_", "um_", "k2_")]
    K += [f"{i3}q3_{k} = q_{k} + hh * v2_{k}" for k in range(n)]
    K += [f"{i3}v3_{k} = v_{k} + hh * k2_{k}" for k in range(n)]
    K += [i3 + line for line in acc_block("q3_", "v3_", "um_", "k3_")]
    K += [f"{i3}q4_{k} = q_{k} + h * v3_{k}" for k in range(n)]
    K += [f"{i3}v4_{k} = v_{k} + h * k3_{k}" for k in range(n)]
    K += [i3 + line for line in acc_block("q4_", "v4_", "ub_", "k4_")]
    K += [f"{i3}q_{k} = q_{k} + h6 * (v_{k} + 2.0 * v2_{k} + 2.0 * v3_{k} + v4_{k})"
          for k in range(n)]
    K += [f"{i3}v_{k} = v_{k} + h6 * (k1_{k} + 2.0 * k2_{k} + 2.0 * k3_{k} + k4_{k})"
          for k in range(n)]

    src = [
        '"""Generated by siva_core._impl.simulate for one structure signature. Do not edit."""',
        "import math",
        "import numpy as np",
        "import numba as nb",
        "",
        "",
        "@nb.njit(cache=CACHE, nogil=True, error_model='numpy',",
        f"         fastmath={_fastmath_literal()})",
        "def kernel(P, G, F, invm, Q0, V0, dt, m, Q, V, A):",
        "    # F: force at every RK4 stage time, (1 or B, 2 m (T - 1) + 1, n_dof): sample i,",
        "    # substep s -> rows i*2m + 2s (start), +1 (midpoint), +2 (end)",
        "    B = P.shape[0]",
        "    T = Q.shape[1]",
        "    m2 = 2 * m",
        "    h = dt / m",
        "    hh = 0.5 * h",
        "    h6 = h / 6.0",
        "    fstride = F.shape[0] // B  # 1: one force per set; 0: one force shared by all",
        "    for b in range(B):",
        *K,
        "",
    ]
    return "\n".join(src)


#: LLVM may reassociate and contract (FMA) the RK4 combinations (~1.5x faster, differences at
#: rounding level); no 'nnan'/'ninf' (the divergence check must see NaN/inf) and no 'afn'
#: (tanh, pow keep libm accuracy)
_FASTMATH = ("arcp", "contract", "nsz", "reassoc")


def _fastmath_literal() -> str:
    """A set literal in fixed order: the source (hence the cache key) must not depend on
    the process's string-hash seed."""
    return "{" + ", ".join(repr(f) for f in _FASTMATH) + "}"


_KERNELS: dict[str, Callable[..., None]] = {}
_KERNEL_LOCK = threading.Lock()  # one thread writes / compiles a kernel module at a time


def _cache_dir() -> Path | None:
    for cand in (os.environ.get("SIVA_CACHE_DIR"),
                 str(Path.home() / ".cache" / "siva" / "kernels"),
                 os.path.join(tempfile.gettempdir(), f"siva-kernels-{os.getuid()}")):
        if not cand:
            continue
        p = Path(cand)
        try:
            p.mkdir(parents=True, exist_ok=True)
            probe = p / f".probe-{os.getpid()}"
            probe.write_text("")
            probe.unlink()
            return p
        except OSError:
            continue
    return None


def compiled_kernel(structure: Any) -> Callable[..., None]:
    """The compiled numba kernel of this structure's signature (in-process + on-disk cache)."""
    src = _kernel_source(structure)
    key = hashlib.sha256(src.encode()).hexdigest()[:20]
    fn = _KERNELS.get(key)
    if fn is not None:
        return fn
    with _KERNEL_LOCK:
        fn = _KERNELS.get(key)
        if fn is not None:
            return fn
        directory = _cache_dir()
        modname = f"siva_kernel_{key}"
        if directory is not None:
            path = directory / f"{modname}.py"
            text = src.replace("CACHE", "True")
            if not path.exists() or path.read_text() != text:
                tmp = directory / f".{modname}.{os.getpid()}.tmp"
                tmp.write_text(text)
                os.replace(tmp, path)
            spec = importlib.util.spec_from_file_location(modname, path)
            assert spec is not None and spec.loader is not None
            mod = importlib.util.module_from_spec(spec)
            sys.modules[modname] = mod
            spec.loader.exec_module(mod)
            fn = mod.kernel
        else:
            ns: dict[str, Any] = {}
            exec(compile(src.replace("CACHE", "False"), f"<{modname}>", "exec"), ns)
            fn = ns["kernel"]
        _KERNELS[key] = fn
        return fn


def run_numba(structure: Any, theta: np.ndarray, dt: float, T: int, Q0: np.ndarray,
              V0: np.ndarray, F: np.ndarray | None, m: int,
              force_scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Q, V, A), each (B, T, n_dof), by the compiled kernel; ``F`` is the force on the
    stage grid (``grid.stage_force``): (rows, n_dof) shared, (B, rows, n_dof) one per set,
    or None."""
    kernel = compiled_kernel(structure)
    values = structure.full_values(theta)
    B, n = Q0.shape
    P = np.empty((B, len(structure.parameters)))
    for k, p in enumerate(structure.parameters):
        P[:, k] = values[p]
    G = structure.gains(theta)
    if force_scale is not None:
        G = G * force_scale[:, None]
    Fa = (np.zeros((1, 2 * m * (T - 1) + 1, n)) if F is None
          else np.ascontiguousarray(F, dtype=float))
    if Fa.ndim == 2:
        Fa = Fa[None]
    if Fa.shape[0] not in (1, B):
        raise ValueError(f"force for {Fa.shape[0]} sets, simulating {B}")
    Q = np.empty((B, T, n))
    V = np.empty((B, T, n))
    A = np.empty((B, T, n))
    invm = np.ascontiguousarray(1.0 / structure.masses)
    Q0c, V0c = np.ascontiguousarray(Q0), np.ascontiguousarray(V0)

    def run(a: int, b: int) -> None:
        Fab = Fa if Fa.shape[0] == 1 else Fa[a:b]
        kernel(P[a:b], G[a:b], Fab, invm, Q0c[a:b], V0c[a:b], float(dt), int(m),
               Q[a:b], V[a:b], A[a:b])

    _run_chunked(run, B)
    return Q, V, A


_ACTIVE = 0  # kernel calls running now (any thread)
_ACTIVE_LOCK = threading.Lock()
_POOL: Any = None
_POOL_SIZE = 0


def _run_chunked(run: Callable[[int, int], None], B: int) -> None:
    """Run the sets ``[0, B)`` as contiguous chunks on numba's thread count when no
    other kernel call is running.  Why: the kernel is serial (compiles ~2.3x cheaper than
    ``prange``), so a lone caller simulating a batch (Approach III's candidates, a sample
    ensemble) would otherwise use one core; callers that already run on the cores side by
    side (the diagnosis's worker threads) keep one chunk each.  Each set is computed by
    the same code whichever chunk holds it: bit-identical to one call."""
    global _ACTIVE, _POOL, _POOL_SIZE
    with _ACTIVE_LOCK:
        alone = _ACTIVE == 0
        _ACTIVE += 1
    try:
        threads = _thread_count() if alone and B >= 4 else 1
        if threads <= 1:
            run(0, B)
            return
        from concurrent.futures import ThreadPoolExecutor

        with _ACTIVE_LOCK:
            if _POOL is None or _POOL_SIZE < threads:
                _POOL = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="siva-kernel")
                _POOL_SIZE = threads
            pool = _POOL
        edges = np.linspace(0, B, threads + 1).round().astype(int)
        futures = [pool.submit(run, int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])
                   if b > a]
        for f in futures:
            f.result()
    finally:
        with _ACTIVE_LOCK:
            _ACTIVE -= 1


def _thread_count() -> int:
    """numba's thread count (``NUMBA_NUM_THREADS``, the cores by default)."""
    import numba

    return int(numba.get_num_threads())


def numba_unusable(structure: Any) -> str | None:
    """Why the numba backend cannot run ``structure`` (None when it can)."""
    try:
        import numba  # noqa: F401
    except ImportError:
        return "numba is not installed"
    try:
        _kernel_source(structure)
    except NotCompilable as exc:
        return str(exc)
    return None
