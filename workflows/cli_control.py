"""Sub-command of the control stage: ``control`` (closed-loop episodes, paper §VI-B).

Every argument is checked before any model is loaded or any step taken; bad input raises
:class:`deapull.errors.InputError`, which the ``deapull`` entry point prints as one line
and maps to exit status 2. torch, gymnasium and dolfinx are imported only when a run starts.
"""
from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

from deapull.errors import InputError
from deapull.workflows.args import add_fidelity_arg, overrides_of, shipped_toml


PRESET_DIR = Path(__file__).resolve().parents[1] / "control" / "presets"
#: the options every run names itself (a preset does not set where to write)
NOT_IN_PRESETS = ("out", "preset", "overrides", "func", "command", "verbose", "parser", "options")
#: the options ``deapull control --help`` lists; the others are set by a preset or ``--set control.KEY=VALUE``
LISTED = ("preset", "policy", "plant", "noise", "episodes", "seed", "target_mm", "data", "out", "scene", "fidelity",
          "overrides", "no_progress", "options")


def preset_path(name: str) -> Path:
    """A shipped preset by name (control/presets/NAME.toml) or a path to a TOML file."""
    return shipped_toml(name, PRESET_DIR, "--preset", "preset")


def _option_value(action, key: str, value, source: str):
    """``value`` checked against the option's type (the parser's own conversion for strings);
    ``source`` names where it was set, the key after it (``--set control.`` or ``preset NAME: control.``)."""
    default = action.real_default
    if isinstance(action, argparse._StoreTrueAction) or isinstance(default, bool):
        if not isinstance(value, bool):
            raise InputError(f"{source}{key} = {value!r}: expected true or false")
        return value
    kind = action.type or (type(default) if default is not None else str)
    try:
        if isinstance(value, bool) or (kind in (int, float) and isinstance(value, str)):
            raise ValueError
        out = kind(value)
    except (TypeError, ValueError):
        raise InputError(f"{source}{key} = {value!r}: expected {getattr(kind, '__name__', kind)}") from None
    if action.choices and out not in action.choices:
        raise InputError(f"{source}{key} = {out!r}: expected one of {', '.join(map(str, action.choices))}")
    return out


def apply_preset(args, parser) -> None:
    """``--preset``'s settings, then ``--set control.KEY=VALUE``, onto ``args``: a preset value
    replaces an option left at its default; ``--set control.`` wins over both. An unknown key
    exits 2 naming it and the allowed ones."""
    from deapull.scene import _parse_value
    actions = {a.dest: a for a in parser._actions if a.dest not in NOT_IN_PRESETS and a.dest != "help"}
    allowed = ", ".join(sorted(actions))
    given = {dest for dest in actions if hasattr(args, dest)}      # the flags on the command line
    settings = {}
    args.mpc_table = {}
    if args.preset:
        path = preset_path(args.preset)
        document = read_preset(path)
        table = document.get("control", {})
        args.mpc_table = document.get("mpc", {})
        for key, value in table.items():
            if key not in actions:
                raise InputError(f"preset {path.name}: control.{key}: unknown key; allowed: {allowed}")
            if key not in given:
                settings[key] = _option_value(actions[key], key, value, f"preset {path.name}: control.")
    scene_sets = []
    args.mpc_table = merge_tables(args.mpc_table, mpc_sets(args.overrides))
    for assignment in args.overrides:
        path, _, text = assignment.partition("=")
        if path.strip().startswith("mpc."):
            continue
        if not path.strip().startswith("control."):
            scene_sets.append(assignment)
            continue
        key = path.strip()[len("control."):]
        if key not in actions:
            raise InputError(f"--set control.{key}: unknown key; allowed: {allowed}")
        settings[key] = _option_value(actions[key], key, _parse_value(text.strip()), "--set control.")
    args.overrides = scene_sets
    for dest, action in actions.items():      # the options neither given nor set: their defaults
        if dest not in given and dest not in settings:
            settings[dest] = action.real_default
    for key, value in settings.items():
        setattr(args, key, value)
    for key in ("policy", "plant", "out"):
        if not getattr(args, key):
            raise InputError(f"--{key}: missing; give it, or a --preset that sets it (shipped: "
                             f"{', '.join(sorted(q.stem for q in PRESET_DIR.glob('*.toml')))})")


