"""`exabricks join PIECES... -o OUT`: one bricks, regions or BVH file from the
pieces that `brick`, `regions` or `bvh --piece K/N` built (exabricks.formats.pieces)."""

from __future__ import annotations

import click

from .. import schema
from ..util.errors import ExabricksError
from ..util.output import check_output
from .options import output_option

KINDS = ("bricks", "regions", "bvh")


@click.command()
@click.argument("piece_paths", metavar="PIECES...", nargs=-1, required=True,
                type=click.Path(exists=True, dir_okay=False))
@output_option
def join(piece_paths, output):
    """Put the N pieces of a build (`brick`, `regions` or `bvh` with --piece K/N)
    together, in any order given: the result equals the build of one process."""
    from ..builders import join as stage

    check_output(output, list(piece_paths))
    kind, _, _ = schema.peek(piece_paths[0])
    if kind not in KINDS:
        raise ExabricksError(f"{piece_paths[0]}: holds {kind}; join puts together pieces of "
                             f"{', '.join(KINDS)}")
    parts = [(p, schema.load(p, kind, mapped=True, checked=True, digest=True))
             for p in piece_paths]
    joined = {"bricks": stage.join_bricks, "regions": stage.join_regions,
              "bvh": stage.join_bvh}[kind](parts)
    first = parts[0][1].meta
    extra = {}
    if kind == "regions":
        extra["consistency"] = {**first.get("consistency", {}), "n_regions": joined.n_regions}
    elif kind == "bvh":
        extra["consistency"] = first.get("consistency", {})
    meta = schema.make_meta(
        inputs=list(piece_paths),
        parameters=first.get("parameters", {}),
        statistics=joined.meta["statistics"],
        # What the pieces were built from: their own inputs, and the content they record.
        source_inputs=first.get("inputs", []),
        built_from=first.get("built_from"),
        **extra,
    )
    schema.save(output, joined.replace(meta=meta), inputs=list(piece_paths))
