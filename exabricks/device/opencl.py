"""OpenCL devices, contexts and the compiled kernel program.

Device choice (docs/design-kernels.md, "Devices") is explicit and never interactive: a
``SPEC`` of ``"P:D"`` (platform and device indices as `exabricks devices` lists
them) or a case-insensitive substring of the device or platform name, from
``--device`` or ``EXABRICKS_DEVICE``; the default is the first GPU, else the
first CPU, else the first device. On a machine without a GPU the kernels run on
the CPU through PoCL (Debian package ``pocl-opencl-icd``).

Kernel sources are the ``.cl``/``.h`` files of ``<checkout>/kernels`` or, in an
installed wheel, ``exabricks/kernels``; the directory is passed to the compiler
as an include path. The program is built once per context, set of
preprocessor defines and process; pyopencl's on-disk binary cache (and PoCL's
kernel cache) make later processes skip compilation.

A build that compiles (the first use of a set of options on a machine: seconds to
tens of seconds on a small CPU) says so on a terminal, with the seconds ticking
(exabricks.util.progress.waiting), and in the log with -v; so does a kernel's first
enqueue, where PoCL compiles its work-group function. A build served from a cache
stays silent. `exabricks devices --warm` (exabricks.warm) builds the programs of
the first pictures ahead.
"""

from __future__ import annotations

import logging
import os
import threading
import time
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from . import kernel_abi, runtime
from ..util import progress
from ..util.errors import ExabricksError

log = logging.getLogger(__name__)

# The source file holding the __kernel entry points; it #includes the rest.
ENTRY_SOURCE = "render.cl"

# No -cl-fast-relaxed-math: it implies finite-math-only, and the kernels rely on
# IEEE infinities (ray slabs) and NaN (probe outside the data). Flushing
# denormals and ignoring the sign of zero keep both (the slab test takes
# fmin/fmax of both planes, so the sign of an infinite 1/dir does not matter)
# and make frames faster on PoCL (docs/benchmarks-render.md, "render (PoCL)").
# The limits every kernel loop and stack obeys, and the frame's parameters, come
# from exabricks.device.kernel_abi, whose header() starts every program.
BUILD_OPTIONS = ("-cl-mad-enable", "-cl-no-signed-zeros", "-cl-denorms-are-zero")

def _cl():
    try:
        import pyopencl as cl
    except ImportError as e:  # pragma: no cover - pyopencl is a dependency
        raise ExabricksError(f"pyopencl cannot be imported ({e}); reinstall exabricks") from None
    return cl


def kernel_dir() -> Path:
    """The directory of the kernel sources: ``<checkout>/kernels``, else the wheel's copy."""
    checkout = Path(__file__).resolve().parents[2] / "kernels"
    if (checkout / ENTRY_SOURCE).is_file():
        return checkout
    packaged = Path(str(resources.files("exabricks") / "kernels"))
    if (packaged / ENTRY_SOURCE).is_file():
        return packaged
    raise ExabricksError(f"kernel sources not found (looked in {checkout} and {packaged})")


@dataclass(frozen=True)
class DeviceInfo:
    """One OpenCL device as `exabricks devices` shows it."""

    spec: str          # "P:D", usable as --device
    name: str
    platform: str
    type: str          # GPU, CPU, ACCELERATOR, ...
    version: str       # the device's OpenCL version string
    compute_units: int
    global_memory_bytes: int

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _platforms():
    runtime.prepare()  # before the loader's first query: it reads its folders once
    cl = _cl()
    try:
        platforms = cl.get_platforms()
    except cl.LogicError:  # PLATFORM_NOT_FOUND_KHR: no ICD installed
        platforms = []
    if not platforms:
        raise ExabricksError(runtime.none_found("platform"))
    return platforms


def _devices():
    """[(spec, platform, device)] over every platform, in index order."""
    cl = _cl()
    out = []
    for p, platform in enumerate(_platforms()):
        try:
            devices = platform.get_devices()
        except cl.Error:  # a platform with no devices raises DEVICE_NOT_FOUND
            devices = []
        for d, device in enumerate(devices):
            out.append((f"{p}:{d}", platform, device))
    if not out:
        raise ExabricksError(runtime.none_found("device"))
    return out


