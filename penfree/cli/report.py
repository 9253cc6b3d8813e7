"""``penfree report FILE... -o DIR``: Markdown + JSON (+ PNG) report and CI checks."""

import os

import click
from click.core import ParameterSource

from ..constants import DEFAULT_CD_SHARE, DEFAULT_FRAME_MS, DEFAULT_GAMMA
from ..core.parallel import set_threads
from ..errors import InputError
from ..sequence import SCALE_MAX
from .options import (
    FiniteFloat, Progress, echo_json, frames_option, json_option, overwrite_option, parse_frames, scaleout_options,
    threads_option,
)


#: Options that only the real-client replay reads: (parameter name, option).
CLIENT_ONLY = (("truncation", "--truncation"), ("radius_rule", "--radius"), ("dhat", "--dhat"), ("every", "--every"))


@click.command("report")
@click.argument("files", nargs=-1, required=True, metavar="FILE...", type=click.Path(dir_okay=True))
@click.option("-o", "--output", "outdir", required=True, type=click.Path(file_okay=False),
              help="Report directory to write (report.md, report.json, *.png).")
@overwrite_option
@click.option("--cd-share", type=FiniteFloat(0.0, 1.0), default=DEFAULT_CD_SHARE, show_default=True,
              help="Projected: fraction f of the frame time spent in collision detection.")
@click.option("--frame-ms", type=FiniteFloat(min=0.0, min_open=True), default=DEFAULT_FRAME_MS,
              show_default=True, help="Projected: baseline frame time T_frame in milliseconds.")
@click.option("--replay", is_flag=True, help="Also estimate CD passes by replay (one bound query per pass).")
@click.option("--client", type=click.Choice(["ipctk"]), default=None,
              help="Replay every step through the real OGC client (ipctk.ogc.TrustRegion; pip install 'penfree[ogc]').")
@click.option("--truncation", type=click.Choice(["isotropic", "planar", "both"]), default="both", show_default=True,
              help="With --client: the client's step filter (planar = Divide and Truncate).")
@click.option("--radius", "radius_rule", type=click.Choice(["own", "step", "both"]), default="both",
              show_default=True, help="With --client: step = keep the radius computed at x; own = ipctk's warm start "
              "recomputes it from x_def.")
@click.option("--dhat", type=FiniteFloat(min=0.0, min_open=True, max=SCALE_MAX), default=None,
              help="With --client: contact offset [default: the contact radius, else the thickness].")
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True,
              help="With --client: replay every k-th step.")
@click.option("--no-ladder", is_flag=True, help="Skip the model ladder (re-fits every step with every model).")
@click.option("--no-plots", is_flag=True, help="Do not write PNG plots.")
@frames_option
@threads_option
@json_option
@click.option("--fail-if-uncertified", is_flag=True,
              help="Check: every step's map is certified and its stored deformed state is that map's image.")
@click.option("--min-speedup", type=FiniteFloat(), default=None, metavar="X",
              help="Check: projected speedup (K_1pct rule) >= X (a finite number).")
@click.option("--min-hit-rate-gain", type=FiniteFloat(), default=None, metavar="POINTS",
              help="Check: hit rate vs the next frame gains >= POINTS percentage points (deformed - baseline; "
              "a finite number, negative allows a loss).")
@click.option("--baseline", "baseline_path", type=click.Path(), default=None, metavar="REPORT.json",
              help="Check: compare with a stored report.json (needs --max-regression).")
@click.option("--max-regression", type=FiniteFloat(min=0.0), default=None, metavar="PCT",
              help="Check: K_1pct, projected speedup and hit rate regress by at most PCT percent vs --baseline.")
