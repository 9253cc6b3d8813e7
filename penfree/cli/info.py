"""``penfree info FILE``: what a sequence or deform result holds."""

import click

from .options import echo_json, json_option, usd_options

FORMAT_NAMES = ("hdf5", "npz", "meshseq", "xdmf", "usd")


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
        solid = f"; exact solid: {ob['solid']} (checked instead of the mesh)" if ob.get("solid") else ""
        rows.append((f"obstacle {ob['name']}",
                     f"{ob['vertices']} vertices, {topo}, {'static' if ob['static'] else 'moving'}{solid}"))
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
@usd_options
@json_option
def command(path, in_format, usd_prims, usd_obstacles, as_json):
    """Describe FILE: frames, vertices, topology, bounding box, per-step motion.

    FILE is a sequence in any readable format (a mesh sequence may be given as
    a pattern such as out/A%08d.ply) or a deform result, for which the steps,
    models, projections and the smallest certificate margin are shown too.
    """
    from ..core.describe import describe, describe_result
    from ..formats import detect_format, read_sequence
    from ..formats.result import is_result_file, read_result

    if in_format in (None, "hdf5") and is_result_file(path):
        d = describe_result(read_result(path))
    else:
        d = describe(read_sequence(path, format=in_format, prims=usd_prims, obstacles=usd_obstacles))
        if (in_format or detect_format(path)) == "usd":
            from ..formats.usd import describe_stage

            d["usd"] = describe_stage(path, usd_prims, usd_obstacles)
    if as_json:
        echo_json(d)
        return
    for line in _lines(d) + (_usd_lines(d["usd"]) if "usd" in d else []):
        click.echo(line)


def _usd_lines(u: dict) -> list:
    """The USD stage: every geometric prim and its role, time codes, units."""
    tc = u["time_codes"]
    mpu = f"{u['meters_per_unit']:g}" + ("" if u["meters_per_unit_authored"] else " (not authored: USD fallback)")
    lines = [
        f"usd time codes:   {tc['first']:g}..{tc['last']:g} ({tc['count']} frames; stage range "
        f"{'-' if u['stage_start_end'] is None else '{:g}..{:g}'.format(*u['stage_start_end'])})",
        f"usd units:        metersPerUnit {mpu} (positions read in metres), upAxis {u['up_axis']}, "
        f"timeCodesPerSecond {u['time_codes_per_second']:g}, dt {_fmt(u['dt'])}",
    ]
    for p in u["prims"]:
        lines.append(f"usd prim {p['path']} ({p['type']}): {p['role']} - {p['detail']}")
    return lines
