"""The optional denoiser of the film (docs/design-rendering.md, "Path tracing"):
Intel Open Image Denoise (pyoidn, `pip install 'exabricks[denoise]'`) over a
whole developed-to-be frame, for previews of the path and shadow integrators'
noisy frames. Never the default: a denoised frame is not an estimate of the
integral (its error is the network's, not 1/sqrt(spp)), so a reference image
stays raw; the image's metadata records `settings.denoise`.

A signal ends a denoise sooner than its whole call (docs/design.md, "Errors,
hostile input, outputs and signals"): OIDN is one native call of seconds on a
large frame, during which Python runs no signal handler. So it runs on a
thread of its own while the calling thread waits where handlers run, and a
progress monitor cancels it between two layers of its network once the wait
is interrupted. A layer cannot be cut: the longest of a 2048 x 2048 frame took
1.9 s on 2 CPU cores. (A bound on OIDN's scratch memory, maxMemoryMB, would cut
the frame into tiles whose layers are short, with the same image, but their
overlap made the denoise 60 % slower at 512 MB.)"""

from __future__ import annotations

import threading

import numpy as np

from ..util.errors import ExabricksError

PACKAGE = "pyoidn"
# The progress monitor's C declaration, which pyoidn's bindings lack.
_MONITOR = ("void oidnSetFilterProgressMonitorFunction(OIDNFilter filter, "
            "OIDNProgressMonitorFunction func, void* userPtr);")
# One OIDN device for the process, and one filter for each dynamic range (HDR colour,
# alpha), made on first use; one denoise at a time uses them.
_lock = threading.Lock()
_made: dict = {}


def check() -> None:
    """ExabricksError, naming the package, unless the denoiser can be loaded."""
    try:
        import pyoidn  # noqa: F401
    except ImportError:
        raise ExabricksError("--denoise needs Intel Open Image Denoise: pip install "
                             f"'exabricks[denoise]' ({PACKAGE})") from None


def denoise(rgba: np.ndarray) -> np.ndarray:
    """`rgba` (premultiplied radiance, float32 (H, W, 4)) denoised in place: its
    colour as a high-dynamic-range image, its alpha (the coverage the background
    shows through) as a grey one, kept in [0, 1], the colour non-negative."""
    check()
    colour = np.ascontiguousarray(rgba[..., :3], dtype=np.float32)
    alpha = np.ascontiguousarray(np.repeat(rgba[..., 3:4], 3, axis=-1), dtype=np.float32)
    rgba[..., :3] = np.maximum(_stoppable(colour, hdr=True), 0.0)
    rgba[..., 3] = np.clip(_stoppable(alpha, hdr=False).mean(axis=-1), 0.0, 1.0)
    return rgba


def _stoppable(image: np.ndarray, hdr: bool) -> np.ndarray:
    """`image` (float32 (H, W, 3), contiguous) denoised on a thread of its own, which
    an exception in this thread's wait (a signal's `Interrupted`) cancels between
    two layers before it is raised (module docstring)."""
    out = np.empty_like(image)
    cancel, finished = threading.Event(), threading.Event()
    failure: list = []

    def run():
        try:
            _run(image, out, hdr, cancel)
        except BaseException as e:  # handed to the waiting thread
            failure.append(e)
        finally:
            finished.set()

    threading.Thread(target=run, name="exabricks-denoise", daemon=True).start()
    # An Event, not Thread.join: a join that an exception interrupts takes the
    # thread for ended (Python 3.11's _wait_for_tstate_lock), and the second
    # join would not wait for the cancelled call.
    try:
        finished.wait()
    except BaseException:
        cancel.set()
        finished.wait()
        raise
    if failure:
        raise failure[0]
    return out


def _run(image: np.ndarray, out: np.ndarray, hdr: bool, cancel: threading.Event) -> None:
    """OIDN's RT filter at high quality (pyoidn.denoise's defaults) from `image` into
    `out`, asking `cancel` between layers."""
    import pyoidn
    from pyoidn.capi import oidn_Capi, oidn_ffi

    def monitor(user, progress):
        return not cancel.is_set()

    # error=False: an exception in the monitor (none is expected) cancels.
    callback = oidn_ffi.callback("OIDNProgressMonitorFunction", monitor, error=False,
                                 onerror=lambda *exc: None)
    with _lock:
        device, flt = _filter(hdr)
        flt.set_image(pyoidn.OIDN_IMAGE_COLOR, image, pyoidn.OIDN_FORMAT_FLOAT3)
        flt.set_image(pyoidn.OIDN_IMAGE_OUTPUT, out, pyoidn.OIDN_FORMAT_FLOAT3)
        oidn_Capi.oidnSetFilterProgressMonitorFunction(flt._filter, callback, oidn_ffi.NULL)
        flt.commit()
        flt.execute()
        oidn_Capi.oidnSetFilterProgressMonitorFunction(flt._filter, oidn_ffi.NULL, oidn_ffi.NULL)
        error = device.get_error()
    if error is not None and not cancel.is_set():
        raise ExabricksError(f"the denoiser failed: {error}")


def _filter(hdr: bool):
    """The process's OIDN device and its filter for `hdr` (made on first use; under _lock)."""
    import pyoidn
    from pyoidn.capi import oidn_ffi

    if not _made:
        oidn_ffi.cdef(_MONITOR)
        device = pyoidn.Device()
        device.commit()
        _made["device"] = device
    device = _made["device"]
    if hdr not in _made:
        flt = pyoidn.Filter(device, pyoidn.OIDN_FILTER_TYPE_RT)
        flt.set_bool("hdr", hdr)
        flt.set_quality(pyoidn.OIDN_QUALITY_HIGH)
        _made[hdr] = flt
    error = device.get_error()
    if error is not None:
        raise ExabricksError(f"the denoiser could not start: {error}")
    return device, _made[hdr]
