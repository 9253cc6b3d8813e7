"""``penfree convert IN OUT``: between HDF5, NPZ, numbered mesh files and XDMF."""

import click

from .info import FORMAT_NAMES
from .options import overwrite_option


@click.command("convert")
@click.argument("input_path", metavar="IN")
@click.argument("output_path", metavar="OUT")
@click.option("--format", "out_format", type=click.Choice(FORMAT_NAMES), default=None,
              help="Output format (default: from OUT's name).")
@click.option("--from-format", "in_format", type=click.Choice(FORMAT_NAMES), default=None,
              help="Input format (default: from IN's name and content).")
@click.option("--deformed", is_flag=True,
              help="IN is a `penfree deform` result: write its deformed states (one frame per step).")
@overwrite_option
def command(input_path, output_path, out_format, in_format, deformed, overwrite):
    """Convert the sequence IN to OUT (written atomically; IN is never modified).

    \b
      penfree convert frames.h5 frames.xdmf          # + frames.xdmf.h5, for ParaView
      penfree convert 'out/A%08d.ply' frames.h5
      penfree convert frames.h5 meshes/ --format meshseq   # meshes/frame_0000.ply ...
      penfree convert deformed.h5 deformed.xdmf --deformed # the deformed states
    """
    from ..formats import (
        check_outputs, detect_format, input_files, output_files, output_paths, read_sequence, write_sequence,
    )

    out_format = out_format or detect_format(output_path, writing=True)
    in_format = in_format or ("hdf5" if deformed else detect_format(input_path))
    inputs = input_files(input_path, in_format)  # mesh sequences: every frame; XDMF: its heavy-data file too
    check_outputs(output_paths(output_path, out_format), inputs, overwrite)  # before reading anything
    if deformed:
        from ..formats.result import deformed_sequence, read_result

        seq = deformed_sequence(read_result(input_path))
    else:
        seq = read_sequence(input_path, format=in_format)
    # now that the frame count is known: every file the writer will create, replace or remove
    check_outputs(output_files(output_path, out_format, seq.n_frames), inputs, overwrite)
    write_sequence(output_path, seq, format=out_format, overwrite=overwrite)
    click.echo(f"wrote {output_path} ({out_format}): {seq.n_frames} frames, {seq.n_vertices} vertices, {seq.kind}")