@scaleout_options
def command(files, outdir, overwrite, cd_share, frame_ms, replay, client, truncation, radius_rule, dhat, every,
            no_ladder, no_plots, frames, threads, as_json,
            fail_if_uncertified, min_speedup, min_hit_rate_gain, baseline_path, max_regression, workers, scheduler):
    """Report trust-region statistics of `penfree deform` outputs, with optional CI checks.

    Exit status: 0 all checks passed, 1 a check failed (the report is still written),
    2 unusable input (a baseline that cannot be compared included). Frame times and
    speedups are projected, never measured. With any check the statistics are computed
    from the positions and deformed states, never read from the file's stats/ group.

    \b
      penfree report deformed.h5 -o report/
      penfree report deformed.h5 -o report/ --min-speedup 1.1 --fail-if-uncertified
      penfree report deformed.h5 -o new/ --baseline old/report.json --max-regression 5
    """
    from ..report.build import (
        check_report_dir, load_report_json, make_file_report, open_result, open_tables, select_steps, stored_stats,
        write_report,
    )
    from ..report.baseline import baseline_warnings, match_baseline
    from ..report.checks import run_checks

    if (baseline_path is None) != (max_regression is None):
        raise InputError("--baseline and --max-regression go together; give both or neither")
    ctx = click.get_current_context()
    if not client:
        for name, flag in CLIENT_ONLY:
            if ctx.get_parameter_source(name) in (ParameterSource.COMMANDLINE, ParameterSource.ENVIRONMENT):
                raise InputError(f"{flag} applies only to the real-client replay; give --client ipctk or drop {flag}")
    ci = fail_if_uncertified or min_speedup is not None or min_hit_rate_gain is not None or baseline_path is not None
    from ..scaleout import expand_inputs, is_long

    # Several plain files run here as before; directories and globs expand; Dask on request.
    files = expand_inputs(files, missing_ok=True)
    scale = workers is not None or scheduler is not None
    check_report_dir(outdir, overwrite, inputs=list(files) + ([baseline_path] if baseline_path else []))
    frame_slice = parse_frames(frames)
    set_threads(threads)
    baseline = load_report_json(baseline_path) if baseline_path else None
    if baseline is not None:
        match_baseline(files, baseline, baseline_path)  # an ambiguous match is exit 2 before any work
    client_opts = None
    if client:
        from ..core.trust.client import load_ipctk

        load_ipctk()  # exit 2 with the install hint before any work
        client_opts = {"client": client, "truncation": truncation, "radius": radius_rule, "dhat": dhat,
                       "every": every}
    if scale:  # after the checks that can end the command, before the inputs are read
        from . import scaleout

        scaleout.start_workers(scheduler)
    # All inputs checked first; a long recording by its per-step tables (its frames are read
    # a range at a time, as verify reads them).
    long = [is_long(path, "result") for path in files]
    results = []
    for path, lg in zip(files, long):
        res, n_frames = open_tables(path) if lg else (open_result(path), None)
        results.append(select_steps(res, frame_slice, n_frames=n_frames))

    reports = []
    # A stored stats/ group is a cache for reading; a CI check never trusts it.
    opts = dict(frames=frame_slice, cd_share=cd_share, frame_ms=frame_ms, replay=replay, ladder=not no_ladder,
                use_stored_stats=not ci, verify_paths=fail_if_uncertified, client=client_opts)
    if scale:  # several inputs / Dask: a task per file or frame range (penfree.scaleout)
        files, reports = scaleout.report_entries(files, opts, workers=workers, scheduler=scheduler, threads=threads)
    for path, res, lg in zip(files, results if not scale else (), long):
        work = res.n_steps * ((ci or stored_stats(res, replay) is None) + (not no_ladder)) + (
            -(-res.n_steps // every) if client else 0)
        with Progress(work, f"report {os.path.basename(path)}") as bar:
            if lg:  # frames beyond MAX_TASK_BYTES: its frame ranges one after another, as a worker would
                from ..scaleout import report_many

                _, entries = report_many([path], options=opts, threads=threads,
                                         in_process=True, step_progress=bar)
                reports.extend(entries)
                continue
            reports.append(make_file_report(path, res, cd_share=cd_share, frame_ms=frame_ms, replay=replay,
                                            ladder=not no_ladder, progress=bar, client=client_opts,
                                            use_stored_stats=not ci, verify_paths=fail_if_uncertified))
    checks = run_checks(reports, fail_if_uncertified=fail_if_uncertified, min_speedup=min_speedup,
                        min_hit_rate_gain=min_hit_rate_gain, baseline=baseline, max_regression=max_regression,
                        baseline_name=baseline_path)
    options = {"cd_share": cd_share, "frame_ms": frame_ms, "replay": replay, "ladder": not no_ladder,
               "frames": frames, "gamma": DEFAULT_GAMMA}
    if client:
        options.update(client_opts)
    doc = write_report(outdir, reports, overwrite, options=options, checks=checks, plots=not no_plots)
    if baseline is not None:  # after the output is written: an exit 2 prints one line only
        for line in baseline_warnings(baseline, baseline_path, options, reports, match_baseline(
                [r["file"] for r in reports], baseline, baseline_path)):
            click.echo(f"penfree: {line}", err=True)
    if as_json:
        echo_json(doc)
    else:
        _print_summary(doc, outdir)
    if not doc["all_checks_passed"]:
        click.get_current_context().exit(1)


def _fmt(v, spec):
    return "n/a" if v is None else format(v, spec)


def _print_summary(doc, outdir):
    from ..report.checks import entry_labels

    click.echo(f"penfree report -> {outdir}/report.md, report.json")
    for rep, label in zip(doc["files"], entry_labels(doc["files"])):
        sm = rep["summary"]
        b, d, p = sm["baseline"], sm["deformed"], sm["projected"]["k_1pct"]
        hb, hd = (None if v is None else 100 * v for v in (b["hit_rate_next"], d["hit_rate_next"]))
        click.echo(f"  {label}: {sm['n_steps']} steps; hit rate vs next "
                   f"{_fmt(hb, '.1f')}% -> {_fmt(hd, '.1f')}%; "
                   f"K_1pct {_fmt(b['k_1pct_next'], '.2f')} -> {_fmt(d['k_1pct_next'], '.2f')}; "
                   f"projected speedup x{_fmt(p['speedup'], '.3f')} (f={sm['projected']['cd_share']:g}, "
                   f"T_frame={sm['projected']['frame_ms']:g} ms); "
                   f"certified: {'all' if rep['certificate']['all_certified'] else 'NOT ALL'}")
        if rep.get("client"):
            from ..report.client import client_headline

            click.echo(f"  {label}: {client_headline(rep['client'])}")
        if rep.get("stats_note"):
            click.echo(f"  note [{label}]: {rep['stats_note']}")
    pl = doc["plots"]
    if pl["status"] != "written":
        click.echo(f"  plots {pl['status']}: {pl['reason']}")
    for c in doc["checks"]:
        click.echo(f"  check {c['name']} [{c['file']}]: {'pass' if c['passed'] else 'FAIL'} - {c['message']}")
    if doc["checks"] and not doc["all_checks_passed"]:
        failed = [c["name"] for c in doc["checks"] if not c["passed"]]
        click.echo(f"penfree report: {len(failed)} check(s) failed: {', '.join(failed)}", err=True)