def _device_type(device) -> str:
    """GPU, CPU, ACCELERATOR or OTHER (PoCL also sets the ALL bit, which says nothing)."""
    cl = _cl()
    for name in ("GPU", "CPU", "ACCELERATOR"):
        if device.type & getattr(cl.device_type, name):
            return name
    return "OTHER"


def is_cpu(device) -> bool:
    """Whether `device` is a CPU (PoCL, the Intel CPU runtime, ...)."""
    return _device_type(device) == "CPU"


def list_devices() -> list[DeviceInfo]:
    """Every OpenCL device of every platform; ExabricksError if there is none."""
    infos = []
    for spec, platform, device in _devices():
        infos.append(DeviceInfo(
            spec=spec,
            name=device.name.strip(),
            platform=platform.name.strip(),
            type=_device_type(device),
            version=device.version.strip(),
            compute_units=int(device.max_compute_units),
            global_memory_bytes=int(device.global_mem_size),
        ))
    return infos


def choose_device(spec: str | None = None):
    """The pyopencl Device for `spec` (module docstring); None uses EXABRICKS_DEVICE or the
    default; a Device is itself."""
    if spec is not None and not isinstance(spec, str):
        return spec
    cl = _cl()
    if spec is None:
        spec = os.environ.get("EXABRICKS_DEVICE") or None
    devices = _devices()
    if spec is None:
        for wanted in (cl.device_type.GPU, cl.device_type.CPU):
            for _, _, device in devices:
                if device.type & wanted:
                    return device
        return devices[0][2]
    spec = str(spec).strip()
    for s, _, device in devices:
        if s == spec:
            return device
    matches = [device for _, platform, device in devices
               if spec.lower() in device.name.lower() or spec.lower() in platform.name.lower()]
    if matches:
        return matches[0]
    known = "; ".join(f"{s} {device.name.strip()}" for s, _, device in devices)
    raise ExabricksError(f"no OpenCL device matches --device {spec!r} (devices: {known})")


_CONTEXTS: dict = {}
_PROGRAMS: dict = {}


def context_for(device):
    """One context (and in-order queue) per device and process: (context, queue)."""
    cl = _cl()
    key = device.int_ptr
    if key not in _CONTEXTS:
        context = cl.Context([device])
        _CONTEXTS[key] = (context, cl.CommandQueue(context))
    return _CONTEXTS[key]


def build_options(defines=(), nvidia: bool = False, capped: bool = True) -> list[str]:
    """The OpenCL build options of a program with preprocessor `defines`, for an
    NVIDIA device (kernel_abi.nv_build_options of `capped`, first: an option added
    to BUILD_OPTIONS, as benchmarks.ab_kernels adds them, comes later and wins) or
    another."""
    return [*(kernel_abi.nv_build_options(capped) if nvidia else ()), *BUILD_OPTIONS,
            f"-I{kernel_dir()}", *(f"-D{d}" for d in defines)]


def is_nvidia(device) -> bool:
    """Whether `device` runs NVIDIA's OpenCL driver."""
    return "NVIDIA" in device.platform.name.upper()


def program_for(context, defines=(), source_name: str = ENTRY_SOURCE, capped: bool = True):
    """The built kernel program `source_name` (a main file of kernels/) of
    `context` with preprocessor `defines` (e.g. ``("EB_CELL_LOCATION",)``, each
    passed as ``-D``; `capped`: under NVIDIA's register cap), compiled once per
    process (BUILDS records each build)."""
    cl = _cl()
    defines = tuple(defines)
    key = (context.int_ptr, defines, source_name, capped)
    if key not in _PROGRAMS:
        directory = kernel_dir()
        source = kernel_abi.header() + (directory / source_name).read_text(encoding="utf-8")
        options = build_options(defines, is_nvidia(context.devices[0]), capped)
        device = _device_name(context.devices[0])
        what = "the renderer" if source_name == ENTRY_SOURCE else f"kernels/{source_name}"
        start = time.perf_counter()
        try:
            with _compiler_stderr() as terminal, _compiling(what, device, terminal), \
                    warnings.catch_warnings():
                # Intel's CPU runtime logs every build ("Compilation started", ...), which
                # pyopencl turns into a CompilerWarning on stderr: a failure's log is in
                # the error below, and --debug shows the rest.
                warnings.simplefilter("ignore", cl.CompilerWarning)
                _PROGRAMS[key] = cl.Program(context, source).build(options=options)
                _log_build_log(_PROGRAMS[key], context)
        except cl.RuntimeError as e:
            raise ExabricksError(f"{directory / source_name}: OpenCL build failed: {e}") from None
        seconds = time.perf_counter() - start
        BUILDS.append((source_name, defines, seconds))
        _log_compile(f"compiling {what} for {device} (defines: {' '.join(defines) or 'none'})", seconds)
    return _PROGRAMS[key]


