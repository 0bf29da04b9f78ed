"""`exabricks movie 'frames/*.png' -o movie.mp4`: rendered frames into a video."""

from __future__ import annotations

import glob
import os

import click

from ..util.errors import ExabricksError
from .options import fps_option, numbers, output_option


def expand_frames(arguments) -> list[str]:
    """Every FRAMES argument as file names: an existing file as it is, a glob pattern
    (`*`, `?`, `[...]`, `**`) as the files it matches; then in natural order."""
    from ..stages.movie import natural_sorted

    names = []
    for arg in arguments:
        if os.path.lexists(arg):
            if os.path.isdir(arg):
                raise ExabricksError(f"{arg}: is a directory, not a frame (quote a pattern "
                                     "such as 'frames/*.png')")
            names.append(arg)
        elif glob.has_magic(arg):
            matched = [m for m in glob.glob(arg, recursive=True) if not os.path.isdir(m)]
            if not matched:
                raise ExabricksError(f"{arg}: no frames match")
            names += matched
        else:
            raise ExabricksError(f"{arg}: no such file")
    return natural_sorted(names)


@click.command()
@click.argument("frames", nargs=-1, required=True, metavar="FRAMES...")
@output_option
@fps_option(30.0)
@click.option("--crf", type=click.IntRange(0, 51), default=None, metavar="N",
              help="MP4 quality as the encoder's constant rate factor: 0 (best, largest) "
              "to 51 (worst); default 18, hard to tell from the frames.")
@click.option("--codec", type=click.Choice(["h264", "h265"]), default=None,
              help="MP4 video codec (default h264: plays everywhere; h265: about half "
              "the size, fewer players).")
@click.option("--background", callback=numbers((3,)), default="0,0,0", show_default=True,
              metavar="R,G,B", help="Colour in [0, 1] behind transparent pixels.")
def movie(frames, output, fps, crf, codec, background):
    """Assemble images (.png or .exr, all of one size) into a movie: .mp4 (H.264,
    yuv420p) or .gif, chosen by the suffix of OUTPUT.

    FRAMES are files or quoted glob patterns ('frames/*.png'), taken in natural
    order of their names (frame_2 before frame_10). Transparent pixels are
    composited over --background, then colours are rounded to 8 bits as the PNG
    writer does. yuv420p needs an even width and height: an odd one is padded by
    one column or row of the background colour, not rescaled.
    """
    from ..stages.movie import make_movie, movie_format

    if movie_format(output) == ".gif" and (crf is not None or codec is not None):
        raise click.UsageError("--crf and --codec apply to .mp4 output")
    make_movie(expand_frames(frames), output, fps=fps, crf=crf, codec=codec, background=background)
