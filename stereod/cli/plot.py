"""``stereod plot``: draw a run's trajectories, speed and heading against the truth."""

from __future__ import annotations

import argparse

from stereod.cli.common import path_arg
from stereod.files.output_file import check_outputs


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "plot",
        help="draw a run's trajectories, speed and heading (needs the plot extra)",
        description="Draws the objects messages of a run (written by `stereod replay "
        "--jsonl`): the top view of every track (X-Z, m) beside the true trajectories, and "
        "speed (m/s) and heading (deg) against time with the filter's 1-sigma band beside "
        "the paper's eq. 21 estimate. Needs matplotlib: pip install 'stereod[plot]'.",
    )
    p.add_argument("run", type=path_arg, metavar="RUN.jsonl", help="objects messages, one per line")
    p.add_argument(
        "--truth",
        type=path_arg,
        metavar="FILE",
        help="true trajectories: a CSV with header object,t_ns,x_m,y_m,z_m (the world "
        "renderer's truth.csv) or a synthetic recording's truth.json",
    )
    p.add_argument(
        "-o",
        "--out",
        type=path_arg,
        required=True,
        metavar="FIG.png",
        help="figure to write; its suffix gives the format (png, pdf, svg, ...; .png added "
        "when it has none)",
    )
    p.add_argument(
        "--title", default="", help="a title above the figure, drawn as written (no $math$)"
    )
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    from stereod.view.plot import (
        check_overlap,
        figure_target,
        plot_run,
        read_run,
        read_truth,
        summary,
    )

    check_outputs({"--out": figure_target(a.out)[0]}, [a.run, a.truth])
    data = read_run(a.run)
    truth = read_truth(a.truth, data.t0_ns) if a.truth is not None else []
    if a.truth is not None:
        check_overlap(data, truth, a.truth)
    written = plot_run(data, truth, a.out, title=a.title)
    print(summary(data))
    print(f"wrote {written}")
    return 0