def read_preset(path: Path) -> dict:
    """A preset file's tables (``[control]``, ``[mpc]``); anything else exits 2 naming it."""
    try:
        document = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as err:
        raise InputError(f"{path}: not valid TOML ({err})") from None
    stray = [k for k in document if k not in ("control", "mpc")]
    if stray:
        raise InputError(f"preset {path.name}: [{stray[0]}]: unknown table; allowed: [control], [mpc]")
    return document


def mpc_sets(overrides) -> dict:
    """The ``--set mpc.KEY=VALUE`` (``mpc.estimator.KEY``, ``mpc.inference.KEY``) as a nested table."""
    from deapull.scene import _parse_value
    table: dict = {}
    for assignment in overrides:
        path, _, text = assignment.partition("=")
        keys = path.strip().split(".")
        if keys[0] != "mpc":
            continue
        if len(keys) < 2 or not all(keys[1:]):
            raise InputError(f"--set {assignment!r}: expected mpc.KEY=VALUE (deapull control --options lists them)")
        node = table
        for key in keys[1:-1]:
            node = node.setdefault(key, {})
        node[keys[-1]] = _parse_value(text.strip())
    return table


def merge_tables(base: dict, top: dict) -> dict:
    """``top`` over ``base``, sub-tables merged key by key."""
    out = dict(base)
    for key, value in top.items():
        out[key] = merge_tables(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) \
            else value
    return out


def options_text(parser) -> str:
    """Every option of ``deapull control``, the ones --help leaves out too, as a preset key with its help."""
    lines = ["Every option; in a preset (control/presets/*.toml, table [control]) or as --set control.KEY=VALUE:"]
    for a in parser._actions:
        if a.dest in NOT_IN_PRESETS or a.dest == "help":
            continue
        lines.append(f"  {a.dest} (default {a.real_default!r}): {a.full_help}")
    from deapull.control.mpc_policy import MPCConfig  # lazy: torch loads only here
    lines.append("The MPC's settings; in a preset's table [mpc] ([mpc.estimator], [mpc.inference]) or as "
                 "--set mpc.KEY=VALUE (docstring of deapull.control.mpc_policy.MPCConfig):")
    lines += [f"  mpc.{k} (default {v!r})" for k, v in _flat(MPCConfig()).items()]
    return "\n".join(lines)


def _flat(config, prefix: str = "") -> dict:
    """A config's settings by dotted key (sub-configs expanded)."""
    from dataclasses import fields, is_dataclass
    out = {}
    for f in fields(config):
        value = getattr(config, f.name)
        if is_dataclass(value):
            out.update(_flat(value, f"{prefix}{f.name}."))
        else:
            out[f"{prefix}{f.name}"] = value
    return out


def cmd_control(args) -> int:
    if args.options:
        print(options_text(args.parser))
        return 0
    from deapull.workflows import control  # lazy: torch and gymnasium load only when a run starts
    apply_preset(args, args.parser)
    config = control_config(args)
    import torch  # lazy: as above
    torch.set_num_threads(args.threads)
    episodes = control.run(config)
    print(control.summary_table([e.row for e in episodes], config.tolerance_m))
    print(f"wrote {config.out}/control.csv, table.md, traces.npz, run.json and the figures")
    return 0


