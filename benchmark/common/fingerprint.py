"""Where a result was made: the CPU, numpy's SIMD code paths, the BLAS and its kernel, the variables
that steer them. Recorded with every row (`fingerprint`, `fingerprint_id`) and listed by reports.

Two machines with the same `fingerprint_id` run the same code paths, so their trials can be
compared bit for bit; across fingerprints only the statistics are expected to agree
(README, "Reproducibility across CPUs").
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
from functools import cache
from pathlib import Path

ENVIRONMENT = ("OPENBLAS_CORETYPE", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
               "NPY_DISABLE_CPU_FEATURES", "NPY_ENABLE_CPU_FEATURES", "MUJOCO_GL")
CPU_FLAGS = ("sse4_2", "avx", "avx2", "fma", "f16c", "avx512f", "avx512cd", "avx512bw", "avx512dq", "avx512vl",
             "avx512_vnni", "amx_tile", "asimd", "sve")


def _cpu() -> tuple[str, list[str]]:
    """CPU model name and the flags among CPU_FLAGS it has (Linux; the platform's name elsewhere)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return platform.processor() or platform.machine(), []
    model, flags = platform.machine(), set()
    for line in text.splitlines():
        key, _, value = line.partition(":")
        key = key.strip()
        if key in ("model name", "Model", "CPU part") and model == platform.machine():
            model = value.strip()
        elif key in ("flags", "Features") and not flags:
            flags = set(value.split())
    return model, [f for f in CPU_FLAGS if f in flags]


def _blas() -> list[dict]:
    """The BLAS libraries loaded in this process, with the kernel each picked (threadpoolctl)."""
    import numpy  # noqa: F401  (loads numpy's OpenBLAS)
    from threadpoolctl import threadpool_info

    return [{k: info.get(k) for k in ("internal_api", "version", "architecture", "num_threads")}
            for info in threadpool_info() if info.get("user_api") == "blas"]


@cache
def platform_fingerprint() -> dict:
    """What decides the bits of a result on this machine (the same dict for the life of the process)."""
    import numpy as np
    from numpy._core._multiarray_umath import __cpu_features__

    model, flags = _cpu()
    return {
        "machine": platform.machine(),
        "cpu": model,
        "cpu_flags": flags,
        "numpy_simd": sorted(k for k, on in __cpu_features__.items() if on and k.startswith(("AVX512", "X86_V", "ASIMD", "SVE"))),
        "numpy": np.__version__,
        "blas": _blas(),
        "env": {k: os.environ[k] for k in ENVIRONMENT if k in os.environ},
    }


def fingerprint_id(fingerprint: dict | None = None) -> str:
    """A short digest of a fingerprint: equal ids, equal code paths."""
    text = json.dumps(fingerprint or platform_fingerprint(), sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


def describe(fingerprint: dict) -> str:
    """One line for a report: CPU, its vector width, the BLAS kernel, steering variables."""
    blas = ", ".join(f"{b['internal_api']} {b['version']} kernel {b['architecture']}" for b in fingerprint.get("blas", []))
    env = " ".join(f"{k}={v}" for k, v in fingerprint.get("env", {}).items())
    simd = "AVX-512" if "avx512f" in fingerprint.get("cpu_flags", []) else \
        ("AVX2" if "avx2" in fingerprint.get("cpu_flags", []) else "no AVX2")
    return "; ".join(part for part in (f"{fingerprint.get('cpu')} ({simd})", blas or "no BLAS loaded", env) if part)
