"""The VTK side of benchmarks/bench_peers.py: VTK set up the way ParaView renders AMR on
a CPU, matched to our frame, and its worker.

worker_vtk, VTK (the `vtk` wheel from PyPI, 9.7), ParaView's CPU way, offscreen: the worker sets
VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow (EGL on Mesa's llvmpipe: Debian's libegl1,
libegl-mesa0, libgl1-mesa-dri; no X server) and LP_NUM_THREADS=--vtk-threads before
VTK loads. The reader ParaView would use (VTK_READERS: vtkAMReXGridReader,
vtkAMREnzoReader in code units, vtkXdmfReader on Athena++'s .athdf.xdmf; Gerris and
the ExaJet files have none: "no VTK reader"), every level, the field as cell data.
(a) vtkResampleToImage to the finest level's cell centres over the domain (the finest
cell size read from VTK's data; skipped above --max-voxels, e.g. Enzo's 2048^3), then
vtkFixedPointVolumeRayCastMapper with --vtk-threads threads and a fixed sample
distance of half a finest cell: resample seconds, first image (reader + resample +
render window + first frame) and the median of --runs frames (render + read-back)
after it. (b) vtkAMRVolumeMapper on the reader's vtkOverlappingAMR (Athena's XDMF
gives disjoint blocks, not an AMR: not run): first image and frames likewise, and the
grid it resampled to (its own vtkAMRResampleFilter's report on stderr, and the same
filter run again outside it for the spacing) and the render mode its smart mapper
chose. Images are compared with ours at rate 2 (the same sample spacing).

How VTK is matched (vtk_camera_parameters, vtk_volume_property, vtk_image_to_ours;
tests/bench/test_bench_peers.py checks each): the vtkCamera gets our position, look_at as focal
point, our up' as view up and fovy as (vertical) view angle, with a clipping range around
the data; VTK's perspective projection puts pixel centres where ours are, so the ray of
every pixel is ours; VTK's frame starts at the bottom row and is flipped. The colour and
opacity knots go into a vtkColorTransferFunction (RGB space) and a vtkPiecewiseFunction,
clamped as ours, with SetScalarOpacityUnitDistance(unit): VTK's opacity correction
1 - (1 - alpha)^(dt / unit) is ours. Differences that remain: the resampled grid holds
cell values at cell centres (coarse cells repeated) and is trilinear between them, and
stops half a finest cell inside each face; the fixed-point caster composites in 15 bits
and stops at full opacity; the 8-bit framebuffer; vtkAMRVolumeMapper's coarse grid.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.peers.common import RATES, ROOT

# The VTK reader ParaView opens each dataset with (None: VTK has none) and the file it
# opens: the plotfile directory, Enzo's .hierarchy, Athena++'s .athdf.xdmf sidecar.
VTK_READERS = {"amrex": ("vtkAMReXGridReader", ""), "enzo": ("vtkAMREnzoReader", ".hierarchy"),
               "athena": ("vtkXdmfReader", ".xdmf"), "gerris": None, "big": None,
               "shell256": None}
VTK_WINDOW = "vtkEGLRenderWindow"   # offscreen OpenGL through EGL (Mesa's llvmpipe here)
VTK_SAMPLES_PER_CELL = RATES[0]     # fixed-point sample distance: finest cell / this (ours' rate 2)


def vtk_source(name: str, path) -> Path | None:
    """The file VTK's reader opens for dataset `name` at `path` (None: VTK has no reader).
    A sidecar missing beside `path` (tests/data holds no .xdmf) is looked for in the
    shared data folder's copy of the dataset."""
    reader = VTK_READERS.get(name)
    if reader is None:
        return None
    source = Path(str(path) + reader[1])
    shared = ROOT.parent / "shared" / "data" / source.parent.name / source.name
    return shared if not source.exists() and shared.exists() else source


