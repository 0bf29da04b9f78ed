"""The benchmarks: each `bench_*` module measures one part and replaces its
section of docs/benchmarks.md (`python -m benchmarks.bench_render --write-docs`;
`make bench` runs them all); `benchdoc` is their shared harness, `make_big` and
`amrex_plotfile` write the generated inputs, `gallery` makes the images of
docs/gallery.md. Not part of the installed package: run from a checkout, where
the editable install puts the checkout on the path."""
