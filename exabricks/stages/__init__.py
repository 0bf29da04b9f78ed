"""The stages, one module per command, each the library function its command calls:
`ingest`, `brick`, `regions`, `bvh`, `join`, `coarsen` build the structures
(arrays in, arrays out; their shares by `--piece K/N` are exabricks.formats.pieces);
`render` runs a render job and `probe` samples the fields (exabricks.engine is
their OpenCL side); `compare` and `movie` work on images. docs/contributing.md
has the map of the rest of the package."""
