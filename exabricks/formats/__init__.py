"""The `.npz` file kinds, one concept a module (exabricks.schema is their public face):

- `kinds`: the kinds (Cells, Bricks, Regions, Bvh) and their summaries;
- `checks`: `validate` and the checks of the .npy headers before reading;
- `provenance`: input hashes, `make_meta`, content digests and the build chain;
- `memory`: pages of mapped arrays handed back, work in steps (`rows`), memory limits;
- `npz`: the .npz reader (`NpzArchive`) and the header entries;
- `files`: `save`, `load` and `peek`.
"""
