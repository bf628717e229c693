"""`dockhil sweep CAMPAIGN.yaml --out RESULTS.parquet`: run a scene over a campaign of
launch arguments; `dockhil sweep plot RESULTS.parquet --png FILE`: what the campaign found."""

from __future__ import annotations

import argparse

from dockhil import log
from dockhil.commands.stop_signal import StopOnSignal
from dockhil.errors import DockhilError
from dockhil.log import Log


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.description = (
        "Run a scene many times (composed, sim time) over the launch arguments a campaign\n"
        "file gives: fixed args, a grid, random draws, samples. One Parquet row per run:\n"
        "its args, status (ok / invalid / failed), error, run_time_s and its summary.\n"
        "A rerun with the same --out skips the runs already done."
    )
    p.epilog = (
        "campaign file:\n"
        "  scene: stability.yaml          # shipped scene by name, or a path\n"
        "  args: {m: 750, delay: 0.016}   # fixed launch args\n"
        "  duration: 40                   # simulated seconds per run, at most 1e6 (default: the scene's)\n"
        "  grid:                          # the product of all axes\n"
        "    b: [20, 60]                  # values, or {values: [...]}\n"
        "    k: {range: [500, 6000], num: 12}   # add log: true for a geometric range\n"
        "  random:                        # per run: uniform [a, b], normal [mean, std], loguniform [a, b]\n"
        "    thrust: {uniform: [8, 12]}\n"
        "  samples: 1                     # runs per grid point; at most 100,000 runs in all\n"
        "  seed: 0                        # 0 to 2**32 - 1\n"
        "  outputs: [peak_force_N, growth_rate_per_s, stable]   # summary columns to keep (default all)\n"
        "  bags: false                    # true: one MCAP bag per run in RESULTS.parquet.bags/\n"
        "\n"
        "Before anything runs, each argument's values (each grid axis's ends, the least and\n"
        "greatest draw) go through the scene's own checks, as in 'dockhil launch'.\n"
        "\n"
        "exit status: 0 every run ok or invalid (refused by the scene), 1 some run failed\n"
        "(its row says why) or a result could not be written (a full disk: rerun to resume),\n"
        "2 a bad campaign or results file (nothing ran), 128+N stopped by signal N (130: Ctrl-C;\n"
        "rerun to resume).\n"
        "\n"
        "examples:\n"
        "  dockhil sweep launch/campaigns/fig7.yaml --out fig7.parquet\n"
        "  dockhil sweep launch/campaigns/fig7.yaml --out fig7.parquet --dask local --workers 2\n"
        "  dockhil sweep plot fig7.parquet --png fig7-sim.png"
    )
    p.add_argument("campaign", metavar="CAMPAIGN.yaml", help="the campaign file (or 'plot' to plot results)")
    p.add_argument("results", nargs="?", metavar="RESULTS.parquet", help="with 'plot': the results to draw")
    p.add_argument("--out", metavar="RESULTS.parquet", help="where the rows go (a rerun resumes it)")
    p.add_argument(
        "--workers",
        type=int,
        metavar="N",
        help="worker processes (default: the CPU count; with --dask ADDRESS: the cluster's)",
    )
    p.add_argument(
        "--dask",
        metavar="ADDRESS|local",
        help="run on a Dask distributed scheduler (tcp://host:8786), or 'local' for a LocalCluster",
    )
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.add_argument("--png", metavar="FILE", help="with 'plot': where to write the figure")
    log.add_arguments(p)


def run(args: argparse.Namespace) -> int:
    if args.campaign == "plot":
        return _plot(args)
    if args.results is not None:
        raise DockhilError(f"unexpected {args.results!r}: give the results file with --out")
    if not args.out:
        raise DockhilError(f"{args.campaign}: give --out RESULTS.parquet (where the rows go)")
    if args.workers is not None and args.workers < 1:
        raise DockhilError(f"--workers must be >= 1, got {args.workers}")
    import os

    folder = os.path.dirname(os.path.abspath(args.out))
    if not os.path.isdir(folder) or not os.access(folder, os.W_OK):
        raise DockhilError(f"--out {args.out}: folder {folder} does not exist or is not writable")
    if os.path.isdir(args.out):
        raise DockhilError(
            f"--out {args.out}: is a folder; give a file name, e.g. {os.path.join(args.out, 'results.parquet')}"
        )
    from dockhil.analysis import sweep

    campaign = sweep.load_campaign(args.campaign)
    sweep.check_outputs(campaign)
    say = Log("dockhil sweep:")
    signals = StopOnSignal()
    try:
        executor: sweep.DaskExecutor | sweep.LocalPool
        if args.dask:
            executor = sweep.DaskExecutor(args.dask, args.workers)
        else:
            executor = sweep.LocalPool(args.workers or sweep.usable_cpus())
        try:
            out = sweep.sweep(campaign, args.out, executor, progress=not args.quiet)
        finally:
            executor.close()
    except KeyboardInterrupt:
        say.info(f"{signals.what}; the finished runs are in {args.out}: rerun the same command to resume")
        return 128 + signals.number
    except sweep.WriteError as exc:
        say.error(
            f"{exc}; the rows written before stay: make room on that disk (or make it writable) and rerun "
            f"the same command to resume"
        )
        return 1
    finally:
        signals.restore()
    print(sweep.format_report(out, args.out, executor.name), flush=True)
    return 1 if out["failed"] else 0


def _plot(args: argparse.Namespace) -> int:
    if not args.results:
        raise DockhilError("sweep plot: give the results file: dockhil sweep plot RESULTS.parquet --png FILE")
    if not args.png:
        raise DockhilError("sweep plot: give --png FILE (where to write the figure)")
    from dockhil.analysis.sweep.plot import plot_results

    for line in plot_results(args.results, args.png):
        print(line)
    Log("dockhil sweep plot:").info(f"figure written to {args.png}")
    return 0