def control_config(args):
    """The :class:`~deapull.workflows.control.ControlConfig` of ``deapull control``'s arguments
    (``bench/bench_control_fem.py`` takes the same flags, so it times ``make control-fem``'s own)."""
    from deapull.workflows import control  # lazy: as above
    from deapull.control.mpc_policy import mpc_config  # lazy: as above
    if args.threads < 1:
        raise InputError(f"--threads {args.threads} must be at least 1")
    return control.ControlConfig(
        policies=control.parse_policies(args.policy),
        plants=control.parse_plants(args.plant, args.scene),
        noises=control.parse_noises(args.noise),
        out=Path(args.out), episodes=args.episodes, seed=args.seed, dv_max_V=args.dv_max,
        max_steps=args.max_steps, hold_steps=args.hold, target_m=1e-3 * args.target_mm,
        setpoints_m=None if args.setpoints_mm is None else parse_setpoints(args.setpoints_mm), data=Path(args.data),
        plant_model=args.plant_model, mpc_model=args.mpc_model, mpc_phi=args.mpc_phi, phi_prior=args.phi_prior,
        mpc=mpc_config(getattr(args, "mpc_table", {})), unreachable=args.unreachable, reach_fraction=args.reach_fraction,
        plant_phi=control.parse_plant_phi(args.plant_phi),
        sac_dir=args.sac_dir, sac_steps=args.sac_steps,
        scene=args.scene, overrides=overrides_of(args), progress=not args.no_progress,
        save_fem_runs=None if args.save_fem_runs is None else Path(args.save_fem_runs))


def parse_setpoints(text: str) -> list[float]:
    """``-0.5,-1.0,-0.7`` (mm) as metres; every item a number (the sign is checked with the rest)."""
    out = []
    for item in [t.strip() for t in str(text).split(",") if t.strip()] or [text]:
        try:
            out.append(1e-3 * float(item))
        except ValueError:
            raise InputError(f"--setpoints-mm {item!r}: not a number (setpoints in mm, comma-separated, "
                             "e.g. --setpoints-mm=-0.5,-1.0,-0.7)") from None
    return out


