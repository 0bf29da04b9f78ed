"""The peer comparison of benchmarks/bench_peers.py: exabricks against yt, VTK,
per-sample cell location and the uniform-grid ceiling, on the same datasets with
the same field, camera, transfer function and image size.

- bench_peers (benchmarks/bench_peers.py): the entry point and driver; it runs each
  peer's worker in a subprocess of its own, dataset by dataset, and writes the report.
- common: the datasets, the shared settings (sampling rates, opacity, seed, opacity
  unit) and the shared view (camera and transfer function), and the timing helpers.
- ours: the exabricks side, the offline stages (the prepare worker), then our two
  reconstructions (regions and cell location) and the uniform-grid ceiling.
- yt: how yt is matched to our camera and transfer function, and its worker.
- vtk: how VTK is matched (ParaView's CPU way), and its worker.
- report: the tables, the ratios against the targets, the verdicts and the markdown.

yt and VTK are optional (the `peers` extra): they are imported only inside the
workers and the functions that need them, so every module here imports without them.
"""
