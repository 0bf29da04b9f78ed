"""Which OpenCL runtime pyopencl finds: the system's drivers, else a CPU runtime
installed from PyPI into this Python environment, without root
(docs/design-kernels.md, "Devices").

pyopencl's ICD loader (ocl-icd) reads the drivers listed in the system folder
/etc/OpenCL/vendors, which only root can fill (`apt install pocl-opencl-icd`, a
GPU vendor's driver). `pip install 'exabricks[cpu]'` brings Intel's CPU runtime
(the `intel-opencl-rt` and `intel-cmplr-lib-rt` wheels, under Intel's End User
License Agreement for Developer Tools) into the environment's lib/; its own ICD
file there names a path of Intel's build machine, so it is not used. Where the
system lists no driver and the environment holds that runtime, `prepare` points
the loader at it (OCL_ICD_VENDORS, the library's path), in this process and the
processes it starts, before the first platform query. A driver of the system
always wins, and an OCL_ICD_VENDORS or OCL_ICD_FILENAMES the user set is left as
it is.

Intel's CPU runtime (from PyPI or a system package) vectorizes a kernel across
work-items by default; the kernels here are written one ray per work-item, with
their own vector code on CPUs (kernels/packet.cl), and that vectorizer made
frames 12-33 times slower than PoCL's. `prepare` turns it off
(CL_CONFIG_CPU_VECTORIZER_MODE=1, unless the user set it), which made them about as
fast as PoCL's (docs/benchmarks-render.md, "OpenCL runtimes on a CPU").
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

# The loader's folder of ICD files; EXABRICKS_SYSTEM_OPENCL_VENDORS names another
# (tests/device/test_runtime.py points it at an empty folder: a machine without a
# driver).
SYSTEM_VENDORS = "/etc/OpenCL/vendors"
# Intel's CPU runtime as its PyPI wheels install it, under the environment's prefix.
PYPI_CPU_RUNTIME = Path("lib") / "libintelocl.so"
CPU_EXTRA = "pip install 'exabricks[cpu]'"
# Intel's CPU runtime: 1 turns off its vectorizer across work-items (module docstring).
INTEL_VECTORIZER = "CL_CONFIG_CPU_VECTORIZER_MODE"


@dataclass(frozen=True)
class Runtime:
    """Where the OpenCL drivers come from, and why (`exabricks devices` says both)."""

    source: str   # "system", "environment" (OCL_ICD_* set by the user), "pypi-cpu", "none"
    detail: str   # the files or the variable
    why: str


def system_folder() -> Path:
    """The folder of the system's ICD files."""
    return Path(os.environ.get("EXABRICKS_SYSTEM_OPENCL_VENDORS") or SYSTEM_VENDORS)


def system_icds(folder: Path) -> list[str]:
    """The ICD files `folder` lists (none where it is missing)."""
    try:
        return sorted(p.name for p in folder.iterdir() if p.suffix == ".icd")
    except OSError:
        return []


def pypi_cpu_runtime() -> Path | None:
    """Intel's CPU runtime installed from PyPI into this environment, or None."""
    for prefix in dict.fromkeys((sys.prefix, sys.base_prefix)):
        library = Path(prefix) / PYPI_CPU_RUNTIME
        if library.is_file():
            return library
    return None


_CHOSEN: Runtime | None = None

_INSTALL = ("install an OpenCL driver (on a CPU-only machine: the Debian/Ubuntu package "
            f"pocl-opencl-icd, or without root: {CPU_EXTRA})")


def none_found(what: str = "platform") -> str:
    """The message where the loader finds no OpenCL `what` (platform, device): where
    an OCL_ICD_* variable the user set chose, it names the variable, its value and
    the system's drivers it hides (the loader then reads nothing else), for a
    driver may well be installed; else how to install one."""
    chosen = prepare()
    if chosen.source != "environment":
        return f"no OpenCL {what} found; {_INSTALL}"
    folder = system_folder()
    icds = system_icds(folder)
    hidden = (f"it hides the system's drivers ({folder}: {', '.join(icds)}): unset it to use them"
              if icds else f"no driver is in the system's folder {folder} either: {_INSTALL}")
    return f"no OpenCL {what} found through {chosen.detail} (set in the environment); {hidden}"


def prepare() -> Runtime:
    """Choose the runtime (module docstring) once per process, before pyopencl's
    first platform query; returns what was chosen."""
    global _CHOSEN
    if _CHOSEN is None:
        os.environ.setdefault(INTEL_VECTORIZER, "1")
        _CHOSEN = _choose()
    return _CHOSEN


def _choose() -> Runtime:
    for name in ("OCL_ICD_VENDORS", "OCL_ICD_FILENAMES"):
        if os.environ.get(name):
            return Runtime("environment", f"{name}={os.environ[name]}",
                           f"{name} is set: the loader reads what it names")
    folder = system_folder()
    icds = system_icds(folder)
    if icds:
        return Runtime("system", f"{folder}: {', '.join(icds)}",
                       "the system's OpenCL drivers (a driver of the system always wins)")
    library = pypi_cpu_runtime()
    if library is not None:
        os.environ["OCL_ICD_VENDORS"] = str(library)
        return Runtime("pypi-cpu", str(library),
                       f"no driver in {folder}: Intel's CPU runtime from PyPI in this "
                       f"environment ({CPU_EXTRA})")
    return Runtime("none", folder, f"no driver in {folder} and no CPU runtime in this "
                                   f"environment ({CPU_EXTRA} brings one without root)")