def register(sub) -> None:
    """Add ``control`` to the ``deapull`` sub-parsers."""
    p = sub.add_parser("control", help="closed-loop control episodes: MPC, SAC, PD, heuristic on surrogate or "
                                       "FEM plants (CSV, table beside the paper, Fig. 6 plots)")
    p.add_argument("--preset", default=None,
                   help="a shipped preset (control/presets: surrogate, the paper's Fig. 6 on f_s,1 and f_s,2; fem, the "
                        "MPC on fem:C1..C8) or a TOML file; the flags given win over it, --set control.KEY=VALUE "
                        "over both")
    p.add_argument("--options", action="store_true", help="print every option (those a preset sets too) and exit")
    p.add_argument("--policy", default=None,
                   help="policy or comma-separated policies: mpc, sac, pd (K_p -0.5, K_d 5 V/mm), heur (+0.5 V/step); "
                        "mpc is offset-free (it estimates f_a's gain error with the position and holds V once "
                        "the estimate is inside the window); mpc+kf: the earlier MPC on a position-only Kalman "
                        "estimate; pd+kf: the PD on a constant-velocity Kalman estimate")
    p.add_argument("--plant", default=None,
                   help="plant(s) KIND:SETUP, comma-separated: surrogate:C1 (the paper's f_s,1), fem:C1 (the FEM "
                        "stepped online)")
    p.add_argument("--noise", default="0",
                   help="std(s) of the Gaussian noise on the observed x (m), comma-separated, e.g. 0,1e-5,1e-4,1e-3 "
                        "(default 0; the paper: 1e-3)")
    p.add_argument("--episodes", type=int, default=10, help="episodes per policy, plant and noise (default 10)")
    p.add_argument("--out", default=None, help="output folder (required for a run)")
    p.add_argument("--seed", type=int, default=0, help="episode i uses seed SEED + i (noise, plant) (default 0)")
    p.add_argument("--dv-max", type=float, default=5.0,
                   help="largest |dV| per 1 ms step, the same for every policy (V; default 5)")
    p.add_argument("--max-steps", type=int, default=4000, help="steps before an episode counts as failed (4000)")
    p.add_argument("--hold", type=int, default=100,
                   help="steps run after the first success to judge settling (default 100)")
    p.add_argument("--target-mm", type=float, default=-1.0, help="target coin position x^T (mm; default -1)")
    p.add_argument("--setpoints-mm", default=None,
                   help="a multi-setpoint task instead of --target-mm: setpoints visited in turn, each reached and "
                        "then held for --hold steps, e.g. --setpoints-mm=-0.5,-1.0,-0.7 (push, push, pull back; with '=', "
                        "since the value starts with '-')")
    p.add_argument("--data", default="data", help="folder with <setup>.nc: the surrogate plants' coin φ (data)")
    p.add_argument("--plant-phi", default=None, metavar="FIELD=VALUE,...",
                   help="surrogate plants: simulate this coin instead of the setup's (mass_kg, mu_b, mu_t in SI "
                        "units, e.g. mass_kg=2.07e-3,mu_b=0.25: a coin the inference's prior does not centre on)")
    p.add_argument("--plant-model", default="out/models/fs{n}",
                   help="surrogate plant model folder; {setup} -> C1, {n} -> 1 (default out/models/fs{n})")
    p.add_argument("--mpc-model", default="out/models/fa",
                   help="the MPC's model f_a, f-coulomb or f trained on C3..C8 (default out/models/fa)")
    p.add_argument("--reach-fraction", type=float, default=None,
                   help="FEM plants: each plant's target is this fraction of its own ramp travel (the --data "
                        "dataset's), in place of --target-mm, which the other plants keep (0.8: a target within "
                        "every FEM plant's reach)")
    p.add_argument("--unreachable", default="refuse", choices=("refuse", "report"),
                   help="a plant that cannot take the coin to the task (FEM: its dataset's ramp; surrogate: the "
                        "fastest push): refuse the run (exit 2, default) or report it as unreachable in the "
                        "table and run the other plants")
    p.add_argument("--mpc-phi", default="infer", choices=("infer", "prior", "oracle"),
                   help="where the MPC's coin comes from: infer (online, mpc.inference; default), prior (the "
                        "coin-family prior's median, inferring nothing; needs --phi-prior coins) or oracle (the "
                        "plant's true coin)")
    p.add_argument("--phi-prior", default="none",
                   help="the MPC's online inference: none (maximum likelihood, the paper's Algorithm 2; default) "
                        "or coins (MAP with a log-normal prior over the design card's coin family, a factor 2 "
                        "wide: control.inference.COIN_PRIOR) or family (the design's coins at ±1 std: family_prior())")
    p.add_argument("--sac-dir", default="out/models/sac{n}",
                   help="trained SAC policy folder; trained there on the surrogate plant when absent "
                        "(default out/models/sac{n})")
    p.add_argument("--sac-steps", type=int, default=30000,
                   help="SAC training budget in env steps when it is trained here (30000: ~13 min on one core)")
    p.add_argument("--scene", default="coin_pull", help="scene of the setups and of the FEM plant (coin_pull)")
    add_fidelity_arg(p)
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="control.KEY=VALUE: one control option (deapull control --options lists them); any other "
                        "section: one key of the FEM plant's scene (validated like the file); repeatable")
    p.add_argument("--save-fem-runs", default=None, metavar="DIR",
                   help="write each FEM plant episode as a dataset DIR/<setup>_<policy>_n<noise>_e<episode>.nc (the "
                        "FEM's contract; the surrogates train on it)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    for action in p._actions:          # --help lists the main options; --options and presets the rest
        action.full_help = action.help
        if action.dest not in LISTED and action.dest != "help":
            action.help = argparse.SUPPRESS
        # an option absent from the command line is absent from the namespace, so that a preset can
        # tell it from one given at its default value; apply_preset fills in the defaults
        if action.dest not in NOT_IN_PRESETS and action.dest != "help":
            action.real_default, action.default = action.default, argparse.SUPPRESS
    p.set_defaults(func=cmd_control, parser=p)