def _log_build_log(program, context) -> None:
    """A build's log (its warnings and notes), at debug level."""
    cl = _cl()
    for device in context.devices:
        try:
            text = program.get_build_info(device, cl.program_build_info.LOG).strip()
        except cl.Error:
            continue
        if text:
            log.debug("build log on %s:\n%s", _device_name(device), text)


# Every program build of this process: (source name, defines, seconds), in order
# (a build that a cache served counts too; tests count them).
BUILDS: list = []

# A compile that follows a shown one within this many seconds continues its line and clock.
_CONTINUE_SECONDS = 1.0
_last_shown = {"since": 0.0, "until": -1e9}


def separate_compiles() -> None:
    """Start the next compile's terminal line and clock afresh (a new task begins)."""
    _last_shown["until"] = -1e9


def _device_name(device) -> str:
    return device.name.strip()


@contextmanager
def _compiling(what: str, device: str, stream=None):
    """The terminal line of a compile of `what` for `device` (progress.waiting, on
    `stream`: default stderr), shown when it takes long; consecutive compiles (a
    frame's programs, then its kernel's work-group function) share one line and one
    clock."""
    now = time.perf_counter()
    since = _last_shown["since"] if now - _last_shown["until"] < _CONTINUE_SECONDS else now
    message = f"compiling {what} for {device} (first use of these options; cached afterwards)…"
    with progress.waiting(message, since=since, stream=stream) as wait:
        try:
            yield wait
        finally:
            if wait.shown:
                _last_shown.update(since=wait.since, until=time.perf_counter())


# One build at a time holds file descriptor 2 aside (`_compiler_stderr`).
_STDERR_HELD = threading.Lock()


@contextmanager
def _compiler_stderr():
    """Hold what is written to file descriptor 2 during a program build aside, and
    write it there afterwards unless a signal came meanwhile; yields a stream on the
    real stderr (for the build's terminal line).

    PoCL compiles in the process with clang, which writes its "1 error generated."
    to descriptor 2 itself, and whose own handlers of SIGINT and SIGTERM remove the
    temporary file it is writing before Python's handler sees the signal: the
    interrupted build fails, and its compiler output would precede the run's one
    `error: interrupted` line (exabricks.util.interrupt). A build that fails without a
    signal shows its output as before (and its log is in the error)."""
    import sys
    import tempfile

    from ..util import interrupt

    def flush():
        try:
            sys.stderr.flush()
        except (AttributeError, OSError, ValueError):
            pass

    with _STDERR_HELD:
        flush()
        try:
            saved = os.dup(2)
        except OSError:  # no stderr to hold aside
            saved = None
        if saved is None:
            yield None
            return
        quiet = False
        try:
            with tempfile.TemporaryFile() as held, os.fdopen(
                    os.dup(saved), "w", encoding=getattr(sys.stderr, "encoding", None) or "utf-8",
                    errors="backslashreplace") as terminal:
                os.dup2(held.fileno(), 2)
                try:
                    yield terminal
                except BaseException as e:
                    quiet = not isinstance(e, Exception)  # Interrupted, KeyboardInterrupt
                    raise
                finally:
                    flush()  # what Python wrote meanwhile is held too
                    os.dup2(saved, 2)
                    if not quiet and interrupt.pending() is None:
                        held.seek(0)
                        data = held.read()
                        while data:
                            data = data[os.write(2, data):]
        finally:
            os.close(saved)


def _log_compile(what: str, seconds: float) -> None:
    """One log line per compile: INFO (-v) when it took long enough to be announced."""
    level = logging.INFO if seconds >= progress.announce_after() else logging.DEBUG
    log.log(level, "%s took %.1f s", what, seconds)


