"""``penfree convert IN OUT``: between HDF5, NPZ, numbered mesh files and XDMF."""

import os

import click

from ..errors import InputError
from .info import FORMAT_NAMES
from .options import overwrite_option, usd_options


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
@usd_options
def command(input_path, output_path, out_format, in_format, deformed, overwrite, usd_prims, usd_obstacles):
    """Convert the sequence IN to OUT (written atomically; IN is never modified).

    \b
      penfree convert frames.h5 frames.xdmf          # + frames.xdmf.h5, for ParaView
      penfree convert 'out/A%08d.ply' frames.h5
      penfree convert frames.h5 meshes/ --format meshseq   # meshes/frame_0000.ply ...
      penfree convert deformed.h5 deformed.xdmf --deformed # the deformed states
      penfree convert deformed.h5 deformed.usda --deformed # recorded + deformed prims
      penfree convert sim.usd frames.h5 --prim /World/Cloth
    """
    from ..formats import (
        check_outputs, detect_format, input_files, output_files, output_paths, read_sequence, write_sequence,
    )

    out_format = out_format or detect_format(output_path, writing=True)
    if out_format != "meshseq" and os.path.isdir(output_path):  # only a mesh sequence is written into a directory
        raise InputError(f"output {output_path} is a directory; expected a file name for {out_format} "
                         f"(a directory of frames only with --format meshseq)")
    in_format = in_format or ("hdf5" if deformed else detect_format(input_path))
    inputs = input_files(input_path, in_format)  # mesh sequences: every frame; XDMF: every heavy-data file too
    if os.path.isdir(input_path):  # read whole: nothing may be written into it
        inputs.append(input_path)
    check_outputs(output_paths(output_path, out_format), inputs, overwrite)  # before reading anything
    if deformed and out_format == "usd":  # both the recorded frames and the deformed states
        from ..formats.result import read_result
        from ..formats.usd import write_usd_result

        result = read_result(input_path)
        write_usd_result(output_path, result, overwrite=overwrite)
        click.echo(f"wrote {output_path} (usd): {result.sequence.n_frames} recorded frames and "
                   f"{len(result.steps['frame'])} deformed states, {result.sequence.n_vertices} vertices")
        return
    if deformed:
        from ..formats.result import deformed_sequence, read_result

        seq = deformed_sequence(read_result(input_path))
    else:
        seq = read_sequence(input_path, format=in_format, prims=usd_prims, obstacles=usd_obstacles)
    # now that the frame count is known: every file the writer will create, replace or remove
    check_outputs(output_files(output_path, out_format, seq.n_frames), inputs, overwrite)
    write_sequence(output_path, seq, format=out_format, overwrite=overwrite)
    click.echo(f"wrote {output_path} ({out_format}): {seq.n_frames} frames, {seq.n_vertices} vertices, {seq.kind}")