def vtk_skip_reason(name: str, path) -> str | None:
    """Why VTK is not run on a dataset (None: it is run)."""
    source = vtk_source(name, path)
    if source is None:
        return "no VTK reader"
    if not source.exists():
        return f"no VTK input: {source.name} missing"
    return None


def vtk_finest_grid(bounds, spacing) -> tuple[list[int], list[float]]:
    """The finest level's cell-centred lattice over `bounds` (VTK's (xmin, xmax, ymin, ymax,
    zmin, zmax)) with cell size `spacing` (3,): (dims = extent / spacing, rounded;
    vtkResampleToImage's sampling bounds, the first and last cell centres on each axis)."""
    b = np.asarray(bounds, np.float64).reshape(3, 2)
    h = np.asarray(spacing, np.float64)
    if (h <= 0).any() or not np.isfinite(h).all():
        raise ValueError(f"finest cell size must be positive, got {h.tolist()}")
    dims = np.rint((b[:, 1] - b[:, 0]) / h).astype(np.int64)
    if (dims < 1).any():
        raise ValueError(f"bounds {b.tolist()} hold no cell of size {h.tolist()}")
    sampling = np.column_stack([b[:, 0] + 0.5 * h, b[:, 0] + (dims - 0.5) * h]).ravel()
    return [int(d) for d in dims], [float(x) for x in sampling]