class Kernel:
    """A pyopencl Kernel (attributes pass through) whose first enqueue waits until
    the command starts running, announced like a build when that takes long: PoCL
    compiles a kernel's work-group function for the work-group size of its first
    command, on its worker thread, before it runs (otherwise an unannounced wait
    in the read that follows)."""

    def __init__(self, kernel, name: str):
        self.kernel = kernel
        self.entry = name
        self.first = True

    def __call__(self, queue, *args, **kw):
        if not self.first:
            return self.kernel(queue, *args, **kw)
        self.first = False
        device = _device_name(queue.device)
        start = time.perf_counter()
        with _compiling("the renderer" if self.entry == "eb_render" else f"kernel {self.entry}",
                        device):
            event = self.kernel(queue, *args, **kw)
            _wait_running(queue, event)
        _log_compile(f"compiling the work-group function of {self.entry} for {device}",
                     time.perf_counter() - start)
        return event

    def __getattr__(self, name):
        return getattr(self.kernel, name)


def _wait_running(queue, event) -> None:
    """Wait until `event`'s command runs or has ended (not for the run itself)."""
    cl = _cl()
    queue.flush()  # a driver may hold a command back until the queue is flushed
    running = cl.command_execution_status.RUNNING
    while event.command_execution_status > running:
        time.sleep(0.002)


_KERNELS: dict = {}


def kernel(program, name: str) -> Kernel:
    """The Kernel `name` of `program`, one object per process (pyopencl's
    ``program.name`` makes a new one, and warns, on every access); called as a
    pyopencl Kernel, its first enqueue says so when it compiles (`Kernel`)."""
    key = (program.int_ptr, name)
    if key not in _KERNELS:
        _KERNELS[key] = Kernel(_cl().Kernel(program, name), name)
    return _KERNELS[key]


def to_device(queue, array, dtype=None, writable: bool = False, share: bool = False):
    """A device buffer holding `array` (at least one element: OpenCL forbids 0
    bytes), read-only unless `writable`.

    share: on a CPU device, a read-only buffer uses the host array's memory itself
    (CL_MEM_USE_HOST_PTR; the buffer keeps the array alive), so that a dataset is
    not held twice in the same RAM; elsewhere it is copied to the device.  Only
    for buffers that outlive every kernel using them (the resident dataset): when
    the last reference to a shared buffer goes, so does the memory a queued kernel
    may still be reading."""
    cl = _cl()
    host = np.ascontiguousarray(array, dtype=dtype)
    if host.nbytes == 0:
        host = np.zeros(1, dtype=host.dtype)
    access = cl.mem_flags.READ_WRITE if writable else cl.mem_flags.READ_ONLY
    placement = cl.mem_flags.COPY_HOST_PTR
    if share and not writable and queue.device.type & cl.device_type.CPU:
        placement = cl.mem_flags.USE_HOST_PTR
    return cl.Buffer(queue.context, access | placement, hostbuf=host)


def int4(a: int, b: int, c: int, d: int):
    """An OpenCL int4 kernel argument."""
    import pyopencl.cltypes as cltypes

    return cltypes.make_int4(int(a), int(b), int(c), int(d))


def float4(xyz, w=0.0):
    """An OpenCL float4 kernel argument (x, y, z, w)."""
    import pyopencl.cltypes as cltypes

    x, y, z = (float(v) for v in xyz)
    return cltypes.make_float4(x, y, z, float(w))


def empty_buffer(queue, nbytes: int):
    """A device buffer of `nbytes` (at least 1) for kernel output."""
    cl = _cl()
    return cl.Buffer(queue.context, cl.mem_flags.READ_WRITE, size=max(int(nbytes), 1))


def fill_zero(queue, buffer, nbytes: int) -> None:
    """Set the first `nbytes` (a multiple of 4) of `buffer` to zero."""
    if nbytes:
        _cl().enqueue_fill_buffer(queue, buffer, np.uint32(0), 0, int(nbytes))


def write_to(queue, buffer, host: np.ndarray) -> None:
    """Copy the contiguous host array `host` into the start of `buffer` (blocking)."""
    if host.nbytes:
        _cl().enqueue_copy(queue, buffer, np.ascontiguousarray(host))


def read_back(queue, buffer, out: np.ndarray) -> np.ndarray:
    """Copy `buffer` into the host array `out` (blocking) and return it."""
    cl = _cl()
    if out.nbytes:
        cl.enqueue_copy(queue, out, buffer)
    return out
