"""``penfree info FILE``: what a sequence or deform result holds."""

import click

from .options import echo_json, json_option

FORMAT_NAMES = ("hdf5", "npz", "meshseq", "xdmf")


def _fmt(value):
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    if value is None:
        return "-"
    return str(value)


def _lines(d: dict) -> list:
    mo = d["motion"]
    rows = [
        ("file", d["origin"]),
        ("kind", d["kind"]),
        ("frames", d["frames"]),
        ("vertices", d["vertices"]),
        ("edges", d["n_edges"]),
        ("faces", d["n_faces"]),
        ("dtype", d["dtype"]),
        ("bbox min", d["bbox"]["min"]),
        ("bbox max", d["bbox"]["max"]),
        ("bbox extent", d["bbox"]["extent"]),
        ("median edge length", d["edge_length_median"]),
        ("step motion max", "min {} / median {} / max {}".format(*map(_fmt, mo["max"].values()))),
        ("step motion rms", "min {} / median {} / max {}".format(*map(_fmt, mo["rms"].values()))),
        ("thickness", d["thickness"]),
        ("contact radius", d["contact_radius"]),
        ("dt", d["dt"]),
        ("source", d["source"]),
        ("weights", "yes" if d["weights"] else "no"),
        ("components", d["components"]),
    ]
    for ob in d["obstacles"]:
        if ob.get("half_space"):
            rows.append((f"obstacle {ob['name']}", f"half-space normal {_fmt(ob['normal'])}, offset {_fmt(ob['offset'])}"))
            continue
        topo = f"{ob['faces']} faces" if ob["faces"] else f"{ob['edges']} edges"
        rows.append((f"obstacle {ob['name']}", f"{ob['vertices']} vertices, {topo}, {'static' if ob['static'] else 'moving'}"))
    res = d.get("result")
    if res is not None:
        counts = lambda c: ", ".join(f"{k} x{v}" for k, v in c.items()) or "-"  # noqa: E731
        rows += [
            ("steps", res["steps"]),
            ("step frames", "-" if res["frames"] is None else f"{res['frames'][0]}..{res['frames'][1]}"),
            ("models", counts(res["models"])),
            ("projections", counts(res["projections"])),
            ("min certificate margin", res["min_certificate_margin"]),
            ("groups", ", ".join(res["groups"]) or "-"),
        ]
    width = max(len(k) for k, _ in rows) + 1
    return [f"{k + ':':<{width}} {_fmt(v)}" for k, v in rows]


@click.command("info")
@click.argument("path", metavar="FILE")
@click.option("--format", "in_format", type=click.Choice(FORMAT_NAMES), default=None,
              help="Input format (default: from the name and content).")
@json_option
def command(path, in_format, as_json):
    """Describe FILE: frames, vertices, topology, bounding box, per-step motion.

    FILE is a sequence in any readable format (a mesh sequence may be given as
    a pattern such as out/A%08d.ply) or a deform result, for which the steps,
    models, projections and the smallest certificate margin are shown too.
    """
    from ..core.describe import describe, describe_result
    from ..formats import read_sequence
    from ..formats.result import is_result_file, read_result

    if in_format in (None, "hdf5") and is_result_file(path):
        d = describe_result(read_result(path))
    else:
        d = describe(read_sequence(path, format=in_format))
    if as_json:
        echo_json(d)
        return
    for line in _lines(d):
        click.echo(line)
