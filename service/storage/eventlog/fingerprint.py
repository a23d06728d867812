"""The platform fingerprint: what decides whether a replay can be bit-identical.

Why: training is float arithmetic whose rounding depends on the library builds (torch,
numpy, scipy, numba, the BLAS behind them), on the SIMD kernels they dispatch to (torch's
CPU capability, the CPU's instruction sets, which MKL and OpenBLAS pick from at run time)
and on the interpreter.  Two platforms that agree on all of these replay a log
bit-identically; two that differ in any of them cannot be expected to - their results
agree only to within rounding amplified by training (docs/logs.md, "exactness").

Every event log records :func:`platform_fingerprint` in its ``siva.platform`` metadata
record; ``siva replay`` compares it with the current one (:func:`fingerprint_differences`)
to say whether ``identical`` was to be expected.  All values are strings (MCAP metadata
is a string map).
"""
from __future__ import annotations

import os
import platform
import re
from functools import lru_cache
from importlib import metadata
from typing import Mapping

#: the instruction sets that BLAS/oneDNN/torch kernels dispatch on (x86 and ARM names)
_SIMD_FLAGS = ("sse4_2", "avx", "avx2", "fma", "f16c", "avx512f", "avx512dq", "avx512bw",
               "avx512vl", "avx512_vnni", "avx512_bf16", "avx512_fp16", "amx_tile",
               "amx_bf16", "amx_int8", "asimd", "sve", "sve2")

#: environment variables that change which kernels run (ATEN_CPU_CAPABILITY shows up as
#: the capability itself)
_DISPATCH_ENV = ("MKL_CBWR", "MKL_ENABLE_INSTRUCTIONS", "MKL_DEBUG_CPU_TYPE",
                 "OPENBLAS_CORETYPE", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES")


def _version(dist: str) -> str:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "absent"


def _cpu_simd() -> str:
    """The dispatch-relevant instruction sets of this CPU, sorted ('' when unknown)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                if key.strip() in ("flags", "Features"):
                    have = set(value.split())
                    return " ".join(f for f in _SIMD_FLAGS if f in have)
    except OSError:
        pass
    return ""


def _torch_blas(config: str) -> str:
    """torch's BLAS and its version, from ``torch.__config__.show()``."""
    info = re.search(r"BLAS_INFO=([^,\s]+)", config)
    mkl = re.search(r"Math Kernel Library Version ([^\n]+?) for", config)
    name = info.group(1) if info else "unknown"
    return f"{name} {mkl.group(1).strip()}" if mkl and name == "mkl" else name


def _numpy_blas() -> str:
    try:
        import numpy as np

        blas = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
        return f"{blas.get('name', 'unknown')} {blas.get('version', '')}".strip()
    except Exception:  # noqa: BLE001 - older numpy: no dict mode; the version still says it
        return "unknown"


@lru_cache(maxsize=1)
def _static() -> dict[str, str]:
    import torch

    return {
        "python": platform.python_version(),
        "torch": torch.__version__,
        "numpy": _version("numpy"),
        "scipy": _version("scipy"),
        "numba": _version("numba"),
        "torch_blas": _torch_blas(torch.__config__.show()),
        "numpy_blas": _numpy_blas(),
        "machine": platform.machine(),
        "cpu_simd": _cpu_simd(),
    }


def platform_fingerprint() -> dict[str, str]:
    """What bit-identity of training depends on, here and now (strings only)."""
    import torch

    env = " ".join(f"{k}={os.environ[k]}" for k in _DISPATCH_ENV if os.environ.get(k))
    return {**_static(), "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
            "dispatch_env": env}


def fingerprint_differences(logged: Mapping[str, str] | None,
                            current: Mapping[str, str]) -> dict[str, list[str | None]]:
    """``{key: [logged, current]}`` for every key that differs; a log without a
    fingerprint (written before logs carried one) differs in ``platform`` itself."""
    if not logged:
        return {"platform": ["unknown (log without a fingerprint)", "this one"]}
    keys = sorted(set(logged) | set(current))
    return {k: [logged.get(k), current.get(k)] for k in keys if logged.get(k) != current.get(k)}
