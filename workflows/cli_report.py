"""Sub-command ``report``: the reproduction report page from the outputs that exist.

Arguments are checked before any work; bad input raises :class:`deapull.errors.InputError`
(exit 2). ``--missing-steps`` prints the make arguments of the steps whose outputs are absent, one a line
(``make report FULL=1`` runs them). ``--check`` opens the page in headless chromium.
"""
from __future__ import annotations

from deapull.errors import InputError


def cmd_report(args) -> int:
    # here, not at the top: the CLI imports every sub-command's module, and the report package
    # imports matplotlib
    from deapull.workflows import report
    from deapull.workflows.report.check import check_page, find_browser
    inputs = report.Inputs.under(args.outputs, args.data, fields=args.fields, fidelity=args.fidelity_dir,
                                 stability=args.stability_dir, experiments=args.experiments_dir,
                                 control=args.control_dir, bench_control=args.bench_control_dir)
    if args.missing_steps:
        for name in report.missing_steps(inputs):
            print(report.STEP[name].make.removeprefix("make "))
        return 0
    if args.check == "yes":
        if find_browser(args.browser) is None:
            raise InputError("--check yes: no browser (apt-get install chromium; pip install playwright)")
    summary = report.build(args.out, inputs, frames=args.frames, progress=not args.no_progress)
    print(f"wrote {summary['index']} and {summary['markdown']} ({len(summary['images'])} images, "
          f"{len(summary['claims'])} paper numbers beside ours)")
    for name in summary["missing"]:
        step = report.STEP[name]
        print(f"missing: {step.what}: {step.hint(inputs)[0]}")
    if args.check == "no":
        return 0
    if find_browser(args.browser) is None:
        print("browser check skipped: no chromium/playwright (apt-get install chromium; pip install playwright)")
        return 0
    result = check_page(summary["index"], args.browser)
    print(result.summary())
    return 0 if result.ok else 1


def register(sub) -> None:
    """Add ``report`` to the ``deapull`` sub-parsers."""
    p = sub.add_parser("report", help="the reproduction report: every result on one page beside the paper's "
                                      "(index.html + report.md)")
    p.add_argument("--out", default="out/report", help="output folder (default out/report)")
    p.add_argument("--data", default="data", help="folder of the sweep datasets C1..C8.nc (default data)")
    p.add_argument("--outputs", default="out", help="folder the studies wrote into (default out): "
                                                   "fidelity/, stability/, experiments/, control/, ...")
    p.add_argument("--fields", default=None, help="field file of the pictures (default "
                                                  "OUTPUTS/report_fields/C3_fields.xdmf)")
    p.add_argument("--fidelity-dir", default=None, help="default OUTPUTS/fidelity")
    p.add_argument("--stability-dir", default=None, help="default OUTPUTS/stability")
    p.add_argument("--experiments-dir", default=None, help="default OUTPUTS/experiments")
    p.add_argument("--control-dir", default=None, help="default OUTPUTS/control")
    p.add_argument("--bench-control-dir", default=None, help="default OUTPUTS/bench_control")
    p.add_argument("--frames", type=int, default=30, help="frames of the animation (default 30)")
    p.add_argument("--check", default="auto", choices=("auto", "yes", "no"),
                   help="open the page in headless chromium: auto (when installed, default), yes, no")
    p.add_argument("--browser", default=None, help="chromium executable (default /usr/bin/chromium)")
    p.add_argument("--missing-steps", action="store_true",
                   help="only print the make targets whose outputs are missing, one a line")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_report)