def vtk_camera_parameters(camera, world_bounds) -> dict:
    """vtkCamera settings that see exactly what `camera` sees (module docstring): position,
    focal point = look_at, view up = our up' (orthogonal to the view), view angle = fovy
    (VTK's angle is vertical unless UseHorizontalViewAngle), and a clipping range
    (depths along the view direction) that holds the whole box `world_bounds` ([lo, hi])."""
    position = np.asarray(camera.position, np.float64)
    forward = np.asarray(camera.look_at, np.float64) - position
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(camera.up, np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    lo, hi = (np.asarray(b, np.float64) for b in world_bounds)
    corners = np.array([[(lo, hi)[(k >> a) & 1][a] for a in range(3)] for k in range(8)])
    depth = (corners - position) @ forward
    far = float(depth.max()) * 1.01
    if far <= 0.0:
        raise ValueError("the data lies behind the camera")
    near = max(float(depth.min()) * 0.99, far * 1e-4)
    return {"position": position.tolist(), "focal_point": list(camera.look_at),
            "view_up": up.tolist(), "view_angle": float(camera.fovy),
            "clipping_range": [near, far]}


def apply_vtk_camera(vtk_camera, params: dict) -> None:
    """Set a vtkCamera from `vtk_camera_parameters`."""
    vtk_camera.SetParallelProjection(False)
    vtk_camera.SetUseHorizontalViewAngle(False)
    vtk_camera.SetPosition(*params["position"])
    vtk_camera.SetFocalPoint(*params["focal_point"])
    vtk_camera.SetViewUp(*params["view_up"])
    vtk_camera.SetViewAngle(params["view_angle"])
    vtk_camera.SetClippingRange(*params["clipping_range"])


def vtk_volume_property(tf, unit_distance: float):
    """A vtkVolumeProperty equal to `tf`: a vtkColorTransferFunction (RGB space) through its
    colour knots and a vtkPiecewiseFunction through its opacity knots, both clamped outside
    (as ours), opacity per `unit_distance` (VTK corrects a step dt to
    1 - (1 - alpha)^(dt / unit), as we do), no shading, trilinear interpolation."""
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction
    from vtkmodules.vtkRenderingCore import vtkColorTransferFunction, vtkVolumeProperty

    colour = vtkColorTransferFunction()
    colour.SetColorSpaceToRGB()
    colour.SetClamping(True)
    for x, r, g, b in tf.rgb_points:
        colour.AddRGBPoint(float(x), float(r), float(g), float(b))
    opacity = vtkPiecewiseFunction()
    opacity.SetClamping(True)
    for x, a in tf.alpha_points:
        opacity.AddPoint(float(x), float(a))
    prop = vtkVolumeProperty()
    prop.SetColor(colour)
    prop.SetScalarOpacity(opacity)
    prop.SetScalarOpacityUnitDistance(float(unit_distance))
    prop.ShadeOff()
    prop.SetInterpolationTypeToLinear()
    return prop


def vtk_image_to_ours(pixels, width: int, height: int) -> np.ndarray:
    """VTK's RGBA floats (rows from the bottom, premultiplied over the transparent black
    background) as our float32 (row from the top, col, rgba) layout."""
    image = np.asarray(pixels, np.float32).reshape(height, width, 4)
    return np.ascontiguousarray(image[::-1])


# vtkAMRResampleFilter reports on stderr how it resampled (vtkAMRResampleFilter.cxx):
# the level it resolves to, the grid it made and the levels it took values from.
_AMR_LOG = {
    "requested_max_level": (r"Requested Max Level = (\d+)", int),
    "requested_dims": (r"Request Grid Dim : (\d+), (\d+), (\d+)", int),
    "computed_dims": (r"Computed Grid Dim: (\d+), (\d+), (\d+)", int),
    "adjusted_dims": (r"Adjusted Grid Dim: (\d+), (\d+), (\d+)", int),
    "levels_loaded": (r"Number Levels Loaded = (\d+)", int),
    "blocks_loaded": (r"Number of Blocks = (\d+)", int),
    "average_level": (r"Average Level: ([-+0-9.eE]+|nan)", float),
    "failed_points": (r"Number Of Failed Points: (\d+)", int),
}


def parse_amr_resampler_log(text: str) -> dict:
    """The figures vtkAMRResampleFilter printed (the last of each), as {key: value or list}."""
    import re

    out = {}
    for key, (pattern, kind) in _AMR_LOG.items():
        found = re.findall(pattern, text)
        if found:
            last = found[-1]
            out[key] = [kind(x) for x in last] if isinstance(last, tuple) else kind(last)
    return out


class _StderrCapture:
    """Collect what C++ code writes to file descriptor 2 inside a `with` block (.text)."""

    def __enter__(self):
        sys.stderr.flush()
        self._file = tempfile.TemporaryFile()
        self._saved = os.dup(2)
        os.dup2(self._file.fileno(), 2)
        return self

    def __exit__(self, *exc):
        sys.stderr.flush()
        os.dup2(self._saved, 2)
        os.close(self._saved)
        self._file.seek(0)
        self.text = self._file.read().decode(errors="replace")
        self._file.close()
        return False


def _vtk_reader(kind: str, source: str, field: str):
    """A VTK reader of `source` with `field` (cell data) selected and every level loaded."""
    if kind == "vtkXdmfReader":
        from vtkmodules.vtkIOXdmf2 import vtkXdmfReader

        reader = vtkXdmfReader()
        reader.SetFileName(source)
        reader.UpdateInformation()
        for i in range(reader.GetNumberOfCellArrays()):
            name = reader.GetCellArrayName(i)
            reader.SetCellArrayStatus(name, int(name == field))
        return reader
    from vtkmodules import vtkIOAMR

    reader = getattr(vtkIOAMR, kind)()
    reader.SetFileName(source)
    if kind == "vtkAMREnzoReader":
        reader.SetConvertToCGS(False)  # code units, as our reader and the transfer function
    reader.UpdateInformation()
    reader.SetMaxLevel(max(reader.GetNumberOfLevels(), 1) + 1)  # default: level 0 only
    for i in range(reader.GetNumberOfCellArrays()):
        name = reader.GetCellArrayName(i)
        reader.SetCellArrayStatus(name, int(name == field))
    return reader


def _vtk_finest_spacing(data) -> list[float]:
    """The smallest cell size (per axis) of a vtkOverlappingAMR (its finest level) or of the
    leaf blocks of any other composite data set (image or rectilinear grids)."""
    from vtkmodules.vtkCommonDataModel import vtkOverlappingAMR
    from vtkmodules.util.numpy_support import vtk_to_numpy

    if isinstance(data, vtkOverlappingAMR):
        h = [0.0, 0.0, 0.0]
        data.GetSpacing(data.GetNumberOfLevels() - 1, h)
        return h
    h = np.full(3, np.inf)
    it = data.NewIterator()
    it.InitTraversal()
    while not it.IsDoneWithTraversal():
        block = it.GetCurrentDataObject()
        if hasattr(block, "GetXCoordinates"):
            for a, coords in enumerate((block.GetXCoordinates(), block.GetYCoordinates(),
                                        block.GetZCoordinates())):
                c = vtk_to_numpy(coords)
                if c.size > 1:
                    h[a] = min(h[a], float(np.diff(c).min()))
        elif hasattr(block, "GetSpacing"):
            h = np.minimum(h, block.GetSpacing())
        it.GoToNextItem()
    return h.tolist()


def worker_vtk(spec: dict) -> dict:
    """VTK the way ParaView renders AMR on a CPU (module docstring): (a) the reader,
    vtkResampleToImage to the finest level's cell centres, vtkFixedPointVolumeRayCastMapper;
    (b) vtkAMRVolumeMapper on the reader's vtkOverlappingAMR. Offscreen through EGL."""
    threads = int(spec.get("vtk_threads") or os.cpu_count() or 1)
    # Read when the first render window is made (VTK) and when Mesa starts (llvmpipe).
    os.environ["VTK_DEFAULT_OPENGL_WINDOW"] = VTK_WINDOW
    os.environ["LP_NUM_THREADS"] = str(threads)
    from exabricks.picture.camera import Camera
    from exabricks.picture.transfer_function import TransferFunction

    camera = Camera.from_dict(spec["camera"])
    tf = TransferFunction.from_paraview_dict(spec["transfer_function"])
    size, runs, field, unit = spec["size"], spec["runs"], spec["field"], spec["unit_distance"]
    kind = VTK_READERS[spec["name"]][0]
    source = str(vtk_source(spec["name"], spec["path"]))
    view = vtk_camera_parameters(camera, spec["world_bounds"])

    t = time.perf_counter()
    import importlib

    # The OpenGL render window and the OpenGL volume mappers, registered on import.
    for module in ("vtkmodules.vtkRenderingOpenGL2", "vtkmodules.vtkRenderingVolumeOpenGL2"):
        importlib.import_module(module)
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkFloatArray, vtkVersion
    from vtkmodules.vtkCommonDataModel import vtkOverlappingAMR
    from vtkmodules.vtkRenderingCore import vtkCamera, vtkRenderer, vtkRenderWindow, vtkVolume
    t_import = time.perf_counter() - t

    def window(volume):
        rw = vtkRenderWindow()
        rw.SetOffScreenRendering(True)
        rw.SetMultiSamples(0)
        rw.SetAlphaBitPlanes(True)
        rw.SetSize(size, size)
        ren = vtkRenderer()
        ren.SetBackground(0.0, 0.0, 0.0)
        ren.SetBackgroundAlpha(0.0)
        cam = vtkCamera()
        apply_vtk_camera(cam, view)
        ren.SetActiveCamera(cam)
        ren.AddVolume(volume)
        rw.AddRenderer(ren)
        out["window"] = rw.GetClassName()  # vtkEGLRenderWindow unless VTK fell back
        return rw, ren

    def frame(rw):
        """Render, and read the frame back (as ours does): our image layout."""
        rw.Render()
        pixels = vtkFloatArray()
        rw.GetRGBAPixelData(0, 0, size - 1, size - 1, 0, pixels, 0)
        return vtk_image_to_ours(vtk_to_numpy(pixels), size, size)

    def steady(rw):
        times = []
        for _ in range(runs):
            t = time.perf_counter()
            image = frame(rw)
            times.append(time.perf_counter() - t)
        return times, image

    out = {"version": vtkVersion.GetVTKVersion(), "import_s": t_import, "reader": kind,
           "threads": threads, "camera": view}

    # (a) ParaView's CPU way: resample to the finest grid, fixed-point ray caster.
    t0 = time.perf_counter()
    reader = _vtk_reader(kind, source, field)
    reader.Update()
    t_read = time.perf_counter() - t0
    data = reader.GetOutputDataObject(0)
    if data is None:
        raise SystemExit(f"VTK {kind}: nothing read from {source}")
    is_amr = isinstance(data, vtkOverlappingAMR)
    bounds = [0.0] * 6
    data.GetBounds(bounds)
    spacing = _vtk_finest_spacing(data)
    dims, sampling = vtk_finest_grid(bounds, spacing)
    out.update(bounds=bounds, finest_spacing=spacing, finest_dims=dims, amr=is_amr,
               levels=data.GetNumberOfLevels() if is_amr else None)
    a = out["resample"] = {"read_s": t_read, "dims": dims}
    if int(np.prod(dims)) > spec["max_voxels"]:
        a["error"] = f"finest grid {'x'.join(map(str, dims))} > --max-voxels {spec['max_voxels']:,}"
    else:
        from vtkmodules.vtkFiltersCore import vtkResampleToImage
        from vtkmodules.vtkRenderingVolume import vtkFixedPointVolumeRayCastMapper

        t = time.perf_counter()
        resample = vtkResampleToImage()
        resample.SetInputConnection(reader.GetOutputPort())
        resample.SetUseInputBounds(False)
        resample.SetSamplingBounds(*sampling)
        resample.SetSamplingDimensions(*dims)
        resample.Update()
        a["resample_s"] = time.perf_counter() - t
        image = resample.GetOutput()
        valid = image.GetPointData().GetArray("vtkValidPointMask")
        a["invalid_points"] = 0 if valid is None else int((vtk_to_numpy(valid) == 0).sum())
        step = min(spacing) / VTK_SAMPLES_PER_CELL
        mapper = vtkFixedPointVolumeRayCastMapper()
        mapper.SetInputData(image)
        mapper.SetScalarModeToUsePointFieldData()
        mapper.SelectScalarArray(field)
        mapper.SetNumberOfThreads(threads)
        mapper.SetAutoAdjustSampleDistances(False)
        mapper.SetLockSampleDistanceToInputSpacing(False)
        mapper.SetSampleDistance(step)
        mapper.SetInteractiveSampleDistance(step)
        mapper.SetImageSampleDistance(1.0)
        volume = vtkVolume()
        volume.SetMapper(mapper)
        volume.SetProperty(vtk_volume_property(tf, unit))
        t = time.perf_counter()
        rw, _ = window(volume)
        frame(rw)
        a["first_frame_s"] = time.perf_counter() - t
        a["first_image_s"] = time.perf_counter() - t0
        a["frame_s"], rgba = steady(rw)
        a["sample_distance"] = mapper.GetSampleDistance()
        a["mapper_threads"] = mapper.GetNumberOfThreads()
        out["gl_renderer"] = _gl_renderer(rw)
        np.save(spec["image_prefix"] + "-vtk.npy", rgba)
        del rw, mapper, volume, image, resample
    del reader, data

    # (b) vtkAMRVolumeMapper: the reader's AMR, resampled by the mapper itself.
    if not is_amr:
        out["amr_mapper"] = {"error": "not an AMR data set (vtkAMRVolumeMapper needs a "
                                      "vtkOverlappingAMR)"}
        return out
    from vtkmodules.vtkRenderingVolumeAMR import vtkAMRVolumeMapper

    b = out["amr_mapper"] = {}
    t0 = time.perf_counter()
    reader = _vtk_reader(kind, source, field)
    mapper = vtkAMRVolumeMapper()
    mapper.SetInputConnection(reader.GetOutputPort())
    mapper.SetScalarModeToUseCellFieldData()
    mapper.SelectScalarArray(field)
    volume = vtkVolume()
    volume.SetMapper(mapper)
    volume.SetProperty(vtk_volume_property(tf, unit))
    rw, ren = window(volume)
    with _StderrCapture() as log:
        frame(rw)
    b["first_image_s"] = time.perf_counter() - t0
    b["frame_s"], rgba = steady(rw)
    out.setdefault("gl_renderer", _gl_renderer(rw))
    b["samples_requested"] = list(mapper.GetNumberOfSamples())
    b["render_mode_requested"] = mapper.GetRequestedRenderMode()
    b["resampler"] = parse_amr_resampler_log(log.text)
    b.update(_amr_mapper_grid(reader, ren, mapper, field))
    np.save(spec["image_prefix"] + "-vtk-amr.npy", rgba)
    return out


def _gl_renderer(render_window) -> str:
    """The OpenGL renderer string of a render window that has rendered (e.g. llvmpipe)."""
    caps = render_window.ReportCapabilities() or ""
    return next((line.split(":", 1)[1].strip() for line in caps.splitlines()
                 if line.startswith("OpenGL renderer string")), "?")


def _amr_mapper_grid(reader, ren, mapper, field: str) -> dict:
    """The grid vtkAMRVolumeMapper resampled to, made again outside it the same way
    (vtkAMRVolumeMapper.cxx UpdateResamplerFrustrumMethod: a vtkAMRResampleFilter in
    demand-driven mode over the data's part of the view frustum, NumberOfSamples points,
    biased along the view direction), and which mode its smart mapper renders in."""
    from vtkmodules.vtkFiltersAMR import vtkAMRResampleFilter
    from vtkmodules.vtkRenderingVolumeAMR import vtkAMRVolumeMapper
    from vtkmodules.vtkRenderingVolumeOpenGL2 import vtkSmartVolumeMapper

    cam = ren.GetActiveCamera()
    region = [0.0] * 6
    bounds = [0.0] * 6
    reader.GetOutputDataObject(0).GetBounds(bounds)
    vtkAMRVolumeMapper.ComputeResamplerBoundsFrustumMethod(cam, ren, bounds, region)
    resampler = vtkAMRResampleFilter()
    resampler.SetInputConnection(reader.GetOutputPort())
    resampler.SetDemandDrivenMode(0)  # as in the mapper: its input carries no AMR meta-data
    resampler.SetNumberOfSamples(*mapper.GetNumberOfSamples())
    resampler.SetMin(region[0], region[2], region[4])
    resampler.SetMax(region[1], region[3], region[5])
    resampler.SetBiasVector(*cam.GetDirectionOfProjection())
    resampler.SetUseBiasVector(True)
    with _StderrCapture() as log:
        resampler.Update()
    grid = resampler.GetOutput().GetBlock(0)
    out = {"frustum_region": region, "replica_log": parse_amr_resampler_log(log.text)}
    if grid is None:
        return out
    out.update(grid_dims=list(grid.GetDimensions()), grid_spacing=list(grid.GetSpacing()),
               grid_origin=list(grid.GetOrigin()))
    smart = vtkSmartVolumeMapper()
    smart.SetInputData(grid)
    smart.SetScalarModeToUsePointFieldData()
    smart.SelectScalarArray(field)
    probe = ren.GetVolumes().GetLastProp()
    probe.SetMapper(smart)
    ren.GetRenderWindow().Render()
    used = smart.GetLastUsedRenderMode()
    out["render_mode"] = {smart.RayCastRenderMode: "ray cast (CPU)", smart.GPURenderMode: "GPU",
                          smart.OSPRayRenderMode: "OSPRay"}.get(used, str(used))
    probe.SetMapper(mapper)
    return out
